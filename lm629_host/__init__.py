"""lm629_host: host driver, chip simulator and bench CLI for the LM628/LM629 motion controllers.

    import lm629_host
    with lm629_host.open("sim://") as chip:
        chip.reset()
        chip.load_filter(kp=20); chip.update_filter()
        chip.move_to(1000, velocity=65536, acceleration=655).wait()   # or MotionError
"""

from __future__ import annotations

from .errors import (
    AxisError,
    BusyTimeout,
    CommandError,
    LM629Error,
    MotionError,
    ProtocolViolation,
    ResetError,
    TransportError,
    WaitTimeout,
)
from .lm629 import LM629, Snapshot
from .move import Move, MoveResult, MoveRules
from .opcodes import Cmd, FilterFlags, Signals, Status, TrajectoryFlags
from .program import DEFAULT_BUSY_TIMEOUT_S, BusCycle, Program, ProgramResult
from .ports import resolve_port
from .transports import DEFAULT_URL

__version__ = "0.1.0"

from .board import Board, BoardMove, open_board


def open(url: str = DEFAULT_URL, *, chip: str | None = None,  # noqa: A001 - lm629_host.open, as io.open
         clock: float | str | None = None, trace=None,
         busy_timeout: float = DEFAULT_BUSY_TIMEOUT_S) -> LM629:
    """Open the chip behind ``url`` (``sim://`` by default; see :mod:`lm629_host.transports`).

    ``chip`` is "lm628" or "lm629" and ``clock`` the chip's clock (Hz, or ``"6MHz"``); either
    may be said in the URL instead (``?chip=lm628&clock=6MHz``), and where both say it they
    must agree (:func:`lm629_host.ports.resolve_port`).  ``trace`` is called with a
    :class:`BusCycle` for every bus cycle.  ``busy_timeout`` (s) bounds every busy check (0.2
    to 65.5 ms; default 5 ms).  On a multi-axis board ``?cs=k`` opens the chip on chip select
    ``k`` (default 0); :func:`open_board` opens them all.
    """
    spec = resolve_port(url, chip=chip, clock=clock)
    transport = spec.open_transport(trace)
    try:
        return LM629(transport, chip=spec.chip, busy_timeout=busy_timeout, axis=spec.cs,
                     clock_hz=spec.clock_hz)
    except Exception:
        transport.close()
        raise


__all__ = [
    "LM629", "Snapshot", "Move", "MoveResult", "MoveRules", "open", "open_board", "Board",
    "BoardMove", "AxisError", "Status", "Signals", "FilterFlags", "TrajectoryFlags", "Cmd",
    "BusCycle", "Program", "ProgramResult", "LM629Error", "BusyTimeout", "ResetError",
    "TransportError", "CommandError", "WaitTimeout", "MotionError", "ProtocolViolation",
    "__version__",
]
