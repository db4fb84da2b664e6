"""Parameter types and checks of the ``lm629`` command line, shared by its command modules.

Why a module of its own: every number a bench user types reaches a motor.  ``inf``, ``nan``
and words that round to 0 must be refused with the option's name before the port is opened,
and a negative number must be taken as typed (``lm629 move -5000``), not as an unknown
option.  Commands that take signed positional numbers use :data:`SIGNED_ARGS` as their
context settings; their number types then turn a stray ``-x`` into "no such option".
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import click

#: context settings of a command whose positional arguments may be negative numbers:
#: click hands unknown "options" such as -5000 to the arguments, and the types below check them
SIGNED_ARGS: dict[str, Any] = {"ignore_unknown_options": True}

_NUMBER = re.compile(r"^[+-]?(\d|\.\d)")


def _not_an_option(value: str, param: Any, ctx: Any) -> None:
    """A stray ``--velo`` that click handed to the arguments: "no such option", with click's
    own suggestion of the command's closest options (``--vel``), as for any other command."""
    if value.startswith("-") and not _NUMBER.match(value):
        known = ([o for p in ctx.command.get_params(ctx) for o in (*p.opts, *p.secondary_opts)
                  if o not in ctx.help_option_names] if ctx is not None else None)
        raise click.NoSuchOption(value.split("=")[0], possibilities=known, ctx=ctx)


def parse_int(text: str) -> int:
    """Decimal, 0x hex, 0b binary; a trailing 'h' also means hex (datasheet style)."""
    t = text.strip().replace("_", "")
    neg = t.startswith("-")
    body = t[1:] if neg else t
    try:
        if body.lower().endswith("h") and not body.lower().startswith("0x"):
            v = int(body[:-1], 16)
        else:
            v = int(body, 0)
    except ValueError:
        raise click.BadParameter(f"{text!r} is not an integer (decimal, 0x.. hex, or ..h)") from None
    return -v if neg else v


class IntWord(click.ParamType):
    """An integer in decimal, hex (0x.., ..h) or binary; negative as typed."""

    name = "INT"

    def convert(self, value: Any, param: Any, ctx: Any) -> int:
        if isinstance(value, int):
            return value
        _not_an_option(str(value), param, ctx)
        return parse_int(str(value))


class Typed(float):
    """A number that remembers how it was typed, so that a message quotes the user's own
    ``2000000000`` (or ``0x100``), not ``2e+09``; arithmetic gives plain floats."""

    text: str

    def __new__(cls, value: float, text: str) -> Typed:
        obj = super().__new__(cls, value)
        obj.text = text
        return obj


def shown(value: float) -> str:
    """``value`` as the user typed it (a :class:`Typed`), else whole numbers in full and
    others in ``:g``."""
    text = getattr(value, "text", None)
    if isinstance(text, str):
        return text
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


class Finite(click.ParamType):
    """A finite float: ``inf`` and ``nan`` are refused with the option's name."""

    name = "NUMBER"

    def convert(self, value: Any, param: Any, ctx: Any) -> float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            x = float(value)
        else:
            _not_an_option(str(value), param, ctx)
            try:
                x = float(str(value).strip())
            except ValueError:
                try:
                    x = float(parse_int(str(value)))  # 0x100, 100h: counts in hex
                except click.BadParameter:
                    self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return x if isinstance(value, (int, float)) else Typed(x, str(value).strip())


INT = IntWord()
FINITE = Finite()


def positive(name: str, value: float | None) -> None:
    """Seconds, rates: > 0 (None passes)."""
    if value is not None and not value > 0:
        raise click.BadParameter(f"{shown(value)} must be positive", param_hint=name)


def check_writable(path: str | os.PathLike, name: str) -> Path:
    """An output file that can be written, checked before anything moves: its directory
    exists and is writable, and the file itself (if it exists) is a writable file."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise click.BadParameter(f"{str(p)!r}: the directory {str(parent)!r} does not exist",
                                 param_hint=name)
    if p.exists() and (p.is_dir() or not os.access(p, os.W_OK)):
        raise click.BadParameter(f"{str(p)!r} is not a writable file", param_hint=name)
    if not p.exists() and not os.access(parent, os.W_OK):
        raise click.BadParameter(f"cannot create {str(p)!r}: the directory is not writable",
                                 param_hint=name)
    return p


__all__ = ["FINITE", "INT", "SIGNED_ARGS", "Finite", "IntWord", "Typed", "check_writable",
           "parse_int", "positive", "shown"]
