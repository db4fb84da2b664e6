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
from .transports import DEFAULT_URL, transport_class
from .urls import query_params, split_params

__version__ = "0.1.0"

from .board import Board, BoardMove, open_board


def open(url: str = DEFAULT_URL, *, chip: str | None = None, trace=None,  # noqa: A001 - lm629_host.open, as io.open
         busy_timeout: float = DEFAULT_BUSY_TIMEOUT_S) -> LM629:
    """Open the chip behind ``url`` (``sim://`` by default; see :mod:`lm629_host.transports`).

    ``chip`` is "lm628" or "lm629"; on a simulator URL it defaults to the URL's ``chip=``.
    ``trace`` is called with a :class:`BusCycle` for every bus cycle.  ``busy_timeout`` (s)
    bounds every busy check (0.2 to 65.5 ms; default 5 ms).  On a multi-axis board ``?cs=k``
    opens the chip on chip select ``k`` (default 0); :func:`open_board` opens them all.
    """
    cls = transport_class(url)
    if chip is None:
        chip = query_params(url).get("chip", "lm629") if cls.simulated else "lm629"
    url, taken = split_params(url, {"cs"})
    axis = None
    if "cs" in taken:
        try:
            axis = int(taken["cs"])
        except ValueError:
            raise ValueError(f"cs={taken['cs']!r} is not a chip select number (0, 1, ...)") from None
    transport = cls.from_url(url, trace=trace)
    try:
        return LM629(transport, chip=chip, busy_timeout=busy_timeout, axis=axis)
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
