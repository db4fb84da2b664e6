"""The package's layout keeps its rules: no import circles, every transport in transports/, and
the simulated parts (lm629_host/sim/) reached by the driver only through the simulator URLs."""

from __future__ import annotations

import ast
import functools
import io
import re
import subprocess
import sys
import tokenize
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

    visit(_parse(path))
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
    assert "lm629_host.chip.lm629" in graph and graph["lm629_host.cli"]  # the walk sees the package
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
    """Importing the package, the CLI (every command family) and the hardware transports
    loads nothing of sim/."""
    code = ("import importlib, sys, lm629_host, lm629_host.cli\n"
            "from lm629_host.cli.families import COMMAND_FAMILIES\n"
            "for family in set(COMMAND_FAMILIES.values()):\n"  # the commands load lazily: every one
            "    importlib.import_module('lm629_host.cli.' + family)\n"
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
        if info.name == "lm629_host.integrations.labgrid_driver" and importlib.util.find_spec("labgrid") is None:
            continue  # the optional extra, in a venv of its own (tests/integrations/test_labgrid.py)
        if info.name.startswith("lm629_host.sigrok.lm629"):
            continue  # the sigrok decoder runs inside libsigrokdecode, which provides its import
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
        "assert 'lm629_host.bench.tuning' not in sys.modules, 'tuning imported eagerly'\n"
        "assert 'lm629_host.urls' not in sys.modules, 'urls imported eagerly'\n"
        "assert lm629_host.urls.port_url('sim://').scheme == 'sim'  # a submodule, as before\n"
        "from lm629_host import Scale, autotune, emergency_stop, MotionError, MotionFault\n"
        "assert 'lm629_host.bench.tuning' in sys.modules and autotune.__module__ == 'lm629_host.bench.tuning'\n"
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
    # the names load on first use: a type checker (and an editor) sees each from its home
    tree = ast.parse(Path(lm629_host.__file__).read_text())
    typed = {a.asname or a.name for node in tree.body if isinstance(node, ast.If)
             and "TYPE_CHECKING" in ast.unparse(node.test)
             for imp in node.body if isinstance(imp, ast.ImportFrom) for a in imp.names}
    assert set(lm629_host.__all__) - {"open", "__version__"} <= typed


# ---------------------------------------------------------------------- grep-level rules
#: the modules that may open a simulator URL: the simulator transports, sim/ and `lm629 sim`
#: ``lm629 twin check`` opens a simulator by design: the twin of the user's axis is one; so
#: does ``lm629 selftest``: the model it compares the chip with is one
SIM_OPENERS = ("lm629_host.transports.sim", "lm629_host.sim", "lm629_host.cli.sim",
               "lm629_host.cli.twin", "lm629_host.bench.selftest")
#: a URL of a simulated bench at the start of a string: ``sim://``, ``sim+emu://``...
SIM_URL = re.compile(r"sim(\+\w+)?://")
#: an issue number: the word issue (or issues) and a number, or a hash sign and a number
ISSUE_NUMBER = re.compile(r"\bissues?\s+#?\d+|(?<![\w&/])#\d+\b", re.IGNORECASE)


def _trees() -> dict[str, tuple[Path, ast.Module]]:
    return {name: (path, _parse(path)) for name, path in _modules().items()}


def _is_self(node: ast.AST) -> bool:
    return isinstance(node, ast.Name) and node.id in ("self", "cls")


def _private_reach(tree: ast.Module) -> list[int]:
    """Lines where code reads another object's whole state (``vars(x)``, ``x.__dict__``) or
    sets one of its private fields by name (``setattr(x, "_f", v)``): either makes that
    object's private fields the caller's business."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.args:
            target, name = node.args[0], node.args[1] if len(node.args) > 1 else None
            if node.func.id == "vars" and not _is_self(target):
                lines.append(node.lineno)
            elif node.func.id in ("setattr", "delattr") and not _is_self(target) and (
                    isinstance(name, ast.Constant) and str(name.value).startswith("_")):
                lines.append(node.lineno)
        elif isinstance(node, ast.Attribute) and node.attr == "__dict__" and not _is_self(node.value):
            lines.append(node.lineno)
    return lines


#: names with a leading underscore that are public API of the standard library
_STDLIB_UNDERSCORED = frozenset({"_replace", "_asdict", "_fields", "_make", "_field_defaults",
                                 "_exit", "_getframe"})


def _own_names(tree: ast.Module) -> set[str]:
    """Every name a module defines: its functions, classes, module and local names, imported
    names, and the fields its classes set on ``self`` or ``cls``."""
    names: set[str] = set()
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(n.name)
        elif isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store) and _is_self(n.value):
            names.add(n.attr)
        elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
            names.add(n.id)
        elif isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name):
            names.add(n.target.id)
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in n.names)
    return names


def _foreign_private(tree: ast.Module) -> list[tuple[int, str]]:
    """``obj._name`` where ``obj`` is not ``self``, ``cls`` or ``super()`` and no class or
    function of this module defines ``_name``: a read or write of another module's object's
    private state (a module's own private name used on a copy of its own object, or a nested
    private class, stays that module's business)."""
    own = _own_names(tree)
    out = []
    for n in ast.walk(tree):
        if not (isinstance(n, ast.Attribute) and n.attr.startswith("_")
                and not n.attr.endswith("__") and n.attr not in _STDLIB_UNDERSCORED
                and n.attr not in own):
            continue
        v = n.value
        if _is_self(v) or (isinstance(v, ast.Call) and isinstance(v.func, ast.Name)
                           and v.func.id == "super"):
            continue
        out.append((n.lineno, ast.unparse(n)))
    return out


def test_the_foreign_private_rule_finds_a_reach_in():
    tree = ast.parse("class A:\n    def __init__(self):\n        self._own = 1\n"
                     "    def f(self, other, link):\n        other._own = 2\n"
                     "        link._resync()\n        self._x()\n        super()._y()\n"
                     "        return t._replace(a=1), os._exit, link.__class__\n")
    assert _foreign_private(tree) == [(6, "link._resync")]


def test_no_module_reaches_into_another_modules_objects_private_state():
    """Parts talk through public interfaces: no ``obj._name`` on another module's object
    (the link's parts use its session's public interface, the chip layer the transport's)."""
    found = [f"{path.relative_to(ROOT)}:{line}: {text}" for path, tree in _trees().values()
             for line, text in _foreign_private(tree)]
    assert found == []


def _execute_assigned(tree: ast.Module) -> list[int]:
    """Lines that replace a transport's ``execute`` (an assignment, or setattr by name)."""
    lines = []
    for node in ast.walk(tree):
        targets: list[ast.expr] = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                node.func.id == "setattr" and len(node.args) > 1 and \
                isinstance(node.args[1], ast.Constant) and node.args[1].value == "execute":
            lines.append(node.lineno)
        lines += [node.lineno for t in targets for a in ast.walk(t)
                  if isinstance(a, ast.Attribute) and a.attr == "execute"]
    return lines


def _sim_opened(tree: ast.Module) -> list[int]:
    """Lines that pass a simulator URL (a string or f-string starting ``sim://``, ``sim+x://``)
    to a call: ``open_transport("sim://...")``, ``lm629_host.open(f"sim://?wiring={w}")``."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        for arg in node.args:
            text = arg.value if isinstance(arg, ast.Constant) else (
                arg.values[0].value if isinstance(arg, ast.JoinedStr) and arg.values
                and isinstance(arg.values[0], ast.Constant) else None)
            if isinstance(text, str) and SIM_URL.match(text):
                lines.append(node.lineno)
    return lines


@functools.cache
def _parse(path: Path) -> ast.Module:
    """A module's tree, parsed once per test process: a dozen rules read every module (the
    trees are only read, never changed)."""
    return ast.parse(path.read_text())


def _comments_and_docstrings(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every comment and docstring of a file."""
    source = path.read_text()
    out = [(t.start[0], t.string) for t in tokenize.generate_tokens(io.StringIO(source).readline)
           if t.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc is not None:
                first = node.body[0].lineno
                out += [(first + k, line) for k, line in enumerate(doc.splitlines())]
    return out


def test_the_grep_rules_find_what_they_look_for():
    """Each rule below, on a few lines that break it and a few that do not."""
    tree = ast.parse("vars(chip)\nvars(self)\nsetattr(chip, '_ds', 4)\nsetattr(chip, 'limits', x)\n"
                     "setattr(self, '_x', 1)\nx = other.__dict__\n")
    assert _private_reach(tree) == [1, 3, 6]
    tree = ast.parse("t.execute = hook\nt.execute(p)\nsetattr(t, 'execute', hook)\nx = t.executed\n")
    assert _execute_assigned(tree) == [1, 3]
    tree = ast.parse("open_transport(f'sim://?wiring={w}')\nlm629_host.open('sim+emu://')\n"
                     "DEFAULT = 'sim://'\nopen(url)\nclick.echo('use sim:// for a simulator')\n")
    assert _sim_opened(tree) == [1, 2]
    found = [bool(ISSUE_NUMBER.search(t)) for t in (
        "see issue 12", "issues 3 and 4", "(changed, #15)", "Issue 20's tuner", "#: a field",
        "# no" + "qa: E402", "colour #1f77b4", "the 2nd issue of a series", "url#15")]
    assert found == [True, True, True, True, False, False, False, False, False]


def test_no_class_reaches_into_another_objects_private_fields():
    found = [f"{path.relative_to(ROOT)}:{n}" for path, tree in _trees().values()
             for n in _private_reach(tree)]
    assert found == []


def test_only_transports_assign_execute():
    found = [f"{path.relative_to(ROOT)}:{n}" for name, (path, tree) in _trees().items()
             if not name.startswith("lm629_host.transports.") for n in _execute_assigned(tree)]
    assert found == []


def test_only_the_simulator_opens_a_simulator_url():
    """Library code that diagnoses or drives a bench never opens a simulated one: only the
    simulator transports, sim/ and `lm629 sim` pass a simulator URL to anything."""
    found = [f"{path.relative_to(ROOT)}:{n}" for name, (path, tree) in _trees().items()
             if not name.startswith(SIM_OPENERS) for n in _sim_opened(tree)]
    assert found == []


def test_no_class_name_is_defined_twice():
    seen: dict[str, list[str]] = {}
    for path, tree in _trees().values():
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                seen.setdefault(node.name, []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert {k: v for k, v in seen.items() if len(v) > 1} == {}


def test_no_issue_number_in_a_comment_or_docstring():
    """Comments and docstrings say why; which issue asked for something is the commit
    message's business (and means nothing to a reader of the code)."""
    paths = [p for p in _modules().values()] + sorted((ROOT / "tests").glob("*.py"))
    found = [f"{path.relative_to(ROOT)}:{n}: {text.strip()[:60]}" for path in paths
             for n, text in _comments_and_docstrings(path) if ISSUE_NUMBER.search(text)]
    assert found == []


#: the layers, bottom first: a module imports only from its own layer and those below it.
#: The foundations (errors, clock, urls) are top-level modules every layer uses; the package
#: root is the top.
LAYERS: list[tuple[str, ...]] = [
    ("errors", "clock", "urls", "data"),
    ("bus",),  # the chip's bus: opcodes, pins, bus programs, the snapshot
    ("physics",),  # PID, motor, plans, soft limits, units: arithmetic, no I/O
    ("config",),  # the bench profile as data
    ("wiring",),  # pin maps of the adapters and the wiring-fault vocabulary
    ("bridge",),  # the serial bridge's link protocol, shared with the firmware and far end
    ("sim",),  # the simulated chip, motor, far ends and adapters
    ("transports",),  # the ports, and what settles a URL into one
    ("chip",),  # the typed command layer: LM629, moves, waits, recordings, batches
    ("motion",),  # several axes on one bus
    ("bench",),  # bring-up, tuning, capture, scope, wiring check and drawing
    # the doors, the sigrok decoder (loaded by libsigrokdecode, imports nothing of ours), and
    # the root
    ("cli", "panel", "integrations", "sigrok", "__main__", ""),
]


def _layer_of(module: str) -> int:
    part = module.split(".")[1] if "." in module else ""
    for i, names in enumerate(LAYERS):
        if part in names:
            return i
    raise AssertionError(f"{module} is in no layer of tests/test_layout.py's LAYERS")


def test_every_import_points_down_the_layers():
    """``bus`` <- ``physics`` <- ``wiring`` <- ``bridge`` <- ``sim`` <- ``transports`` <-
    ``chip`` <- ``motion`` <- ``bench`` <- ``cli``: no module imports from a layer above its
    own, type-checking imports included."""
    graph = _graph()
    up = sorted(f"{m} -> {d}" for m, deps in graph.items() for d in deps
                if _layer_of(d) > _layer_of(m))
    assert up == []


def test_the_layer_rule_sees_an_upward_import():
    assert _layer_of("lm629_host.chip.lm629") > _layer_of("lm629_host.transports.base")
    assert _layer_of("lm629_host.bus.opcodes") < _layer_of("lm629_host.sim.model.chip")


def test_at_most_eight_modules_at_the_top():
    """The package's top level holds its subpackages, ``__init__``/``__main__`` and the
    foundations: a new module goes in the layer it belongs to."""
    top = sorted(p.stem for p in PKG.glob("*.py") if p.stem not in ("__init__", "__main__"))
    assert len(top) <= 8, top


def test_every_command_is_registered_one_way():
    """A command is a function in its family's module under ``@main.command()`` (or a group
    under ``@main.group()``): no ``add_command`` lines elsewhere, no top-level ``@click.command``
    waiting to be added, no hook table standing in for an import (``COMMAND_FAMILIES`` in
    cli/families.py names the family whose import registers each command:
    tests/cli/test_cli_lazy.py)."""
    found = []
    for path in sorted((PKG / "cli").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "add_command":
                found.append(f"{path.name}:{node.lineno}: add_command")
            if isinstance(node, ast.Name) and node.id == "HOOKS":
                found.append(f"{path.name}:{node.lineno}: HOOKS")
        for node in tree.body:
            if isinstance(node, ast.FunctionDef):
                for d in node.decorator_list:
                    f = d.func if isinstance(d, ast.Call) else d
                    if (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                            and f.value.id == "click" and f.attr in ("command", "group")
                            and node.name != "main"):  # the group itself
                        found.append(f"{path.name}:{node.lineno}: @click.{f.attr} on {node.name}")
    assert not found, found
    import click

    from lm629_host.cli import main
    ctx = click.Context(main, info_name="lm629")
    names = {"tune", "calc", "bridge", "sim", "sigrok", "identify", "twin", "selftest"}
    assert names <= set(main.list_commands(ctx))
    assert all(main.get_command(ctx, name) is not None for name in names)


#: a module's length and a class's, in lines: a room past these has more than one job
MODULE_LINES_MAX = 600
CLASS_LINES_MAX = 450
#: rooms still past them, each at most its size when this guard came in (none may grow), and
#: why; a room leaves this list when it is split by job
OVERSIZE: dict[str, int] = {}


def _oversize() -> list[str]:
    found = []
    for path in sorted(PKG.rglob("*.py")):
        rel = str(path.relative_to(ROOT))
        text = path.read_text(encoding="utf-8")
        n = len(text.splitlines())
        if n > OVERSIZE.get(rel, MODULE_LINES_MAX):
            found.append(f"{rel}: {n} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                size = (node.end_lineno or node.lineno) - node.lineno + 1
                if size > OVERSIZE.get(node.name, CLASS_LINES_MAX):
                    found.append(f"{rel}: class {node.name} {size} lines")
    return found


def test_no_room_has_several_jobs():
    """Every module of lm629_host within ``MODULE_LINES_MAX`` lines and every class within
    ``CLASS_LINES_MAX`` (a room past them has grown a second job: split it by job, as chip/
    and bench/ are), but for the rooms of ``OVERSIZE``, which may not grow."""
    assert _oversize() == []


def test_the_size_guard_sees_a_big_room(tmp_path, monkeypatch):
    pkg = tmp_path / "lm629_host"
    pkg.mkdir()
    (pkg / "big.py").write_text("x = 1\n" * (MODULE_LINES_MAX + 1))
    (pkg / "room.py").write_text("class Room:\n" + "    x = 1\n" * CLASS_LINES_MAX)
    monkeypatch.setattr(sys.modules[__name__], "PKG", pkg)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _oversize() == [f"lm629_host/big.py: {MODULE_LINES_MAX + 1} lines",
                           f"lm629_host/room.py: class Room {CLASS_LINES_MAX + 1} lines"]
