"""The board's URL options, ``chip=``, ``clock=``, ``axes=``, ``cs=``, as rows of a table: every
transport's option table starts with :data:`BOARD_ROWS` (so a URL's options are checked once,
against one table, and an unknown name's message lists them with the transport's own), and
:func:`lm629_host.transports.ports.resolve_port` checks the URL's board values with these
same rows.  A bad value is an :class:`~lm629_host.errors.ArgumentError` naming the option."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from lm629_host.bus.opcodes import NOMINAL_CLOCK_HZ
from lm629_host.errors import ArgumentError
from lm629_host.urls import Option, parse_hz

#: the chips the driver knows
CHIPS = ("lm628", "lm629")
#: the chip's clock range (datasheets: 1 to 8 MHz parts)
CLOCK_MIN_HZ, CLOCK_MAX_HZ = 1_000_000, NOMINAL_CLOCK_HZ
#: what ``axes=`` and ``cs=`` count, for the messages
AXES_WHAT, CS_WHAT = "a whole number of chips", "a chip select number (0, 1, ...)"


def check_clock(hz: float, said: str) -> float:
    """``hz`` within the chip's clock range; ``said``: how the value was given, for the
    message."""
    if not CLOCK_MIN_HZ <= hz <= CLOCK_MAX_HZ:
        raise ArgumentError("clock", hz, f"{said} is outside the chip's 1-8 MHz",
                            lo=CLOCK_MIN_HZ, hi=CLOCK_MAX_HZ)
    return float(hz)


def _chip_in_url(text: str, url: Any) -> str:
    if text.lower() not in CHIPS:
        raise ArgumentError("chip", text, f"chip={text!r} in {url}: expected lm628 or lm629")
    return text.lower()


def _clock_in_url(text: str, url: Any) -> float:
    try:
        hz = parse_hz(text)
    except ValueError:
        raise ArgumentError("clock", text, f"clock={text!r} in {url} is not a frequency "
                                           "(8MHz, 6e6)") from None
    return check_clock(hz, f"clock={text} in {url}")


def _whole_in_url(name: str, lo: int, what: str) -> Callable[[str, Any], int]:
    def check(text: str, url: Any) -> int:
        try:
            n = int(text)
        except ValueError:
            raise ArgumentError(name, text, f"{name}={text!r} in {url} is not {what}",
                                lo=lo) from None
        if n < lo:
            raise ArgumentError(name, n, f"{name}={n} in {url}: at least {lo}", lo=lo)
        return n
    return check


#: the board's rows (no default: None means not said, and the transport or the driver decides)
BOARD_ROWS = (
    Option("chip", check=_chip_in_url),
    Option("clock", check=_clock_in_url),
    Option("axes", check=_whole_in_url("axes", 1, AXES_WHAT)),
    Option("cs", check=_whole_in_url("cs", 0, CS_WHAT)),
)
BOARD = {o.name: o for o in BOARD_ROWS}
#: their names (lm629_host.transports.ports takes them out before a hardware transport opens)
BOARD_OPTIONS = frozenset(BOARD)

__all__ = ["AXES_WHAT", "BOARD", "BOARD_OPTIONS", "BOARD_ROWS", "CHIPS", "CLOCK_MAX_HZ", "CLOCK_MIN_HZ",
           "CS_WHAT", "check_clock"]
