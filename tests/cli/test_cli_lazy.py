"""``lm629``'s commands load lazily: ``lm629_host.cli.families.COMMAND_FAMILIES`` (name ->
family module) is what ``main`` lists, and a family is imported when one of its commands is
asked for.

The table is checked against what the families really register (a command left out of it
would vanish from ``lm629``), and a command's run against the modules it loads, in a fresh
interpreter (this one has imported everything by now): the package's names, the driver, the
profile's parser and the rest load when a command uses them (lm629_host/__init__.py), so that
an ``lm629`` start, which the bench's scripts and this suite pay hundreds of times, costs only
what it runs.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import subprocess
import sys

import click

import lm629_host.cli
from lm629_host.cli.app import main
from lm629_host.cli.families import COMMAND_FAMILIES
from served import _sim_serve

#: what a command imports only when it uses it: the profile's parser (--profile; tempfile only
#: to save one), the board (several axes, a profile), the S-curve shapes, json (--json), the
#: bring-up and the tuner (their commands), statistics (nothing on these paths)
ONLY_WHEN_USED = frozenset({
    "lm629_host.config.profile", "tomllib", "tempfile", "lm629_host.motion.board",
    "lm629_host.chip.shapes", "json", "lm629_host.bench.bringup", "lm629_host.bench.tuning",
    "statistics"})


def _fresh(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)


def _loaded_by(argv: list[str], before_main: str = "") -> tuple[str, set[str]]:
    """(stdout, the modules it imported) of ``lm629 ARGV`` in a fresh interpreter (nothing
    imported first that the count would miss: the list is printed as a Python literal)."""
    code = ("import sys\n"
            "before = set(sys.modules)\n"
            "from lm629_host.cli import main\n"
            f"{before_main}"
            f"code = main({argv!r}, standalone_mode=False)\n"
            "print(sorted(set(sys.modules) - before))\n"
            "sys.exit(code or 0)\n")
    r = _fresh(code)
    assert r.returncode == 0, r.stderr
    out, _, last = r.stdout.rstrip("\n").rpartition("\n")
    return out, set(ast.literal_eval(last))


def _simulator(loaded: set[str]) -> set[str]:
    return {m for m in loaded if m == "lm629_host.sim" or m.startswith("lm629_host.sim.")
            or m.startswith("lm629_host.transports.sim")}


def test_the_table_is_every_command_the_families_register_and_where():
    """Import every module of lm629_host.cli: the commands ``main`` then holds, each by the
    module its function is in, are the table's rows, no more, no fewer."""
    for mod in pkgutil.iter_modules(lm629_host.cli.__path__):
        importlib.import_module(f"lm629_host.cli.{mod.name}")
    registered = {name: cmd.callback.__module__.rpartition(".")[2]
                  for name, cmd in main.commands.items() if cmd.callback is not None}
    assert set(registered) == set(main.commands)  # every command has its function
    assert registered == COMMAND_FAMILIES
    ctx = click.Context(main, info_name="lm629")
    assert main.list_commands(ctx) == sorted(COMMAND_FAMILIES)  # as click sorts them in --help


def test_status_loads_its_family_only():
    """``lm629 --port sim:// status`` imports lm629_host.cli.chip, not the panel's web server,
    the lab, the tuner or the other families (nor importlib.metadata: sim:// is built in), nor
    what it does not run (:data:`ONLY_WHEN_USED`: no profile given, no --json)."""
    out, loaded = _loaded_by(["--port", "sim://", "status"])
    assert "status" in out and "lm629_host.cli.chip" in loaded
    families = {f"lm629_host.cli.{f}" for f in COMMAND_FAMILIES.values()}
    assert families & loaded == {"lm629_host.cli.chip"}
    assert "http.server" not in loaded
    # a built-in port scheme is opened without reading the installed packages' entry points
    assert "importlib.metadata" not in loaded
    assert loaded & ONLY_WHEN_USED == set()


def test_commands_on_a_bench_load_no_simulator():
    """On a bench behind ser2net (here ``lm629 sim serve --tcp``, in its own process), the
    commands the bench's scripts run most, ``status``, ``reset``, ``filter`` and ``move``,
    import neither the simulator (lm629_host.sim, the sim:// transport: they drive a board)
    nor what they do not run (:data:`ONLY_WHEN_USED`)."""
    with _sim_serve() as url:
        for args in (["status"], ["reset"], ["filter", "--kp", "20", "--ds", "1"],
                     ["move", "100"]):
            out, loaded = _loaded_by(["--port", url, *args])
            assert "lm629_host.transports.serial" in loaded, (args, out)
            assert _simulator(loaded) == set(), args
            assert loaded & ONLY_WHEN_USED == set(), args


def test_version_loads_no_driver():
    """``lm629 --version`` opens no chip: it imports no driver (lm629_host.chip.lm629) and no
    simulator."""
    out, loaded = _loaded_by(["--version"])
    assert "version" in out
    assert "lm629_host.chip.lm629" not in loaded and _simulator(loaded) == set()
    assert loaded & ONLY_WHEN_USED == set()


def test_sim_serve_loads_no_driver():
    """``lm629 sim serve`` is the simulated bench, not a client of one: it imports no driver
    (lm629_host.chip.lm629), whose import every served test's bench paid at its start."""
    # SIGTERM once `sim serve` installed its handler (it serves), as a user's Ctrl-C or kill
    stop = ("import os, signal, threading, time\n"
            "def stop():\n"
            "    while getattr(signal.getsignal(signal.SIGTERM), '__module__', None) != 'lm629_host.cli.sim':\n"
            "        time.sleep(0.01)\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "threading.Thread(target=stop, daemon=True).start()\n")
    out, loaded = _loaded_by(["sim", "serve", "--tcp", "127.0.0.1:0"], before_main=stop)
    assert out.startswith("serving ") and "stopped" in out, out
    assert "lm629_host.sim.serve" in loaded and "lm629_host.chip.lm629" not in loaded
    assert loaded & ONLY_WHEN_USED == set()


def test_a_fresh_lm629_lists_and_suggests_every_command():
    """With nothing loaded yet: ``--help`` lists every command, and a misspelt one gets
    click's "Did you mean" from all of them (click takes it from the commands loaded)."""
    r = subprocess.run([sys.executable, "-m", "lm629_host", "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    section = r.stdout.split("Commands:\n")[1].split("\n\n")[0]
    listed = [line.split()[0] for line in section.splitlines()
              if line.startswith("  ") and not line.startswith("   ")]
    assert listed == sorted(COMMAND_FAMILIES)
    r = subprocess.run([sys.executable, "-m", "lm629_host", "wirng"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2
    if hasattr(click.exceptions, "NoSuchCommand"):  # click >= 8.4 suggests
        assert "No such command 'wirng'." in r.stderr and "'wiring'?" in r.stderr, r.stderr
