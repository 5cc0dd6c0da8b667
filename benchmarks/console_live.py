"""The console in a real browser: how often the swarm's page updates at 50 robots and what the server
spends, and how far the agents' view lags behind their streams.

*swarm*: ``decentral console --swarm --robots N`` in three settings: the operator loop at the default
step (``dt`` 0.1 s: the simulation makes 10 states a second, the most a page can show), the same at
``--dt 0.05`` (20 states a second: what the page and the server keep up with beyond the default), and
``--auto`` (every robot pictures, reports and reads every step). One headless Chromium page watches
each for ``--repeats`` windows of ``--seconds``; every figure is the median over the windows. Along
the way from the simulation to the screen it counts: steps the server made and pushes it sent (its
``/healthz`` counts), top-view updates that reached the page's socket, and distinct steps the page
showed (the top view's step label read on every animation frame: two updates in one browser frame
count once). The reference, measured in the same window, is the server's own step rate: ``shown /
stepped`` is the share of the simulation's states a person saw. The server's CPU is its process's user
+ system time per wall second (1.0 = one core); Chromium's renderer is measured the same way.
*launch*: ``--agents`` synthetic agents append a stream record each every ``--period`` seconds
(what ``decentral agent --stream`` writes, with the write time kept); ``decentral console --streams``
follows the folder, and the page's table is read on every animation frame: the delay of a record is
the time it first shows minus the time it was written (same clock).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, parser, save  # noqa: E402
from _console import CHROMIUM_ARGS, cpu_seconds, free_port, wait_port  # noqa: E402

def start_console(args: list[str]) -> tuple[subprocess.Popen, int]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", "console", *args, "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_port(port, proc, 120)
    except RuntimeError as err:
        proc.kill()
        raise RuntimeError(f"console: {err}: {proc.stderr.read()[-500:]}") from None
    return proc, port


WATCH = """(ms) => new Promise(done => {
    const shown = []; let last = null; let arrivals = 0; const t0 = performance.now();
    const count = (msg) => { if (JSON.stringify(msg).includes('frame-label')) arrivals++; };
    window.socket.on('update', count);
    const tick = () => { const el = document.querySelector('#frame-label');
        if (el && el.textContent !== last) { last = el.textContent; shown.push(last); }
        const t = performance.now() - t0;
        if (t < ms) requestAnimationFrame(tick);
        else { window.socket.off('update', count); done({shown, arrivals, ms: t}); } };
    requestAnimationFrame(tick); })"""


def _renderer_seconds() -> float:
    """CPU seconds of this process's Chromium renderers (descendants whose command line says so)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                parent = int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
            children.setdefault(parent, []).append(int(d))
    total, todo = 0.0, [os.getpid()]
    while todo:
        pid = todo.pop()
        todo += children.get(pid, [])
        try:
            if "--type=renderer" in Path(f"/proc/{pid}/cmdline").read_text():
                total += cpu_seconds(pid)
        except OSError:
            continue
    return total


def _median(values: list) -> float | None:
    values = sorted(v for v in values if v is not None)
    if not values:
        return None
    mid = len(values) // 2
    return values[mid] if len(values) % 2 else 0.5 * (values[mid - 1] + values[mid])


def swarm_rate(robots: int, seconds: float, repeats: int, chromium: str, extra: list[str]) -> dict:
    from urllib.request import urlopen

    from playwright.sync_api import sync_playwright

    proc, port = start_console(["--swarm", "--robots", str(robots), *extra])

    def health() -> dict:
        with urlopen(f"http://127.0.0.1:{port}/healthz", timeout=10) as r:
            return json.loads(r.read())

    windows, errors = [], []
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 1000})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://127.0.0.1:{port}/", timeout=60_000)
            page.wait_for_selector("#frame-label", timeout=60_000)
            time.sleep(2.0)  # past the first page's start-up
            for _ in range(repeats):
                h0, cpu0, ren0, w0 = health(), cpu_seconds(proc.pid), _renderer_seconds(), time.time()
                got = page.evaluate(WATCH, seconds * 1000)
                h1, cpu1, ren1, w1 = health(), cpu_seconds(proc.pid), _renderer_seconds(), time.time()
                span, wall = got["ms"] / 1000, w1 - w0
                # the first label is the step on screen when the window opened; the updates are the changes
                shown = len(got["shown"]) - 1
                stepped = h1["step"] - h0["step"]
                windows.append({
                    "shown_per_s": shown / span, "arrivals_per_s": got["arrivals"] / span,
                    "pushes_per_s": (h1["pushes"] - h0["pushes"]) / wall, "steps_per_s": stepped / wall,
                    "shown_over_stepped": shown / stepped if stepped else None,
                    "late_resets": h1["late"] - h0["late"],
                    "server_cores": (cpu1 - cpu0) / wall,
                    "server_cpu_ms_per_step": 1e3 * (cpu1 - cpu0) / stepped if stepped else None,
                    "renderer_cores": (ren1 - ren0) / wall, "load": list(os.getloadavg())})
            browser.close()
    finally:
        proc.kill()
        proc.wait()
    out = {"robots": robots, "options": extra, "repeats": repeats, "seconds": seconds}
    for key in windows[0]:
        if key != "load":
            out[key] = _median([w[key] for w in windows])
    out["cores_needed_at_10hz"] = 10 * out["server_cpu_ms_per_step"] / 1e3 if out["server_cpu_ms_per_step"] else None
    out["console_errors"] = errors
    out["windows"] = windows
    return out


