"""Live-update web UI libraries for the console, measured: updates per second that reach the page at
50 robots, the server's CPU, the page weight and the installed size.

Each library runs the same small server (``benchmarks/console_libs/<lib>_server.py``): ``--robots``
robots moving on circles, redrawn at a target rate, with a sequence number in every update. Headless
Chromium (Playwright, Debian's ``/usr/bin/chromium``) loads the page and, for ``--seconds``, reads the
sequence number on every animation frame: the distinct values seen per second are the updates that
reached the page. The server's CPU is its process's user + system time over the same window (from
``/proc``); the page weight is the sum of the response bodies of the page load. Each library can run
in its own interpreter (``--python nicegui=PATH``); its site-packages size is reported beside it.

Run: ``python benchmarks/console_libraries.py --python nicegui=... --python viser=... --python panel=...``
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, parser, save  # noqa: E402
from _console import CHROMIUM_ARGS, cpu_seconds, free_port, wait_port  # noqa: E402

HERE = Path(__file__).resolve().parent / "console_libs"
LIBS = ("nicegui", "viser", "panel")
#: how each page exposes the server's sequence number (read in the browser on every animation frame)
SEQ_JS = {
    "nicegui": "document.querySelector('#seq') && document.querySelector('#seq').textContent",
    "viser": "[...document.querySelectorAll('input')].map(e => e.value).join(',')",
    "panel": "(() => { try { return window.Bokeh.documents[0].get_model_by_name('src').data.seq[0]; }"
             " catch (e) { return null; } })()",
}
def site_packages_kb(python: str) -> int:
    out = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                         capture_output=True, text=True, check=True).stdout.strip()
    return int(subprocess.run(["du", "-sk", out], capture_output=True, text=True, check=True).stdout.split()[0])


def measure(lib: str, python: str, robots: int, hz: float, seconds: float, chromium: str) -> dict:
    from playwright.sync_api import sync_playwright

    port = free_port()
    proc = subprocess.Popen([python, str(HERE / f"{lib}_server.py"), "--port", str(port), "--robots", str(robots),
                             "--hz", str(hz)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_port(port, proc, 120)
        weight = [0]
        errors: list[str] = []
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page()

            def on_response(resp):
                try:
                    weight[0] += len(resp.body())
                except Exception:  # noqa: BLE001 - redirects and websockets have no body
                    pass

            page.on("response", on_response)
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            t0 = time.time()
            page.goto(f"http://127.0.0.1:{port}/", wait_until="load", timeout=60_000)
            page.wait_for_function(f"() => {{ const v = {SEQ_JS[lib]}; return v !== null && v !== '' && v !== undefined; }}",
                                   timeout=60_000)
            load_s = time.time() - t0
            page.remove_listener("response", on_response)
            cpu0, w0 = cpu_seconds(proc.pid), time.time()
            seen = page.evaluate(
                f"""(ms) => new Promise(done => {{
                    const seen = new Set(); const t0 = performance.now();
                    const tick = () => {{ seen.add(String({SEQ_JS[lib]}));
                        if (performance.now() - t0 < ms) requestAnimationFrame(tick); else done(seen.size); }};
                    requestAnimationFrame(tick); }})""", seconds * 1000)
            cpu1, w1 = cpu_seconds(proc.pid), time.time()
            browser.close()
        return {"library": lib, "updates_per_s": seen / (w1 - w0), "server_cpu_fraction": (cpu1 - cpu0) / (w1 - w0),
                "page_weight_bytes": weight[0], "page_load_s": load_s, "console_errors": errors,
                "site_packages_kb": site_packages_kb(python), "load_during": list(os.getloadavg())}
    finally:
        proc.kill()
        proc.wait()


def main() -> int:
    ap = parser(__doc__)
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--hz", type=float, default=20.0, help="target update rate of every server (default 20)")
    ap.add_argument("--seconds", type=float, default=5.0, help="measuring window per library (default 5)")
    ap.add_argument("--repeats", type=int, default=3, help="windows per library; medians are reported (default 3)")
    ap.add_argument("--python", action="append", default=[], metavar="LIB=PATH",
                    help="interpreter that has LIB installed (default: this one)")
    ap.add_argument("--libs", default=",".join(LIBS))
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    args = ap.parse_args()
    pythons = dict(item.split("=", 1) for item in args.python)
    results = {}
    for lib in args.libs.split(","):
        runs = [measure(lib, pythons.get(lib, sys.executable), args.robots, args.hz, args.seconds, args.chromium)
                for _ in range(args.repeats)]
        med = lambda key: sorted(r[key] for r in runs)[len(runs) // 2]  # noqa: E731
        results[lib] = {"runs": runs, "updates_per_s_median": med("updates_per_s"),
                        "server_cpu_fraction_median": med("server_cpu_fraction"),
                        "page_weight_bytes_median": med("page_weight_bytes"),
                        "site_packages_kb": runs[0]["site_packages_kb"]}
        print(f"{lib:8s} {results[lib]['updates_per_s_median']:6.1f} updates/s  "
              f"server {100 * results[lib]['server_cpu_fraction_median']:5.1f} % CPU  "
              f"page {results[lib]['page_weight_bytes_median'] / 1e6:5.2f} MB  "
              f"installed {results[lib]['site_packages_kb'] / 1024:6.1f} MiB", flush=True)
    ref = results.get("nicegui")
    if ref:
        for lib, r in results.items():
            r["updates_ratio_to_nicegui"] = r["updates_per_s_median"] / max(ref["updates_per_s_median"], 1e-9)
    save(f"console_libraries_r{args.robots}_hz{args.hz:g}",
         {"benchmark": "console_libraries", "parameters": vars(args) | {"out": str(args.out)}, "machine": machine(),
          "results": results}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
