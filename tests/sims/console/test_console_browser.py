"""`decentral console` in a real browser: Playwright drives Debian's chromium (never a downloaded one).

The page is read the way a person looks at it: every robot, estimate and agent row carries its values
in the DOM (``data-*`` attributes, table cells).
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

CHROMIUM = os.environ.get("DECENTRAL_CHROMIUM", "/usr/bin/chromium")
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--no-first-run"]
ROOT = Path(__file__).resolve().parents[3]

pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                reason=f"no chromium binary at {CHROMIUM} (apt-get install chromium)")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    """This environment without pytest's variables (NiceGUI switches to its own test mode when it sees them)."""
    return {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}


class Console:
    """A `decentral console` process on a free loopback port (killed by its pid when done)."""

    def __init__(self, *args: str):
        self.port = _free_port()
        self.proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", "console", *args, "--port",
                                      str(self.port)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True, env=_env())
        end = time.time() + 90
        while time.time() < end:
            if self.proc.poll() is not None:
                raise AssertionError(f"console exited: {self.proc.stderr.read()[-800:]}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.2)
        self.close()
        raise AssertionError("console did not listen within 90 s")

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.proc.stderr.close()


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def _page(browser, url):
    page = browser.new_page(viewport={"width": 1100, "height": 1000})
    errors = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url, timeout=60_000)
    return page, errors


def _truth(page, robot):
    el = page.locator(f"#truth-{robot}")
    return float(el.get_attribute("data-x")), float(el.get_attribute("data-y"))


def _est(page, observer, target):
    el = page.locator(f'g.est[data-observer="{observer}"][data-target="{target}"]')
    if el.count() == 0:
        return None
    return float(el.first.get_attribute("data-x")), float(el.first.get_attribute("data-y"))


def _wait_until(condition, timeout=10.0):
    """Poll ``condition()`` (every 0.1 s) until it is truthy or ``timeout`` seconds passed; return its last value.
    (A busy machine takes longer to answer a click: the tests wait for what a click does, not a fixed time.)"""
    end = time.time() + timeout
    while True:
        value = condition()
        if value or time.time() >= end:
            return value
        time.sleep(0.1)


def _settle(page, robot, timeout=8.0):
    """Wait until ``robot`` has stopped moving in the truth; return where it stands."""
    end, last = time.time() + timeout, None
    while time.time() < end:
        now = _truth(page, robot)
        if last is not None and now == last:
            return now
        last = now
        time.sleep(0.4)
    return last


@pytest.fixture(scope="module")
def swarm_page(browser):
    # seed 8, 4 robots: R1 and R2 see each other, R1 sees R0, R2 does not (tests/sims/console/test_operator.py)
    console = Console("--swarm", "--robots", "4", "--seed", "8")
    page, errors = _page(browser, console.url)
    page.wait_for_selector("#topview", timeout=60_000)
    yield page, errors
    page.close()
    console.close()


def test_swarm_page_shows_every_robot(swarm_page):
    """The swarm's page loads with every robot drawn, R0 selected, and no error in the browser console."""
    page, errors = swarm_page
    assert sorted(page.eval_on_selector_all("g.truth", "els => els.map(e => e.dataset.robot)")) == \
        ["R0", "R1", "R2", "R3"]
    assert page.locator("#truth-R0").get_attribute("data-selected") == "1"
    assert errors == []


def test_keys_drive_the_robot_and_its_new_place_reaches_the_estimates(swarm_page):
    """Arrow keys move R0 in the truth; after R1 takes a picture and reports, R1's estimate of R0 is at
    its new place; the report waits unread in R2's inbox until R2 reads it, and then R2's estimate of R0
    moves toward its new place (R2 cannot see R0: it learns the move only from R1's report)."""
    page, errors = swarm_page
    page.get_by_role("button", name="all", exact=True).click()  # show every robot's estimates
    for _ in range(3):
        page.get_by_test_id("loop-all").click()
        if _wait_until(lambda: _est(page, "R1", "R0") is not None and _est(page, "R2", "R0") is not None, 3.0):
            break
    e1_before = _est(page, "R1", "R0")
    assert e1_before is not None and _est(page, "R2", "R0") is not None
    t0 = _settle(page, "R0")
    page.locator("body").click(position={"x": 1050, "y": 980})  # focus the page, off every control
    for _ in range(3):
        page.keyboard.press("ArrowUp")
        page.wait_for_timeout(150)
    t1 = _settle(page, "R0")
    moved = math.dist(t0, t1)
    assert moved > 0.1
    page.keyboard.press("]")  # select the next robot: R1
    page.wait_for_selector('#truth-R1[data-selected="1"]', timeout=10_000)
    page.get_by_test_id("picture").click()
    assert _wait_until(lambda: "R0" in page.get_by_test_id("seen").inner_text())
    page.get_by_test_id("report").click()
    e1_after = _wait_until(lambda: (e := _est(page, "R1", "R0")) is not None and math.dist(e, t1) < 0.15 and e)
    assert e1_after and math.dist(e1_after, e1_before) > 0.5 * moved, (e1_after, t1, e1_before)
    page.keyboard.press("]")  # R2: R1's report waits unread in its inbox until it reads
    page.wait_for_function("() => /unread by R2: [1-9]/.test(document.querySelector('[data-testid=status]')"
                           ".textContent)", timeout=5_000)
    e2_held = _est(page, "R2", "R0")
    page.get_by_test_id("all-read").click()
    page.wait_for_function("() => /unread by R2: 0/.test(document.querySelector('[data-testid=status]')"
                           ".textContent)", timeout=5_000)
    e2_after = _wait_until(lambda: (e := _est(page, "R2", "R0")) != e2_held and e) or e2_held
    # R2 fuses R1's report with its own track (both weighted by their covariances, which depend on how many
    # steps the running clock took meanwhile), so its estimate moves toward the report rather than onto it
    assert math.dist(e2_after, t1) < math.dist(e2_held, t1)
    assert math.dist(e2_after, e1_after) < math.dist(e2_held, e1_after)
    assert errors == []


