"""``lm629``: the bench command line (the ``main`` group, :mod:`.app`), its commands in one
module per family: :mod:`.bench` (bringup, list, doctor, udev), :mod:`.chip` (status, reset,
filter, index, breakpoint, limit, watch, raw), :mod:`.motion` (move, velocity, stop, home),
:mod:`.tune` (step, tune), :mod:`.twin` (identify, twin check), :mod:`.wiring` (wiring,
wiring --check), :mod:`.calc`, :mod:`.bridge` (bridge list|flash), :mod:`.sim` (sim serve),
:mod:`.sigrok` (sigrok install), :mod:`.lab` (--place, lab selftest), :mod:`.profile` (--profile,
profile init|apply|show), :mod:`.scope`, :mod:`.panel`, :mod:`.shell`; :mod:`.types` holds the parameter
types and checks they share.

A new command is a function in its family's module decorated with ``@main.command()``.
"""

from __future__ import annotations

from lm629_host.cli import (  # noqa: F401 - importing a family registers its commands
    bench, bridge, calc, chip, lab, motion, panel, profile, scope, selftest, shell, sigrok, sim,
    tune, twin, wiring)
from lm629_host.chip.safety import Terminated
from lm629_host.cli.app import EXIT_CODES, Session, main
from lm629_host.cli.common import snapshot_dict
from lm629_host.cli.types import parse_int


__all__ = ["main", "EXIT_CODES", "Session", "Terminated", "parse_int", "snapshot_dict"]
