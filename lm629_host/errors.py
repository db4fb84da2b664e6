"""Exceptions.  Every message says what failed and what to check on the bench."""

from __future__ import annotations

import enum
from collections.abc import Sequence


class LM629Error(Exception):
    """Base class of every error this package raises on purpose (besides
    :class:`ArgumentError`, a ValueError for arguments, raised before any bus traffic)."""


class ArgumentError(ValueError):
    """A bad argument, found before any bus traffic.  ``argument`` is its name as the caller
    spelled it (``kp``, ``derivative_interval``, ``axes``), ``value`` what was given, ``lo``
    and ``hi`` the allowed range where there is one (inclusive; None: no bound or no range),
    so that a caller with its own names for the arguments (the CLI's ``--ds``) can say the
    same without reading the message."""

    def __init__(self, argument: str, value: object, message: str, *,
                 lo: float | None = None, hi: float | None = None) -> None:
        self.argument = argument
        self.value = value
        self.lo = lo
        self.hi = hi
        super().__init__(message)


class BusyTimeout(LM629Error):
    """The busy bit stayed set longer than the transport's busy timeout."""

    def __init__(self, operation: str, timeout_s: float, status: int | None = None,
                 index: int | None = None, words: Sequence[int] = ()):
        self.operation = operation
        self.timeout_s = timeout_s
        self.status = status
        self.index = index
        self.words = tuple(words)
        seen = f"; last status read {status:02X}" if status is not None else ""
        if status == 0xFF:  # every bit high: nothing drives the data bus (pull-ups, or FF)
            advice = ("Status FF is what a bus that no chip drives reads: check that this "
                      "chip's /CS reaches it and that it has power; on a board with fewer chips "
                      "than the bridge has chip selects, name the chips wired (?axes=N).")
        else:
            advice = ("Check the chip's power and its clock input, that /CS and /PS reach the "
                      "chip, and that /RST is not held low.")
        super().__init__(
            f"busy bit stayed set for {timeout_s * 1e3:.3g} ms before {operation}{seen} "
            f"(the chip never holds busy for more than 100 us). {advice}"
        )


class ResetError(LM629Error):
    """The reset check of AN-706 4.4.1 failed."""

    def __init__(self, statuses: Sequence[int], expected: str, attempts: int = 1, *,
                 axis: int | None = None):
        self.statuses = tuple(statuses)
        self.attempts = attempts
        self.axis = axis  #: the failing chip on a multi-axis board (None: a single chip)
        seen = " ".join(f"{s:02X}" for s in self.statuses) or "nothing"
        prefix = f"axis {axis}: " if axis is not None else ""
        super().__init__(
            f"{prefix}reset check failed after {attempts} attempt(s): status read {seen}, expected "
            f"{expected}. Check the chip's supply and clock (CLK pin), that /RST is wired and "
            "released, and that the data bus and /PS are wired the right way round."
        )


class TransportError(LM629Error):
    """The link to the chip failed: port missing, busy, no permission, no answer, bad frames."""

    def __init__(self, message: str, port: str | None = None):
        self.port = port
        super().__init__(f"{port}: {message}" if port else message)


class LinkError(TransportError):
    """The link to a bridge gave up on a request.  ``may_have_run``: True when the request may
    have reached the bridge (its program may or may not have run), False when nothing was sent
    to the chip (the resynchronising HELLO before it got no answer).  ``host_late_s``: how long
    the host itself stalled during the attempts (its clock jumped: suspended, swapping, a busy
    machine), 0 when it did not; then the message blames the host, not the line."""

    def __init__(self, message: str, *, port: str, may_have_run: bool,
                 host_late_s: float = 0.0) -> None:
        super().__init__(message, port=port)
        self.may_have_run = may_have_run
        self.host_late_s = host_late_s


class FailsafeTripped(TransportError):
    """The far side's failsafe tripped: the host was silent past its timeout, and the bridge
    stopped the chips itself.  Raised for a trajectory command the bridge refused while the trip
    is latched, and once for the first program after the host learnt of a trip it had not
    seen happen (a host paused mid-move).

    ``state``: the latched trip as the bridge reports it (a
    :class:`~lm629_host.bridge.protocol.FailsafeState`, None when it could not be read);
    ``stopped``: the chip selects the bridge stopped; ``action``: how (``abrupt``, ``smooth``,
    ``off``); ``host_late_s``: how long this host was seen to stall, when it was.  A caller
    that must stop a motor reads ``stopped`` (the bridge did it already), never the message."""

    def __init__(self, message: str, *, port: str, state: object = None,
                 stopped: Sequence[int] = (), action: str = "",
                 host_late_s: float = 0.0) -> None:
        super().__init__(message, port=port)
        self.state = state
        self.stopped = tuple(stopped)
        self.action = action
        self.host_late_s = host_late_s

    def stopped_by_bridge(self, cs: int | None = None) -> bool:
        """True when the bridge reports it stopped chip select ``cs`` (None: any chip)."""
        return bool(self.stopped) if cs is None else cs in self.stopped

    @property
    def stop_note(self) -> str:
        """One line on how the motors were left, for a caller's report."""
        who = ", ".join(f"cs {k}" for k in self.stopped) or "no chip"
        return f"stopped by the bridge's failsafe ({who}, {self.action or '?'} stop)"


class SchemeError(TransportError, ArgumentError):
    """A port URL whose scheme no transport is registered for: bad usage (an ArgumentError
    with ``argument`` ``"port"``), and a TransportError for code that catches those."""

    def __init__(self, message: str, port: str):
        self.port = port
        self.argument, self.value, self.lo, self.hi = "port", port, None, None
        Exception.__init__(self, f"{port}: {message}")


