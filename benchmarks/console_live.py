"""The console in a real browser: how often the swarm's page updates at 50 robots and what the server
spends, and how far the agents' view lags behind their streams.

*swarm*: ``decentral console --swarm --robots N`` (operator loop; ``--auto`` also measured: every
robot pictures, reports and reads every step); headless Chromium reads the top view's step label on
every animation frame for ``--seconds``: distinct steps seen per second are the page's updates. The
server's CPU is its process's user + system time over the same window, per wall second (1.0 = one
core). *launch*: ``--agents`` synthetic agents append a stream record each every ``--period`` seconds
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


def swarm_rate(robots: int, seconds: float, chromium: str, auto: bool) -> dict:
    from playwright.sync_api import sync_playwright

    proc, port = start_console(["--swarm", "--robots", str(robots)] + (["--auto"] if auto else []))
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 1000})
            errors = []
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(f"http://127.0.0.1:{port}/", timeout=60_000)
            page.wait_for_selector("#frame-label", timeout=60_000)
            time.sleep(2.0)  # past the first page's start-up
            cpu0, w0 = cpu_seconds(proc.pid), time.time()
            seen = page.evaluate("""(ms) => new Promise(done => {
                const seen = new Set(); const t0 = performance.now();
                const tick = () => { const el = document.querySelector('#frame-label');
                    if (el) seen.add(el.textContent);
                    if (performance.now() - t0 < ms) requestAnimationFrame(tick); else done(seen.size); };
                requestAnimationFrame(tick); })""", seconds * 1000)
            cpu1, w1 = cpu_seconds(proc.pid), time.time()
            browser.close()
    finally:
        proc.kill()
        proc.wait()
    rate, cores = seen / (w1 - w0), (cpu1 - cpu0) / (w1 - w0)
    # CPU per update is what the load cannot change much: cores needed at 10 Hz = 10 x this
    return {"robots": robots, "auto": auto, "updates_per_s": rate, "server_cores": cores,
            "server_cpu_s_per_update": cores / rate if rate > 0 else None,
            "cores_needed_at_10hz": 10 * cores / rate if rate > 0 else None,
            "console_errors": errors, "load": list(os.getloadavg())}


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
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--period", type=float, default=0.2, help="seconds between two records of an agent")
    ap.add_argument("--steps", type=int, default=40, help="records per agent in the launch measurement")
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    args = ap.parse_args()
    result = {"benchmark": "console_live", "parameters": vars(args) | {"out": str(args.out)}, "machine": machine()}
    result["swarm_operator"] = swarm_rate(args.robots, args.seconds, args.chromium, auto=False)
    print(result["swarm_operator"], flush=True)
    result["swarm_auto"] = swarm_rate(args.robots, args.seconds, args.chromium, auto=True)
    print(result["swarm_auto"], flush=True)
    result["launch"] = launch_delay(args.agents, args.period, args.steps, args.chromium)
    print(result["launch"], flush=True)
    save(f"console_live_r{args.robots}_a{args.agents}", result, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
