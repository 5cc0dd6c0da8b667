"""Layering: decentral <- protocols <- agents <- sims, sims by role, no import cycle, heavy libraries kept out."""

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


def _module_files() -> dict[str, Path]:
    """Every module of the four packages, by dotted name (a package by its ``__init__.py``)."""
    out = {}
    for layer in ORDER:
        for path in (ROOT / layer).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    """The ids of the nodes under ``if TYPE_CHECKING:`` (imports for annotations only, never run)."""
    hidden = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            hidden |= {id(sub) for child in node.body for sub in ast.walk(child)}
    return hidden


def _imports(path: Path, name: str | None = None) -> list[tuple[str, int]]:
    """``(imported name, line)`` for every import that runs in ``path``: module level and function-local alike.

    ``from a.b import c`` gives ``a.b.c`` (a module or a name in ``a.b``); relative imports are resolved
    against ``name``, the module's dotted name.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    hidden = _type_checking_nodes(tree)
    found = []
    for node in ast.walk(tree):
        if id(node) in hidden:
            continue
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                package = package[: len(package) - node.level + 1]
                base = ".".join(package + ([base] if base else []))
            found += [(f"{base}.{a.name}", node.lineno) for a in node.names]
    return found


def _is_cli(name: str) -> bool:
    return name == "sims.cli" or name.startswith("sims.cli.")


def test_only_the_cli_imports_the_cli():
    """No package module outside sims.cli imports a sims.cli module (function-local imports count); benchmarks
    and tests import only its entry module sims.cli.main, except tests named test_cli_*.py, which test the
    command modules themselves."""
    offenders = []
    for name, path in _module_files().items():
        if not _is_cli(name):
            offenders += [f"{path.relative_to(ROOT)}:{line}: {n}" for n, line in _imports(path, name) if _is_cli(n)]
    for path in [*(ROOT / "benchmarks").rglob("*.py"), *(ROOT / "tests").rglob("*.py")]:
        if path.name.startswith("test_cli_") or path.name == "test_layers.py":
            continue
        offenders += [f"{path.relative_to(ROOT)}:{line}: {n}" for n, line in _imports(path, "")
                      if _is_cli(n) and n != "sims.cli.main" and not n.startswith("sims.cli.main.")]
    assert not offenders, offenders


def _module_graph():
    """The import graph of the four packages: an edge per import that runs, to the module that holds the name."""
    import networkx as nx

    files = _module_files()
    graph = nx.DiGraph()
    graph.add_nodes_from(files)
    for name, path in files.items():
        for target, line in _imports(path, name):
            while target and target not in files:  # a name inside a module -> that module
                target = target.rpartition(".")[0]
            if target and target != name:
                graph.add_edge(name, target, line=line)
    return graph


def test_no_import_cycle():
    """The modules of the four packages import one another without a cycle, function-local imports counted.

    (Function-local imports remain where they keep start-up fast, e.g. in the ``run()`` of each
    ``sims/cli`` command, but never to hide a circle: this test sees them.)
    """
    import networkx as nx

    graph = _module_graph()
    cycles = list(nx.simple_cycles(graph))
    shown = [" -> ".join(f"{a} (line {graph.edges[a, b]['line']})" for a, b in zip(c, c[1:] + c[:1]))
             for c in cycles[:5]]
    assert not cycles, shown


#: the parts of sims by role, and the parts each may import (docs/development.md draws the layout)
SIMS_ROLES = {
    "io": set(),
    "simulation": {"io"},
    "runners": {"io", "simulation"},
    "lab": {"io", "simulation", "runners"},
    "console": {"io", "simulation", "runners"},
    "cli": {"io", "simulation", "runners", "lab", "console"},
}


def test_every_sims_module_belongs_to_a_role():
    """sims holds only the role subpackages of SIMS_ROLES (no loose modules beside them)."""
    loose = [name for name in _module_files() if name.startswith("sims.") and name.split(".")[1] not in SIMS_ROLES]
    assert not loose, loose


def test_sims_roles_import_one_way():
    """Within sims, each role imports only the roles SIMS_ROLES allows it (io <- simulation <- runners <- lab,
    the console beside the lab, the CLI over all), function-local imports counted."""
    graph = _module_graph()
    offenders = []
    for a, b in graph.edges:
        if a.startswith("sims.") and b.startswith("sims."):
            ra, rb = a.split(".")[1], b.split(".")[1]
            if ra != rb and rb not in SIMS_ROLES.get(ra, set()):
                offenders.append(f"{a} (line {graph.edges[a, b]['line']}) -> {b}")
    assert not offenders, offenders
