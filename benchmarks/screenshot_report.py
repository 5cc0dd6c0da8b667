"""Screenshot a study's report as a reader sees it: ``report.html`` in headless Chromium, 1280 px wide.

Writes ``DIR/report.html`` from ``DIR/study.sqlite`` (``decentral report``), then a PNG of its top
``--height`` pixels through Debian's ``chromium`` (``apt-get install chromium``), reduced to a
palette so it stays small enough to commit. With ``--spec`` the study is first run into DIR (cells
already there are not run again).

    python benchmarks/screenshot_report.py out/admm_loss --spec studies/admm_loss.toml \
        --out docs --name report_after.png --force

The PNG goes to ``--out DIR`` (default ``out/benchmarks``) as ``--name`` (default
``report_screenshot.png``), and an existing one is never overwritten without ``--force``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

CHROMIUM = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run", "--hide-scrollbars")


def find_chromium() -> str | None:
    """The first Chromium executable on PATH, or ``None``."""
    return next((path for name in CHROMIUM if (path := shutil.which(name))), None)


def screenshot(html: Path, png: Path, width: int = 1280, height: int = 2000, timeout: float = 120.0) -> None:
    """Render ``html`` in headless Chromium at ``width`` x ``height`` and save the view as ``png``."""
    browser = find_chromium()
    if browser is None:
        raise SystemExit("screenshot_report: no chromium on PATH (Debian: apt-get install chromium)")
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([browser, *FLAGS, f"--user-data-dir={profile}", f"--screenshot={png}",
                        f"--window-size={width},{height}", html.resolve().as_uri()],
                       check=True, capture_output=True, timeout=timeout)


def shrink(png: Path, colours: int = 64) -> None:
    """Rewrite ``png`` with a ``colours`` palette (a page of text and line plots loses nothing visible)."""
    from PIL import Image

    with Image.open(png) as im:
        small = im.convert("RGB").quantize(colours)
    small.save(png, optimize=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("directory", type=Path, metavar="DIR", help="study directory (holds study.sqlite)")
    parser.add_argument("--out", type=Path, default=Path("out/benchmarks"), metavar="DIR",
                        help="folder of the screenshot (default: out/benchmarks)")
    parser.add_argument("--name", default="report_screenshot.png", help="file name of the screenshot")
    parser.add_argument("--spec", type=Path, help="run this study into DIR first (resumes; nothing re-runs)")
    parser.add_argument("--workers", type=int, default=2, help="workers for --spec (default: 2)")
    parser.add_argument("--height", type=int, default=2000, help="pixels of the page to capture (default: 2000)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing PNG")
    args = parser.parse_args(argv)
    args.output = args.out / args.name
    if args.output.exists() and not args.force:
        parser.error(f"{args.output} exists; give --force to overwrite it")
    decentral = [sys.executable, "-m", "sims.cli.main"]
    if args.spec:
        subprocess.run([*decentral, "study", str(args.spec), "-o", str(args.directory), "--workers",
                        str(args.workers)], check=True)
    subprocess.run([*decentral, "report", str(args.directory)], check=True)
    args.out.mkdir(parents=True, exist_ok=True)
    screenshot(args.directory / "report.html", args.output, height=args.height)
    shrink(args.output)
    print(f"{args.output}: {args.output.stat().st_size / 1024:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
