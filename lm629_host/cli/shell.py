"""``lm629 shell``: Python on the open board, the profile applied.

Bound names: ``board`` (the :class:`~lm629_host.Board`), ``lm629_host``, ``Status``,
``Signals``, ``chip`` (the first axis of the command) and each axis by its profile name
(``x``), or ``axis0``, ``axis1``... without a profile.  IPython when it is installed, else
the standard console; when stdin is not a terminal the text read from it is run as one script
(``echo "print(x.read_real_position())" | lm629 --profile bench.toml shell``).

A script that fails stops the axes that are moving (never a servo holding position), prints
its traceback and exits with the code of the error (:data:`.app.EXIT_CODES`; 1 for an error
of the script's own).
"""

from __future__ import annotations

import code
import sys
import traceback
from typing import Any

import click

import lm629_host

from lm629_host.bus.opcodes import Signals, Status
from lm629_host.chip.safety import emergency_stop
from lm629_host.cli.app import _ERROR_EXITS, _session, axes_of, board, main


#: the names the shell binds besides the axes: a profile axis may not take one of them
SHELL_NAMES = ("board", "chip", "lm629_host", "Status", "Signals")


def namespace(s: Any, b: Any) -> dict[str, Any]:
    """The names the shell binds: the command's axes (the profile's, ``--axis``, the URL's
    ``axes=``; else axis 0, as every command), never a chip select the board has but no chip
    is known on.  click.BadParameter for a profile axis that would hide a shell name."""
    ns: dict[str, Any] = {"board": b, "lm629_host": lm629_host, "Status": Status,
                          "Signals": Signals}
    prof = s.profile
    chosen = list(axes_of(s))
    for cs in chosen:
        ax = prof.by_cs(cs) if prof is not None else None
        name = ax.name if ax is not None else f"axis{cs}"
        if name in SHELL_NAMES:
            raise click.BadParameter(
                f"axis {name!r} of {prof.path} would hide the shell's own `{name}` "
                f"({', '.join(SHELL_NAMES)}): rename the axis in the profile", param_hint="--profile")
        ns[name] = b.axes[cs]
    ns["chip"] = b.axes[chosen[0]] if chosen else b.axes[0]
    return ns


def _stop_moving(b: Any, names: dict[int, str]) -> None:
    """Stop the shell's axes (``names``: chip select -> name) whose trajectory runs with the
    drive on (a holding servo is left on), one line each on stderr."""
    for cs, name in names.items():
        a = b.axes[cs]
        try:
            moving = a.is_moving()
        except Exception as exc:  # noqa: BLE001 - the link may be what failed: try the others
            click.echo(f"lm629: {name}: could not tell whether it moves ({exc})", err=True)
            continue
        if moving:
            click.echo(f"lm629: {name} was moving: {emergency_stop(a)[1]}", err=True)


@main.command()
def shell() -> None:
    """Python with `board`, `lm629_host`, `Status` and each axis by its name (the profile
    applied); a script piped into stdin is run."""
    s = _session()
    b = board(s)
    ns = namespace(s, b)
    names = ", ".join(k for k in ns if k not in ("lm629_host", "Status", "Signals"))
    names_of = {chip.chip_select: k for k, chip in ns.items()
                if k not in ("chip", "board") and isinstance(chip, lm629_host.LM629)}
    if not sys.stdin.isatty():
        source = sys.stdin.read()
        try:
            exec(compile(source, "<stdin>", "exec"), ns)
        except (KeyboardInterrupt, click.exceptions.Exit):
            _stop_moving(b, names_of)
            raise
        except Exception as exc:  # noqa: BLE001 - the script's own errors, reported below
            traceback.print_exc()
            _stop_moving(b, names_of)
            code_ = next((c for cls, c in _ERROR_EXITS if isinstance(exc, cls)), 1)
            click.get_current_context().exit(code_)
        return
    banner = (f"lm629 shell on {s.port}: {names} "
              f"(+ lm629_host, Status, Signals)")
    try:
        from IPython import start_ipython
    except ImportError:
        start_ipython = None
    if start_ipython is None:  # outside the except: a traceback in the console has no chain
        code.interact(banner=banner + "; Ctrl-D ends", local=ns, exitmsg="")
        return
    click.echo(banner)
    start_ipython(argv=["--no-banner"], user_ns=ns)


__all__ = ["SHELL_NAMES", "namespace", "shell"]