class AxisError(LM629Error, ArgumentError):
    """An axis (chip select) that the board does not have: raised before any bus cycle
    (``argument`` is ``"axis"``, the range 0..available - 1)."""

    def __init__(self, axis: object, available: int, where: str):
        self.axis = axis
        self.available = available
        ArgumentError.__init__(
            self, "axis", axis,
            f"axis {axis} does not exist: {where} has {available} chip select(s) (axes "
            f"0..{available - 1}). Check the axis number, the board's `axes=` and, on a bridge, "
            "that its firmware is the multi-axis one (lm629 bridge flash).",
            lo=0, hi=available - 1)


class CommandError(LM629Error):
    """The chip set its command-error bit (status bit 1) in answer to a command."""

    def __init__(self, command: str, status: int):
        self.command = command
        self.status = status
        super().__init__(
            f"the chip rejected {command} (command-error bit set, status {status:02X}). "
            "It refuses an acceleration change while moving with the drive on, a relative "
            "velocity that would go negative, and a transfer in the wrong direction."
        )


class WaitTimeout(LM629Error):
    """``wait_for`` did not see any of the awaited status flags in time.  ``flags`` are the
    flags waited for, ``what`` says in words what that was (``"the index pulse (status bit
    3)"``; by default the flags' names), ``status`` the last status byte read."""

    def __init__(self, flags: object, timeout_s: float, status: int, *, what: str | None = None):
        self.flags = flags
        self.what = str(flags) if what is None else what
        self.timeout_s = timeout_s
        self.status = status
        super().__init__(
            f"waited {timeout_s:g} s for {self.what} but status stayed {status:02X}. "
            "Check that the motor can follow (following error, stall) and that the move was started."
        )


class UpdateTooSoon(LM629Error):
    """A trajectory update (STT) asked sooner after the last one than ``chip.update_interval``
    allows, on a chip told to raise instead of waiting (``chip.update_rule = "raise"``).
    ``since_s``: seconds since the last STT; ``interval_s``: the rule (AN-706 4.6.2: the chip
    aborts its trajectory calculation at a new STT, so at most one update per 10 ms)."""

    def __init__(self, since_s: float, interval_s: float):
        self.since_s = since_s
        self.interval_s = interval_s
        super().__init__(
            f"trajectory update {since_s * 1e3:.2f} ms after the last STT: AN-706 4.6.2 allows "
            f"one per {interval_s * 1e3:g} ms (the chip aborts the calculation in progress and "
            "holds its output); nothing was sent. Wait, or set chip.update_rule = 'wait'")


class ProtocolViolation(LM629Error):
    """Raised by ``sim://?strict=1`` the moment the host breaks the chip's bus protocol."""


class MotionFault(str, enum.Enum):
    """Why a move did not end where it was sent (:attr:`MotionError.reason`).  A ``str`` enum:
    each member equals its text (``MotionFault.STALL == "stall"``)."""

    POSITION_ERROR = "position error"    #: the chip's position-error flag (LPEI / LPES)
    MOTOR_OFF = "motor off"              #: the drive was found off (LPES, or someone else)
    STALL = "stall"                      #: the desired position moves, the shaft does not
    RUNAWAY = "runaway"                  #: the shaft heads away from the desired position
    FOLLOWING_ERROR = "following error"  #: settled, but further from target than the tolerance
    TIMEOUT = "timeout"                  #: the move did not complete in the time allowed

    def __str__(self) -> str:
        return self.value


class MotionError(LM629Error):
    """A move did not end where it was sent.  ``reason`` is a :class:`MotionFault` (also
    reachable as ``MotionError.STALL`` ...); ``detail`` the sentence that says what was seen
    and what to check; ``axis`` names the axis on a multi-axis board (None on a single chip);
    ``position`` and ``error`` are the last real position and following error read (counts),
    when known.  Whoever raises it has already stopped the motor, or says in ``detail`` that
    it could not."""

    POSITION_ERROR = MotionFault.POSITION_ERROR
    MOTOR_OFF = MotionFault.MOTOR_OFF
    STALL = MotionFault.STALL
    RUNAWAY = MotionFault.RUNAWAY
    FOLLOWING_ERROR = MotionFault.FOLLOWING_ERROR
    TIMEOUT = MotionFault.TIMEOUT
    REASONS = tuple(MotionFault)

    def __init__(self, reason: MotionFault | str, detail: str, *, axis: object = None,
                 position: int | None = None, error: int | None = None):
        try:
            self.reason = MotionFault(reason)
        except ValueError:
            raise ValueError(f"MotionError reason {reason!r} is not one of "
                             f"{[r.value for r in MotionFault]}") from None
        self.detail = detail
        self.axis = axis
        self.position = position
        self.error = error
        prefix = f"axis {axis}: " if axis is not None else ""
        super().__init__(f"{prefix}motion fault ({self.reason.value}): {detail}")

    def on_axis(self, axis: int) -> MotionError:
        """The same fault, named for ``axis`` of a multi-axis board."""
        return MotionError(self.reason, self.detail, axis=axis, position=self.position,
                           error=self.error)


def check_int(name: str, value: object, lo: int, hi: int, *, hex_digits: int = 0) -> int:
    """Validate an integer argument; the :class:`ArgumentError` names it, its value and the
    allowed range."""
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ArgumentError(name, value, f"{name}={value!r} must be an integer in {lo}..{hi}",
                                lo=lo, hi=hi)
    if not lo <= value <= hi:
        rng = f"{lo}..{hi}"
        if hex_digits:
            rng += f" (0x{lo & (16 ** hex_digits - 1):0{hex_digits}X}..0x{hi:0{hex_digits}X})"
        raise ArgumentError(name, value, f"{name}={value} is outside the allowed range {rng}",
                            lo=lo, hi=hi)
    return value
