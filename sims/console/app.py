"""The console's web page (NiceGUI): a thin layer that draws :mod:`sims.console.views` and forwards the
operator's keys and buttons to :class:`sims.console.operator.OperatorSwarm`.

Only this module imports NiceGUI (the optional ``console`` extra); nothing else in the package imports
it. The simulation state lives in the library objects; a page holds only what the person chose to look
at (the selected robot, which estimates to show).
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
import traceback

from nicegui import app, background_tasks, ui

from sims.console.scene import svg
from sims.console.views import error_series, launch_rows, launch_series, swarm_frame

__all__ = ["SwarmRunner", "serve"]

KEYS = {"ArrowUp": "forward", "w": "forward", "ArrowDown": "backward", "s": "backward", "ArrowLeft": "left",
        "a": "left", "ArrowRight": "right", "d": "right", "x": "stop", "p": "picture", "r": "report", "l": "read"}
VIEW_WIDTH = 640


class SwarmRunner:
    """Steps an :class:`OperatorSwarm` on the wall clock and pushes each step to the pages that show it.

    One task (:meth:`run`, started with the server) steps the swarm on a fixed schedule, one step every
    ``dt / rate`` wall seconds counted from one start, so the timer's jitter does not add up and the
    steps are evenly spaced (a step made late, on a busy machine, is followed at once by the steps due
    meanwhile, up to :attr:`MAX_LAG_S` behind; beyond, the schedule starts again). A step runs in a
    worker thread under :attr:`lock` (pages read and command the swarm under the same lock), so the
    server goes on sending the last step while it computes the next. Right after a step every open
    page's draw function is called, so a page shows each step once, when it happens, instead of
    sampling the swarm with a timer of its own (which, at the step's own rate, shows two steps in one
    browser frame and misses one now and then).
    Pages are drawn at most ``display_hz`` times a second on average (pushes go in slots one display
    period apart): a step that comes before its slot is pushed at the slot (with whatever step is
    newest then), so a step made late and its catch-up step still show one by one, and when the swarm
    steps faster than ``display_hz`` the steps in between are skipped. The swarm steps only while a page is open and ``running``.

    Parameters
    ----------
    op : sims.console.operator.OperatorSwarm
    rate : float
        Simulated seconds per wall second.
    display_hz : float
        Most pushes of the top view per second (default 20, above the swarm's 10 steps per second at
        the default ``dt`` of 0.1 s, so every step is shown).
    """

    #: a schedule this far behind [s] starts again from now; less is caught up with steps back to back
    MAX_LAG_S = 0.5

    def __init__(self, op, rate: float = 1.0, display_hz: float = 20.0):
        if not rate > 0 or not display_hz > 0:
            raise ValueError(f"rate and display_hz must be positive, got {rate}, {display_hz}")
        self.op = op
        self.rate = rate
        self.display_hz = display_hz
        self.running = True
        # held while the swarm steps (in a worker thread) and while a page reads or commands it
        self.lock = threading.RLock()
        self.late = 0  # times the schedule was reset because a step came more than MAX_LAG_S late
        self.pushes = 0  # steps pushed to the open pages
        self._pages: list = []
        self._next_slot = -math.inf  # earliest time of the next push
        self._deferred = False  # a push is scheduled for the end of the display period
        self._pushed_k = None  # the step last pushed

    def subscribe(self, draw) -> None:
        """Call ``draw()`` after every step shown (until :meth:`unsubscribe`)."""
        self._pages.append(draw)

    def unsubscribe(self, draw) -> None:
        if draw in self._pages:
            self._pages.remove(draw)

    def _push(self, force: bool = False) -> None:
        now, period = time.monotonic(), 1.0 / self.display_hz
        if not force and now < self._next_slot:
            # too soon (a late step caught up at once): push at the next slot, with the newest step then,
            # so steps made back to back still show one by one
            if not self._deferred:
                self._deferred = True
                asyncio.get_running_loop().call_later(self._next_slot - now, self._push_deferred)
            return
        # slots one display period apart: a push that came late does not delay the next one, and no two
        # pushes are less than half a period apart
        self._next_slot = max(self._next_slot + period, now + 0.5 * period)
        self._pushed_k = self.op.k
        self.pushes += 1
        for draw in list(self._pages):
            try:
                draw()
            except Exception:  # noqa: BLE001 - a page that cannot be drawn (its client went away) is dropped
                self.unsubscribe(draw)
                traceback.print_exc()

    def _push_deferred(self) -> None:
        self._deferred = False
        if self.op.k != self._pushed_k:  # unless a push in the meantime showed the newest step already
            self._push()

    def _tick(self) -> None:
        with self.lock:
            self.op.tick()

    def step(self) -> None:
        """One step now (the *step* button while paused), shown at once."""
        self._tick()
        self._push(force=True)

    async def run(self) -> None:
        """Step while running and watched, one step per ``dt / rate`` wall seconds, forever."""
        period = self.op.config.dt / self.rate
        due = time.monotonic()
        while True:
            due += period
            await asyncio.sleep(max(due - time.monotonic(), 0.0))
            if not self.running or not self._pages:
                due = time.monotonic()
                continue
            try:
                # in a worker thread: the server goes on sending the last step to the pages meanwhile
                await asyncio.to_thread(self._tick)
            except Exception:  # noqa: BLE001 - a failing step pauses the swarm and says why, the page lives on
                self.running = False
                traceback.print_exc()
                continue
            if time.monotonic() - due > max(self.MAX_LAG_S, 2 * period):
                self.late += 1  # the machine could not keep up for a while: no long burst of catch-up steps
                due = time.monotonic()
            self._push()


def _swarm_page(runner: SwarmRunner) -> None:
    op = runner.op
    # last_k: the step drawn; what to show changes redraw at once (even while paused)
    state = {"selected": op.names[0], "mode": "by", "links": "selected", "last_k": -1, "seen": ""}

    def show(**what) -> None:
        state.update(what)
        draw()
    ui.page_title("decentral console: swarm")
    with ui.row().classes("w-full no-wrap items-start"):
        with runner.lock:
            first = svg(swarm_frame(op, state["selected"]), VIEW_WIDTH)
        view = ui.html(first, sanitize=False).props('data-testid="topview-host"')
        with ui.column().classes("gap-1").style("min-width: 360px"):
            ui.label("Kanovsky's operator loop").classes("text-lg")
            status = ui.label().props('data-testid="status"')
            select = ui.select(list(op.names), value=state["selected"], label="robot",
                               on_change=lambda e: show(selected=e.value)).props('data-testid="robot"')

            def cmd(what: str) -> None:
                try:
                    with runner.lock:
                        if what == "picture":
                            state["seen"] = f"{state['selected']} sees: " + (
                                ", ".join(op.picture(state["selected"])) or "nobody")
                        else:
                            op.command(state["selected"], what)
                except Exception as err:  # noqa: BLE001 - a bad command is a notification, not a crash
                    ui.notify(str(err), type="warning")
                draw()  # paused: commands wait for "step", so several robots can act at one instant

            with ui.grid(columns=3).classes("gap-1"):
                ui.label()
                ui.button("▲", on_click=lambda: cmd("forward")).props('data-testid="forward"').tooltip("forward (↑, w)")
                ui.label()
                ui.button("⟲", on_click=lambda: cmd("left")).props('data-testid="left"').tooltip("rotate left (←, a)")
                ui.button("■", on_click=lambda: cmd("stop")).props('data-testid="stop"').tooltip("stop (x)")
                ui.button("⟳", on_click=lambda: cmd("right")).props('data-testid="right"').tooltip("rotate right (→, d)")
                ui.label()
                ui.button("▼", on_click=lambda: cmd("backward")).props('data-testid="backward"').tooltip("backward (↓, s)")
                ui.label()
            with ui.row().classes("gap-1"):
                ui.button("take a picture", on_click=lambda: cmd("picture")).props('data-testid="picture"').tooltip("p")
                ui.button("report", on_click=lambda: cmd("report")).props('data-testid="report"').tooltip("r")
                ui.button("read & localize", on_click=lambda: cmd("read")).props('data-testid="read"').tooltip("l")
            with ui.row().classes("gap-1"):
                def everyone(what: str) -> None:
                    with runner.lock:
                        for n in op.names:
                            op.command(n, what)

                def loop_all() -> None:
                    with runner.lock:
                        op.loop_all()
                ui.button("everyone: picture + report + read", on_click=loop_all).props(
                    'data-testid="loop-all" flat')
                ui.button("all read", on_click=lambda: everyone("read")).props('data-testid="all-read" flat')
            seen = ui.label().props('data-testid="seen"')
            ui.toggle({"by": "estimates by robot", "of": "estimates of robot", "all": "all"}, value="by",
                      on_change=lambda e: show(mode=e.value)).props('data-testid="mode"')
            ui.toggle({"selected": "its links", "all": "all links", "none": "no links"}, value="selected",
                      on_change=lambda e: show(links=e.value))
            with ui.row().classes("gap-1 items-center"):
                ui.switch("run", value=runner.running, on_change=lambda e: setattr(runner, "running", e.value)
                          ).props('data-testid="run"')
                ui.switch("auto loop", value=op.auto, on_change=lambda e: setattr(op, "auto", e.value))
                ui.button("step", on_click=runner.step).props('data-testid="step" flat')
            ui.label("keys: arrows/wasd drive, x stop, p picture, r report, l read, [ ] robot").classes("text-xs")
    chart = ui.echart({
        "animation": False, "legend": {"type": "scroll", "top": 0}, "grid": [{"top": 50, "height": 100}, {"top": 190, "height": 80}],
        "xAxis": [{"type": "value", "name": "t [s]", "gridIndex": 0}, {"type": "value", "gridIndex": 1}],
        "yAxis": [{"type": "value", "name": "error [m]", "gridIndex": 0},
                  {"type": "value", "name": "sent", "gridIndex": 1}],
        "series": [],
    }).style("height: 300px; width: 1000px").props('data-testid="errors"')

    def on_key(e) -> None:
        if not e.action.keydown:
            return
        name = getattr(e.key, "name", str(e.key))
        what = KEYS.get(name) or KEYS.get(name.lower() if len(name) == 1 else name)
        if what:
            cmd(what)
        elif name in ("[", "]"):
            i = op.names.index(state["selected"]) + (1 if name == "]" else -1)
            select.value = op.names[i % len(op.names)]

    ui.keyboard(on_key=on_key, ignore=["input", "select", "textarea"])
    last_chart = [0.0]

    def draw() -> None:
        """The top view and the status line as they are now: one batched update of three elements."""
        with runner.lock:
            state["last_k"] = op.k
            picture = svg(swarm_frame(op, state["selected"], state["mode"], state["links"]), VIEW_WIDTH)
            line = (f"step {op.k}, t = {op.t:.1f} s | {op.sent_copies} messages, "
                    f"{op.sent_bytes / 1e3:.1f} kB | stale reports discarded {op.stale_discarded} | "
                    f"unread by {state['selected']}: {len(op.inbox[state['selected']])}")
        view.set_content(picture)
        status.set_text(line)
        seen.set_text(state["seen"])

    def refresh() -> None:
        # a step not drawn yet (a push to this page failed): draw it, unless a step is running now (its
        # push follows; waiting for the lock here would hold up the server)
        if op.k != state["last_k"] and runner.lock.acquire(blocking=False):
            try:
                draw()
            finally:
                runner.lock.release()
        now = time.monotonic()
        if now - last_chart[0] > 1.0 and op.history:
            last_chart[0] = now
            with runner.lock:
                hist = list(op.history)
                lines = error_series(op, state["selected"])
            series = [{"name": name, "type": "line", "showSymbol": False, "data": pts, "connectNulls": False,
                       "lineStyle": {"width": 3 if name in (state["selected"], "median") else 1},
                       **({"lineStyle": {"width": 3, "type": "dashed", "color": "#000"}} if name == "median" else {})}
                      for name, pts in lines.items()]
            series += [{"name": "messages", "type": "line", "showSymbol": False, "xAxisIndex": 1, "yAxisIndex": 1,
                        "data": [[round(h.t, 2), h.messages] for h in hist]},
                       {"name": "kB", "type": "line", "showSymbol": False, "xAxisIndex": 1, "yAxisIndex": 1,
                        "data": [[round(h.t, 2), round(h.bytes / 1e3, 1)] for h in hist]}]
            chart.options["series"] = series
            chart.update()

    runner.subscribe(draw)
    ui.context.client.on_delete(lambda: runner.unsubscribe(draw))
    ui.timer(0.25, refresh)


def _replay_page(replay) -> None:
    ui.page_title("decentral console: replay")
    state = {"k": 0}
    with ui.row().classes("w-full no-wrap items-start"):
        view = ui.html(svg(replay.frame(0), VIEW_WIDTH), sanitize=False).props('data-testid="topview-host"')
        with ui.column():
            ui.label(f"replay: {len(replay)} steps, reference {replay.reference}").classes("text-lg")
            info = ui.label().props('data-testid="status"')

            def show(k: int) -> None:
                state["k"] = int(k)
                fr = replay.frame(state["k"])
                view.set_content(svg(fr, VIEW_WIDTH))
                errs = [m.error for m in fr.marks if m.error is not None]
                info.set_text(f"{fr.label}" + (f" | mean error {sum(errs) / len(errs):.3f} m" if errs else ""))

            slider = ui.slider(min=0, max=max(len(replay) - 1, 0), value=0, on_change=lambda e: show(e.value)
                               ).props('data-testid="time" label-always').style("width: 320px")
            with ui.row():
                ui.button("◀", on_click=lambda: slider.set_value(max(int(slider.value) - 1, 0))).props(
                    'data-testid="prev" flat')
                ui.button("▶", on_click=lambda: slider.set_value(min(int(slider.value) + 1, len(replay) - 1))).props(
                    'data-testid="next" flat')
            playing = {"on": False}
            ui.switch("play", on_change=lambda e: playing.update(on=e.value)).props('data-testid="play"')

    def tick() -> None:
        if playing["on"] and len(replay):
            slider.value = (int(slider.value) + 1) % len(replay)

    show(0)
    ui.timer(0.2, tick)


def _launch_page(follower, truth, reference: str | None) -> None:
    ui.page_title("decentral console: agents")
    state = {"assembly": None, "coord": 0}
    ui.label("agents (from their --stream files)").classes("text-lg")
    status = ui.label().props('data-testid="status"')
    columns = [{"name": k, "label": k, "field": k} for k in
               ("agent", "step", "t", "rounds", "converged", "status", "placed", "messages", "bytes", "rejected",
                "provisional", "restarts", "age")]
    table = ui.table(columns=columns, rows=[], row_key="agent").props('data-testid="agents" dense')
    with ui.row():
        pick = ui.select([], label="assembly", on_change=lambda e: state.update(assembly=e.value)).style("width: 160px")
        ui.toggle({0: "x", 1: "y", 2: "theta"}, value=0, on_change=lambda e: state.update(coord=e.value))
    chart = ui.echart({"animation": False, "legend": {"top": 0}, "xAxis": {"type": "value", "name": "t [s]"},
                       "yAxis": {"type": "value", "scale": True}, "series": []}).style("height: 320px; width: 1000px")
    last_chart = [0.0]

    def refresh() -> None:
        follower.poll()
        now = time.time()
        rows = launch_rows(follower, now)
        for r in rows:
            r["rejected"] = ", ".join(f"{k} {v}" for k, v in sorted(r["rejected"].items()) if v) or "0"
            r["provisional"] = ", ".join(map(str, r["provisional"])) or "-"
            r["age"] = "" if r["age"] is None else f"{r['age']:.1f} s"
            r["t"] = "" if not isinstance(r["t"], (int, float)) else f"{r['t']:.2f}"
        table.rows = rows
        table.update()
        names = follower.assemblies()
        if names != pick.options:
            pick.set_options(names, value=state["assembly"] if state["assembly"] in names else
                             next((n for n in names if n != reference), names[0] if names else None))
        status.set_text(f"{len(rows)} agents | {sum(r['messages'] for r in rows)} messages, "
                        f"{sum(r['bytes'] for r in rows) / 1e3:.1f} kB | unreadable lines {follower.bad_lines}")
        if state["assembly"] and time.monotonic() - last_chart[0] > 0.5:
            last_chart[0] = time.monotonic()
            series = launch_series(follower, state["assembly"], state["coord"], truth, reference)
            styles = {"truth": {"lineStyle": {"type": "dashed", "color": "#000"}, "showSymbol": False},
                      reference: {"lineStyle": {"width": 4}}}
            chart.options["series"] = [
                {"name": name + (" (reference)" if name == reference else ""), "type": "line", "showSymbol": True,
                 "data": [list(p) for p in pts], **styles.get(name, {})}
                for name, pts in series.items()]
            chart.update()

    ui.timer(0.1, refresh)


def serve(source: dict, host: str = "127.0.0.1", port: int = 8765, title: str = "decentral console") -> None:
    """Serve the page for ``source`` until interrupted.

    Parameters
    ----------
    source : dict
        ``{"kind": "swarm", "runner": SwarmRunner}``, ``{"kind": "replay", "replay": Replay}`` or
        ``{"kind": "launch", "follower": StreamFollower, "truth": Truth | None, "reference": str | None}``.
    """
    kind = source["kind"]

    @ui.page("/")
    def index():
        if kind == "swarm":
            _swarm_page(source["runner"])
        elif kind == "replay":
            _replay_page(source["replay"])
        else:
            _launch_page(source["follower"], source.get("truth"), source.get("reference"))

    @app.get("/healthz")
    def healthz():
        """Liveness, and for the swarm the runner's counts (steps, pushes to the pages, schedule resets)."""
        if kind != "swarm":
            return {"ok": True, "kind": kind}
        runner = source["runner"]
        return {"ok": True, "kind": kind, "step": runner.op.k, "pushes": runner.pushes, "late": runner.late,
                "pages": len(runner._pages)}

    if kind == "swarm":
        app.on_startup(lambda: background_tasks.create(source["runner"].run(), name="swarm steps"))

    ui.run(host=host, port=port, title=title, reload=False, show=False, show_welcome_message=False,
           favicon="🛰", uvicorn_logging_level="warning")
