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


def test_the_driver_asks_the_transport_not_its_model():
    """Outside sim/ and the simulator transports nothing reads a transport's ``model`` or
    ``models`` (the chip model is the simulator's business): Transport.clock_hz and
    Transport.chip_count say what the driver needs, and the simulators' strict, set_strict and
    take_violations what the pytest plugin needs."""
    import re
    pattern = re.compile(r"transport\.models?\b|[\"']models?[\"']")
    found = []
    for name, path in _modules().items():
        if name.startswith("lm629_host.sim") or name.startswith("lm629_host.transports.sim"):
            continue
        found += [f"{path.name}:{n}" for n, line in enumerate(path.read_text().splitlines(), 1)
                  if pattern.search(line)]
    assert found == []


def test_no_code_splits_an_exceptions_text():
    """Errors carry their parts (ArgumentError.argument, MotionError.reason/detail/axis,
    WaitTimeout.what): nothing cuts them out of a message."""
    import re
    pattern = re.compile(r"str\(\s*\w+\s*\)\s*\.\s*(split|rsplit|partition|rpartition)\b"
                         r"|\.args\[0\]\s*\.\s*(split|partition)")
    found = [f"{path.name}:{n}" for path in _modules().values()
             for n, line in enumerate(path.read_text().splitlines(), 1) if pattern.search(line)]
    assert found == []


def test_the_package_root_is_what_a_lab_script_needs():
    """``lm629_host.__all__`` is the curated set (docs/python.md lists it); no helper leaks
    into the root, the tuner loads on first use, and nothing of sim/ is imported."""
    code = (
        "import sys, types\n"
        "import lm629_host\n"
        "assert 'lm629_host.tuning' not in sys.modules, 'tuning imported eagerly'\n"
        "from lm629_host import Scale, autotune, emergency_stop, MotionError, MotionFault\n"
        "assert 'lm629_host.tuning' in sys.modules and autotune.__module__ == 'lm629_host.tuning'\n"
        "public = [n for n in dir(lm629_host) if (not n.startswith('_') or n == '__version__')\n"
        "          and not isinstance(getattr(lm629_host, n), types.ModuleType)]\n"
        "lazy = {'autotune', 'TuneResult'}\n"
        "print(sorted((set(public) - lazy) ^ (set(lm629_host.__all__) - lazy)))\n"
        "print(sorted(m for m in sys.modules if m.startswith('lm629_host.sim')))\n"
        "for name in ('query_params', 'split_params', 'transport_class', 'resolve_port'):\n"
        "    assert not hasattr(lm629_host, name), name\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:2] == ["[]", "[]"]
    import lm629_host
    from lm629_host import MotionError, MotionFault
    assert all(isinstance(r, MotionFault) for r in MotionError.REASONS)
    doc = (ROOT / "docs" / "python.md").read_text()
    missing = [n for n in lm629_host.__all__ if f"`{n}`" not in doc and n != "__version__"]
    assert missing == []