@pytest.fixture(scope="module")
def streams_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("streams")


def _write_agents(folder: Path, agents: int, steps: int, period: float, stop: threading.Event) -> None:
    files = {f"A{i}": open(folder / f"A{i}.0.jsonl", "a") for i in range(agents)}
    try:
        for k in range(steps):
            if stop.is_set():
                return
            for name, fh in files.items():
                fh.write(json.dumps({"step": k, "t": 0.2 * k, "poses": {"A1": {"p": [1.0 + 0.01 * k, 0.0, 0.0],
                                                                            "theta": 0.0}},
                                     "converged": k % 2 == 0, "rounds": 3, "provisional": k % 5 == 4,
                                     "counts": {"messages": k, "bytes": 100 * k, "rejected": {"replay": k // 4}}})
                         + "\n")
                fh.flush()
            time.sleep(period)
    finally:
        for fh in files.values():
            fh.close()


def test_launch_view_shows_every_agent_and_follows_it(browser, streams_dir):
    """With eight agents writing their streams, the page lists all eight and their steps advance while
    they run, within half a second of the writes."""
    for i in range(8):
        (streams_dir / f"A{i}.0.jsonl").write_text("")
    console = Console("--streams", str(streams_dir))
    stop = threading.Event()
    try:
        page, errors = _page(browser, console.url)
        page.wait_for_selector("[data-testid=agents]", timeout=60_000)
        writer = threading.Thread(target=_write_agents, args=(streams_dir, 8, 20, 0.1, stop))
        writer.start()

        def steps():
            rows = page.eval_on_selector_all("[data-testid=agents] tbody tr",
                                             "trs => trs.map(tr => [...tr.querySelectorAll('td')].map(td => "
                                             "td.textContent.trim()))")
            return {r[0]: int(r[1]) for r in rows if len(r) > 1 and r[1].isdigit()}

        page.wait_for_function("() => document.querySelectorAll('[data-testid=agents] tbody tr').length >= 8",
                               timeout=20_000)
        first = steps()
        page.wait_for_timeout(1000)
        later = steps()
        writer.join()
        final = _wait_until(lambda: (f := steps()) and all(v == 19 for v in f.values()) and f) or steps()
        assert sorted(first) == [f"A{i}" for i in range(8)]
        assert all(later[a] > first[a] for a in first)
        assert all(v == 19 for v in final.values())
        assert errors == []
        page.close()
    finally:
        stop.set()
        console.close()


@pytest.mark.slow
def test_replay_slider_steps_through_the_run(browser, tmp_path):
    """A finished log and estimate replay: stepping the time slider shows another step's poses."""
    subprocess.run([sys.executable, "-m", "sims.cli.main", "-q", "simulate", "multi", "-o", str(tmp_path),
                    "--steps", "6"], check=True, cwd=ROOT)
    subprocess.run([sys.executable, "-m", "sims.cli.main", "-q", "localize", str(tmp_path / "log.json"), "-o",
                    str(tmp_path / "est.json")], check=True, cwd=ROOT)
    console = Console("--replay", str(tmp_path / "log.json"), str(tmp_path / "est.json"), "--truth",
                      str(tmp_path / "truth.json"))
    try:
        page, errors = _page(browser, console.url)
        page.wait_for_selector("#frame-label", timeout=60_000)
        assert page.locator("#frame-label").text_content().startswith("step 0")
        for _ in range(3):
            page.get_by_test_id("next").click()
        page.wait_for_function("() => document.querySelector('#frame-label').textContent.startsWith('step 3')",
                               timeout=10_000)
        assert page.locator("g.est").count() >= 1 and page.locator("circle.truth-outline").count() >= 1
        assert errors == []
        page.close()
    finally:
        console.close()


@pytest.mark.slow
def test_launch_view_follows_a_real_launch(browser, tmp_path):
    """`decentral launch --workdir` with three agent processes: the page lists every agent while they run."""
    subprocess.run([sys.executable, "-m", "sims.cli.main", "-q", "simulate", "multi", "-o", str(tmp_path),
                    "--steps", "30", "--set", "n_assemblies=3"], check=True, cwd=ROOT)
    work = tmp_path / "work"
    work.mkdir()
    console = Console("--streams", str(work), "--truth", str(tmp_path / "truth.json"))
    launch = subprocess.Popen([sys.executable, "-m", "sims.cli.main", "-q", "launch", str(tmp_path / "log.json"),
                               "-o", str(tmp_path / "est.json"), "--workdir", str(work)], cwd=ROOT, env=_env())
    try:
        page, errors = _page(browser, console.url)
        page.wait_for_function("() => document.querySelectorAll('[data-testid=agents] tbody tr').length >= 3",
                               timeout=120_000)
        names = page.eval_on_selector_all("[data-testid=agents] tbody tr", "trs => trs.map(tr => "
                                          "tr.querySelector('td').textContent.trim())")
        assert sorted(names) == ["A0", "A1", "A2"]
        assert launch.poll() is None  # still running: the view followed it live
        assert errors == []
        page.close()
    finally:
        if launch.poll() is None:
            launch.kill()
        launch.wait()
        console.close()
