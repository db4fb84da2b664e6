"""Which family module registers which ``lm629`` command, and the group that imports a family
only when one of its commands is asked for (click's "lazily loading subcommands").

Why: importing every family at startup cost each ``lm629`` run ~45 ms (the panel's web server,
importlib.metadata, the tuner...), paid by every command and every test that starts one.
"""

from __future__ import annotations

import importlib
from typing import Any

import click

#: command (or group) name -> the module of :mod:`lm629_host.cli` whose import registers it
#: (``@main.command()``): the one table of what ``lm629`` has.  A family is imported when one of
#: its commands runs (or ``--help`` lists them), never at startup (tests/cli/test_cli_lazy.py
#: holds the table to what the families register)
COMMAND_FAMILIES: dict[str, str] = {
    "bringup": "bench", "list": "bench", "doctor": "bench", "udev": "bench",
    "bridge": "bridge",
    "calc": "calc",
    "status": "chip", "clear": "chip", "reset": "chip", "filter": "chip", "index": "chip",
    "breakpoint": "chip", "limit": "chip", "watch": "chip", "raw": "chip",
    "lab": "lab",
    "move": "motion", "velocity": "motion", "stop": "motion", "home": "motion",
    "panel": "panel",
    "profile": "profile",
    "scope": "scope",
    "selftest": "selftest",
    "shell": "shell",
    "sigrok": "sigrok",
    "sim": "sim",
    "tune": "tune", "step": "tune",
    "identify": "twin", "twin": "twin",
    "wiring": "wiring",
}

#: click >= 8.4 raises this for an unknown command, with its "Did you mean" suggestions
_NO_SUCH_COMMAND: tuple[type[Exception], ...] = tuple(
    c for c in (getattr(click.exceptions, "NoSuchCommand", None),) if c is not None)


class LazyGroup(click.Group):
    """A click group whose commands are ``lazy_commands`` (name -> family module of this
    package, as :data:`COMMAND_FAMILIES`) besides those already registered: a family is
    imported when one of its names is asked for, and its import registers the command on the
    group.

    ``commands`` holds only what is loaded so far; ``list_commands`` and ``get_command`` (what
    click, ``--help`` and ``lm629 panel`` use) see every command."""

    def __init__(self, *args: Any, lazy_commands: dict[str, str] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self.commands, *self.lazy_commands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        family = self.lazy_commands.get(cmd_name)
        if family is not None and cmd_name not in self.commands:
            importlib.import_module(f"{__package__}.{family}")  # registers its commands
            if cmd_name not in self.commands:
                raise RuntimeError(f"{__package__}.{family} registers no command {cmd_name!r}, "
                                   f"as {__name__}.COMMAND_FAMILIES says it does")
        return super().get_command(ctx, cmd_name)

    def resolve_command(self, ctx: click.Context,
                        args: list[str]) -> tuple[str | None, click.Command | None, list[str]]:
        """click suggests a near name ("Did you mean 'status'?") from the commands loaded so
        far: here from every command, loaded or not."""
        try:
            return super().resolve_command(ctx, args)
        except _NO_SUCH_COMMAND as exc:
            name = getattr(exc, "command_name", args[0])
            raise type(exc)(name, possibilities=self.list_commands(ctx),  # type: ignore[call-arg]  # NoSuchCommand, typed as Exception
                            ctx=ctx) from None