def _writer(folder: Path, agents: int, period: float, steps: int, written: dict, stop: threading.Event) -> None:
    files = {f"A{i}": open(folder / f"A{i}.0.jsonl", "a") for i in range(agents)}
    try:
        for k in range(steps):
            if stop.is_set():
                break
            for name, fh in files.items():
                rec = {"step": k, "t": 0.2 * k, "poses": {f"A{j}": {"p": [j + 0.01 * k, 0.0, 0.0], "theta": 0.0}
                                                          for j in range(agents)}, "converged": True, "rounds": 3,
                       "counts": {"messages": k, "bytes": 100 * k, "rejected": {}}}
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                written[(name, k)] = time.time()
            time.sleep(period)
    finally:
        for fh in files.values():
            fh.close()


def launch_delay(agents: int, period: float, steps: int, chromium: str) -> dict:
    from playwright.sync_api import sync_playwright

    folder = Path(tempfile.mkdtemp(prefix="console-streams-"))
    for i in range(agents):
        (folder / f"A{i}.0.jsonl").write_text("")
    proc, port = start_console(["--streams", str(folder)])
    written: dict = {}
    stop = threading.Event()
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 900})
            page.goto(f"http://127.0.0.1:{port}/", timeout=60_000)
            page.wait_for_selector("[data-testid=agents]", timeout=60_000)
            writer = threading.Thread(target=_writer, args=(folder, agents, period, steps, written, stop))
            writer.start()
            firsts = page.evaluate("""(ms) => new Promise(done => {
                const first = {}; const t0 = performance.now();
                const tick = () => { const el = document.querySelector('[data-testid=agents] tbody');
                    if (el) for (const tr of el.querySelectorAll('tr')) {
                        const td = tr.querySelectorAll('td'); if (td.length < 2) continue;
                        const key = td[0].textContent.trim() + ':' + td[1].textContent.trim();
                        if (!(key in first)) first[key] = Date.now() / 1000; }
                    if (performance.now() - t0 < ms) requestAnimationFrame(tick); else done(first); };
                requestAnimationFrame(tick); })""", (steps * period + 2.0) * 1000)
            stop.set()
            writer.join()
            browser.close()
    finally:
        proc.kill()
        proc.wait()
    delays = []
    for key, t_seen in firsts.items():
        m = re.match(r"^(A\d+):(\d+)$", key)
        if m and (m.group(1), int(m.group(2))) in written:
            delays.append(t_seen - written[(m.group(1), int(m.group(2)))])
    delays.sort()
    shown_agents = {k.split(":")[0] for k in firsts if re.match(r"^A\d+:\d+$", k)}
    return {"agents": agents, "period_s": period, "records_written": len(written), "records_seen": len(delays),
            "agents_shown": len(shown_agents),
            "delay_median_s": delays[len(delays) // 2] if delays else None,
            "delay_p90_s": delays[int(0.9 * (len(delays) - 1))] if delays else None,
            "delay_max_s": delays[-1] if delays else None, "load": list(os.getloadavg())}


def main() -> int:
    ap = parser(__doc__)
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=8.0, help="length of one swarm window")
    ap.add_argument("--repeats", type=int, default=3, help="swarm windows per setting (medians are reported)")
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--period", type=float, default=0.2, help="seconds between two records of an agent")
    ap.add_argument("--steps", type=int, default=40, help="records per agent in the launch measurement")
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    args = ap.parse_args()
    result = {"benchmark": "console_live", "parameters": vars(args) | {"out": str(args.out)}, "machine": machine()}
    settings = {"swarm_operator": [], "swarm_operator_dt005": ["--dt", "0.05"], "swarm_auto": ["--auto"]}
    for key, extra in settings.items():
        result[key] = swarm_rate(args.robots, args.seconds, args.repeats, args.chromium, extra)
        print(key, {k: v for k, v in result[key].items() if k != "windows"}, flush=True)
    result["launch"] = launch_delay(args.agents, args.period, args.steps, args.chromium)
    print(result["launch"], flush=True)
    save(f"console_live_r{args.robots}_a{args.agents}", result, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
