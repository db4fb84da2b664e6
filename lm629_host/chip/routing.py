"""Where a chip's bus programs go: its transport, or, in one thread, a runner that answers
them as the chip would (:meth:`LM629.intercept <lm629_host.LM629.intercept>`, a shadow's).

A batch (:mod:`lm629_host.chip.batch`) builds its calls' programs on a shadow of the chip and
decodes their answers through ``intercept``: every typed call goes through
:meth:`ProgramRouting.run`, the one point that reroutes.
"""

from __future__ import annotations

import contextlib
import copy
import threading
from collections.abc import Callable, Iterator
from typing import TypeVar

from lm629_host.bus.program import Program, ProgramResult
from lm629_host.chip.wraparound import PositionTracker
from lm629_host.transports.base import Transport

Routed = TypeVar("Routed", bound="ProgramRouting")


class ProgramRouting:
    """The routing of :class:`~lm629_host.LM629`'s programs (mixed into it)."""

    transport: Transport
    positions: PositionTracker

    def __init__(self) -> None:
        self._this_thread = _ThisThread()  # every thread to the transport, until intercepted

    def run(self, program: Program) -> ProgramResult:
        """Run a bus program (for experts and for composite operations).  Every typed call
        goes through here: the one point :meth:`intercept` reroutes."""
        runner = self._this_thread.runner
        if runner is not None:
            return runner(program)
        if self.before_program is not None:
            self.before_program(program)
        return self.transport.execute(program)

    #: shown every program :meth:`run` sends to the transport, first: a host-timed shaped
    #: move issues its pieces that are due there (:class:`~lm629_host.chip.shapes.ShapedMove`)
    before_program: Callable[[Program], None] | None = None

    @contextlib.contextmanager
    def intercept(self, runner: Callable[[Program], ProgramResult]) -> Iterator[None]:
        """While the block runs, this thread's bus programs of this object go to
        ``runner(program)`` instead of the transport, which answers them as the chip would;
        other threads' calls still reach the bus.  A batch builds and decodes its calls
        through here (:mod:`lm629_host.chip.batch`).  Nested: the inner runner until it ends.
        A wraparound bit a runner's answer shows is cleared only after the block
        (:meth:`PositionTracker.holding <lm629_host.chip.wraparound.PositionTracker.holding>`):
        the programs it answers were built before it was seen."""
        here = self._this_thread
        before, here.runner = here.runner, runner
        try:
            with self.positions.holding():  # the runner answers programs built before
                yield
        finally:
            here.runner = before

    def _rerouted(self: Routed, runner: Callable[[Program], ProgramResult]) -> Routed:
        """A copy of this object whose bus programs, in every thread, go to ``runner``."""
        twin = copy.copy(self)
        twin._this_thread = _ThisThread(runner)
        return twin


class _ThisThread(threading.local):
    """Per thread: where an LM629's bus programs go (None: its transport; see intercept).
    ``runner`` is every thread's start (a threading.local runs ``__init__`` in each)."""

    def __init__(self, runner: Callable[[Program], ProgramResult] | None = None) -> None:
        self.runner = runner
