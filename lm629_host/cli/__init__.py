"""``lm629``: the bench command line (the ``main`` group, :mod:`.app`), its commands in one
module per family: :mod:`.bench` (bringup, list, doctor, udev), :mod:`.chip` (status, reset,
filter, index, breakpoint, limit, watch, raw), :mod:`.motion` (move, velocity, stop, home),
:mod:`.tune` (step, tune), :mod:`.twin` (identify, twin check), :mod:`.wiring` (wiring, wiring --check), :mod:`.calc`,
:mod:`.bridge` (bridge list|flash), :mod:`.sim` (sim serve), :mod:`.profile` (--profile,
profile init|apply|show), :mod:`.scope`, :mod:`.shell`; :mod:`.types` holds the parameter
types and checks they share.

A new command is a function in its family's module decorated with ``@main.command()``.
"""

from __future__ import annotations

from . import bench, chip, motion, profile, scope, shell, wiring  # noqa: F401 - importing them registers their commands
from .app import EXIT_CODES, Session, Terminated, main
from .bridge import bridge
from .calc import calc
from .common import snapshot_dict
from .sim import sim
from .tune import tune
from .twin import identify_cmd, twin_group
from .types import parse_int

main.add_command(calc)
main.add_command(tune)
main.add_command(bridge)
main.add_command(sim)
main.add_command(identify_cmd)
main.add_command(twin_group)

__all__ = ["main", "EXIT_CODES", "Session", "Terminated", "parse_int", "snapshot_dict"]
