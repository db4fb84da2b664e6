"""``lm629``'s commands load lazily: ``lm629_host.cli.families.COMMAND_FAMILIES`` (name ->
family module) is what ``main`` lists, and a family is imported when one of its commands is
asked for.

The table is checked against what the families really register (a command left out of it
would vanish from ``lm629``), and a command's run against the modules it loads, in a fresh
interpreter (this one has imported everything by now).
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import subprocess
import sys

import click

import lm629_host.cli
from lm629_host.cli.app import main
from lm629_host.cli.families import COMMAND_FAMILIES


def _fresh(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)


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
    the lab, the tuner or the other families (nor importlib.metadata: sim:// is built in)."""
    code = ("import json, sys\n"
            "before = set(sys.modules)\n"
            "from lm629_host.cli import main\n"
            "main(['--port', 'sim://', 'status'], standalone_mode=False)\n"
            "print(json.dumps(sorted(set(sys.modules) - before)))\n")
    r = _fresh(code)
    assert r.returncode == 0, r.stderr
    loaded = set(json.loads(r.stdout.splitlines()[-1]))
    assert "status" in r.stdout and "lm629_host.cli.chip" in loaded
    families = {f"lm629_host.cli.{f}" for f in COMMAND_FAMILIES.values()}
    assert families & loaded == {"lm629_host.cli.chip"}
    assert "http.server" not in loaded
    # a built-in port scheme is opened without reading the installed packages' entry points
    assert "importlib.metadata" not in loaded


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
