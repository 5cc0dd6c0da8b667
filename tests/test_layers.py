"""Layering: decentral <- protocols <- agents <- sims, and heavy front-end libraries stay out of the core."""

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["decentral", "protocols", "agents", "sims"]


def modules(package: str) -> list[str]:
    pkg = __import__(package)
    return [package] + [m.name for m in pkgutil.walk_packages(pkg.__path__, package + ".")]


def test_importing_decentral_loads_neither_opencv_nor_pettingzoo():
    """Every decentral module imports without loading cv2, pettingzoo or matplotlib (STYLE 1)."""
    code = (
        "import importlib, sys\n"
        f"for name in {modules('decentral')!r}: importlib.import_module(name)\n"
        "bad = [m for m in ('cv2', 'pettingzoo', 'matplotlib', 'gymnasium') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


@pytest.mark.parametrize("layer", ORDER)
def test_layers_point_one_way(layer):
    """No module imports a package of a higher layer than its own."""
    higher = set(ORDER[ORDER.index(layer) + 1 :])
    offenders = []
    for path in (ROOT / layer).rglob("*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            offenders += [f"{path.relative_to(ROOT)}: {n}" for n in names if n.split(".")[0] in higher]
    assert not offenders, offenders


def test_cli_registry_matches_the_command_modules():
    """Every module in sims/cli (but main and feedback, the shared machinery) is a registered subcommand with HELP, add_arguments and run, and vice versa."""
    from sims.cli.main import COMMANDS, build_parser

    on_disk = {p.stem for p in (ROOT / "sims" / "cli").glob("*.py")} - {"__init__", "main", "feedback"}
    registered = {module.rsplit(".", 1)[1] for module in COMMANDS.values()}
    assert on_disk == registered
    build_parser()  # every module imports and attaches its arguments


#: the console's web and export libraries, and the one module allowed to import each
CONSOLE_ONLY = {"nicegui": "sims/console/app.py", "mcap": "sims/console/mcap_export.py", "playwright": None}


def test_console_libraries_are_imported_only_by_their_module():
    """nicegui is imported only by sims/console/app.py, mcap only by sims/console/mcap_export.py, playwright
    by no package module (the tests and benchmarks drive the browser)."""
    offenders = []
    for layer in ORDER:
        for path in (ROOT / layer).rglob("*.py"):
            rel = str(path.relative_to(ROOT))
            for node in ast.walk(ast.parse(path.read_text(), filename=rel)):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    names = [node.module]
                for n in names:
                    top = n.split(".")[0]
                    if top in CONSOLE_ONLY and CONSOLE_ONLY[top] != rel:
                        offenders.append(f"{rel}: {n}")
    assert not offenders, offenders


def test_cli_and_console_library_load_no_web_library():
    """Building the CLI (every command's parser, `console` included) and importing the console's library
    modules loads neither nicegui, mcap nor playwright."""
    code = (
        "import sys\n"
        "from sims.cli.main import build_parser\n"
        "build_parser()\n"
        "import sims.console.operator, sims.console.views, sims.console.streams, sims.console.scene\n"
        "bad = [m for m in ('nicegui', 'mcap', 'playwright', 'fastapi', 'uvicorn') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
