"""``lm629``: the bench command line: the ``main`` group (:mod:`.app`) and its commands, one
module per family (:mod:`.bench`, :mod:`.chip`, :mod:`.motion`, :mod:`.tune`, :mod:`.twin`...);
:mod:`.types` holds the parameter types and checks they share.

A new command is a function in its family's module decorated with ``@main.command()``, and a
row in :data:`.families.COMMAND_FAMILIES` (command name -> family), the one list of what
``lm629`` has: ``main`` imports a family when one of its commands is asked for, not at startup.  So
``main.commands`` holds only the families loaded so far; ``main.list_commands(ctx)`` and
``main.get_command(ctx, name)`` see every command.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from lm629_host.cli.app import EXIT_CODES, Session, main

if TYPE_CHECKING:
    from lm629_host.chip.safety import Terminated
    from lm629_host.cli.common import snapshot_dict
    from lm629_host.cli.types import parse_int

#: the other names -> their module, imported when first asked for: every ``lm629`` start imports
#: this package, and ``cli.common`` brings the whole driver (``lm629 sim serve`` needs none)
_LAZY = {"Terminated": "lm629_host.chip.safety", "snapshot_dict": "lm629_host.cli.common",
         "parse_int": "lm629_host.cli.types"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["main", "EXIT_CODES", "Session", "Terminated", "parse_int", "snapshot_dict"]
