"""Start-up of the command line: CPU and wall time of `decentral --help`, `--version` and every `COMMAND --help`.

Each call runs in a fresh interpreter (the installed `decentral` script when there is one); its CPU time
is the child's user + system time (``resource.getrusage(RUSAGE_CHILDREN)``), its wall time the time to
exit. The reference, measured in the same run, is a bare interpreter start (``python -c pass``); the
ratios are against it. ``--busy N`` starts N busy-looping processes (``yes``) for the measurement and
stops them afterwards, to see the figures on a loaded machine. Writes ``cli_startup[_busyN].json``.
"""

from __future__ import annotations

import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _common import machine, parser, save


def _timed(argv: list[str]) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one run of ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--reps", type=int, default=5, help="runs of each call (default 5); medians are reported")
    ap.add_argument("--busy", type=int, default=0, help="busy processes to run alongside (default 0)")
    args = ap.parse_args(argv)

    from sims.cli.main import COMMANDS

    script = Path(sys.executable).with_name("decentral")
    base = [str(script)] if script.exists() else [sys.executable, "-m", "sims.cli.main"]
    calls = {"python -c pass": [sys.executable, "-c", "pass"], "decentral --help": [*base, "--help"],
             "decentral --version": [*base, "--version"]}
    calls.update({f"decentral {name} --help": [*base, name, "--help"] for name in COMMANDS})
    busy = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(args.busy)] \
        if args.busy and shutil.which("yes") else []
    info = machine()
    try:
        rows = {}
        for _ in range(args.reps):  # interleaved, so that a change of load touches every call alike
            for name, call in calls.items():
                rows.setdefault(name, []).append(_timed(call))
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
    ref_cpu = statistics.median(c for c, _ in rows["python -c pass"])
    result = {"benchmark": "cli_startup", "machine": info,
              "parameters": {"reps": args.reps, "busy": len(busy), "runner": " ".join(base)},
              "reference": "python -c pass", "calls": {}}
    for name, runs in rows.items():
        cpu, wall = statistics.median(c for c, _ in runs), statistics.median(w for _, w in runs)
        result["calls"][name] = {"cpu_s": cpu, "wall_s": wall, "cpu_max_s": max(c for c, _ in runs),
                                 "cpu_ratio_to_reference": cpu / ref_cpu if ref_cpu else None}
        print(f"{name:34s} CPU {cpu:6.3f} s (max {max(c for c, _ in runs):.3f})  wall {wall:6.3f} s")
    print(f"load average at the start {info['loadavg_start']}, {len(busy)} busy processes")
    save("cli_startup" + (f"_busy{len(busy)}" if busy else ""), result, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
