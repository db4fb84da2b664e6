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

from lm629_host.chip.safety import Terminated
from lm629_host.cli.app import EXIT_CODES, Session, main
from lm629_host.cli.common import snapshot_dict
from lm629_host.cli.types import parse_int


__all__ = ["main", "EXIT_CODES", "Session", "Terminated", "parse_int", "snapshot_dict"]
