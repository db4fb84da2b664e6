"""The package's layout keeps its rules: no import circles, every transport in transports/, and
the simulated parts (lm629_host/sim/) reached by the driver only through the simulator URLs."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "lm629_host"

#: the modules outside sim/ that may import it: the simulator transports and `lm629 sim serve`
SIM_DOORS = {"lm629_host.transports.sim", "lm629_host.transports.simavr",
             "lm629_host.transports.simftdi", "lm629_host.transports.simemu",
             "lm629_host.cli.sim"}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PKG.rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(name: str, path: Path, modules: dict[str, Path], *, typing: bool = True) -> set[str]:
    """The lm629_host modules ``name`` imports: at module level, in a function, and (unless
    ``typing`` is False) under ``if TYPE_CHECKING``: a circle of annotations is a circle too."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if not typing and isinstance(child, ast.If) and _is_type_checking(child):
                for orelse in child.orelse:
                    visit(orelse)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")
                    base = base[:len(base) - (child.level - 1)]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module or ""
                for a in child.names:
                    sub = f"{mod}.{a.name}"
                    found.add(sub if sub in modules else mod)
            visit(child)

    visit(ast.parse(path.read_text()))
    return {m for m in found if m in modules and m != name}


def _graph(typing: bool = True) -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules, typing=typing) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for v in graph:
        if v not in index:
            strong(v)
    return out


def test_no_import_circles():
    graph = _graph()
    assert "lm629_host.lm629" in graph and graph["lm629_host.cli"]  # the walk sees the package
    assert _cycles(graph) == []


def test_the_circle_finder_finds_one():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_only_the_simulator_doors_import_sim():
    graph = _graph()
    graph = _graph(typing=False)  # what runs
    callers = {m for m, deps in graph.items() if not m.startswith("lm629_host.sim")
               and any(d == "lm629_host.sim" or d.startswith("lm629_host.sim.") for d in deps)}
    assert callers == SIM_DOORS


def test_the_driver_loads_no_simulator():
    """Importing the package, the CLI and the hardware transports loads nothing of sim/."""
    code = ("import sys, lm629_host, lm629_host.cli\n"
            "from lm629_host.transports import transport_class\n"
            "for url in ('serial:///dev/ttyACM0', 'ftdi://ftdi:232h/1'):\n"
            "    transport_class(url)\n"
            "print(sorted(m for m in sys.modules if m.startswith('lm629_host.sim')))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]"


def test_every_transport_is_in_transports():
    import importlib
    import importlib.util
    import pkgutil

    import lm629_host
    from lm629_host.transports.base import Transport

    for info in pkgutil.walk_packages(lm629_host.__path__, "lm629_host."):
        if info.name.endswith("__main__"):  # that one runs the CLI
            continue
        if info.name == "lm629_host.labgrid_driver" and importlib.util.find_spec("labgrid") is None:
            continue  # the optional extra, in a venv of its own (tests/test_labgrid.py)
        importlib.import_module(info.name)
    seen, todo = set(), [Transport]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            if sub not in seen:
                seen.add(sub)
                todo.append(sub)
    ours = {c for c in seen if c.__module__.startswith("lm629_host.")}
    assert len(ours) >= 8
    assert {c.__module__ for c in ours if not c.__module__.startswith("lm629_host.transports.")} == set()
