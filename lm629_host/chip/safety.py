"""Stopping the motor when something goes wrong while it moves.

A bench program that dies with the drive on leaves a motor running at full speed, or a
following-error loop pushing against a hard stop.  Everything in the CLI that starts a move runs
inside :func:`stop_on_error`: Ctrl-C or any exception first stops the motor the hard way (LTRJ
abrupt stop + STT, then LTRJ motor off + STT), then the exception goes on to the CLI's error
handler, which prints what happened and how the motor was left.

A library module (no click): :mod:`lm629_host.chip.move`, :mod:`lm629_host.chip.supervise`,
:mod:`lm629_host.bench.bringup`, :mod:`lm629_host.bench.tuning`, :mod:`lm629_host.bench.capture` and the CLI all
stop the motor through it, and :func:`motion_fault` is the one way a motion fault is raised.

A stop signal (Ctrl-C, SIGTERM, SIGHUP) must reach that stop without cutting a bus program in
half: a chip left between a command byte and its data words takes the stop's LTRJ as data.
:class:`StopSignals` raises it as a KeyboardInterrupt, held until the program under way has
ended; the CLI and the pytest plugin both install it.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Protocol

from lm629_host.errors import ArgumentError, MotionError, MotionFault
from lm629_host.bus.bits import STATUS_MOTOR_OFF, STATUS_TRAJECTORY_COMPLETE


class Stoppable(Protocol):
    """What stopping needs of a chip (an :class:`~lm629_host.LM629` is one): LTRJ with a stop
    bit and STT.  Declared here so that the typed layer, which uses this module through
    :mod:`.move`, is not imported back."""

    def load_trajectory(self, *, stop: str | None = None, start: bool = False) -> object: ...

class Watched(Stoppable, Protocol):
    """A chip whose status says whether it moves (an :class:`~lm629_host.LM629`)."""

    def read_status(self) -> int: ...


log = logging.getLogger("lm629_host.chip.safety")

#: the attribute set on an exception that went through :func:`stop_on_error`
STOP_NOTE = "lm629_stop_note"


def emergency_stop(chip: Stoppable) -> tuple[bool, str]:
    """Abrupt stop, then motor off; each tried even when the other fails.

    Returns (stopped, one line saying how the motor was left).  The motor counts as stopped
    when the motor-off STT went through, even if the abrupt stop was refused (the chip refuses
    a stop while an acceleration change is still pending, model choices 13 and 28; motor off
    is always taken).  A second Ctrl-C during the
    stop is swallowed: the stop is two short bus programs and must not be cut in half.
    """
    problems = []
    for stop in ("abrupt", "off"):
        for _attempt in range(2):  # a Ctrl-C hammered during the stop costs one retry
            try:
                chip.load_trajectory(stop=stop, start=True)
                break
            except KeyboardInterrupt:
                continue
            except Exception as exc:  # noqa: BLE001 - the link may be the thing that failed
                if getattr(exc, "stopped", None):
                    # the bridge's failsafe already stopped this axis and says how: the truth,
                    # not "could not stop"
                    return True, f"motor {exc.stop_note}"  # type: ignore[attr-defined]  # FailsafeTripped
                problems.append(f"{stop} stop failed: {exc}")
                break
        else:
            problems.append(f"{stop} stop interrupted")
    off_failed = any(p.startswith("off ") for p in problems)
    if off_failed:
        msg = ("COULD NOT STOP THE MOTOR (" + "; ".join(problems) + "): switch off the motor "
               "supply, then check the link")
        log.info(msg)  # the caller reports it (the CLI: on its one error line)
        return False, msg
    if problems:
        return True, "motor off (" + "; ".join(problems) + "; the motor-off STT was taken)"
    return True, "motor stopped (abrupt stop, then motor off)"


def motion_fault(chip: Stoppable, reason: MotionFault, detail: str, *,
                 position: int | None = None, error: int | None = None) -> MotionError:
    """Stop the motor (:func:`emergency_stop`) and return the :class:`MotionError` that says
    why and how the motor was left (``detail; motor stopped ...``), marked as stopped already
    so that an outer :func:`stop_on_error` does not stop it again.  The caller raises it."""
    _ok, note = emergency_stop(chip)
    exc = MotionError(reason, f"{detail}; {note}", position=position, error=error)
    setattr(exc, STOP_NOTE, note)
    return exc


#: status bits of which either says the chip carries out no trajectory (motor off, or the
#: trajectory complete)
_AT_REST = STATUS_MOTOR_OFF | STATUS_TRAJECTORY_COMPLETE

def stop_if_moving(chip: Watched) -> bool:
    """Abrupt stop (the PID holds where it stopped) when the status says the chip is carrying
    out a trajectory (motor on, trajectory not complete); returns True when it stopped one.
    A ``with lm629_host.open(...)`` or ``open_board(...)`` block left by an exception runs it
    before the link closes: a clean close disarms the bridge's failsafe, so nothing else would
    stop a velocity-mode move the script's error cut short.  Never raises: the block's own
    exception is the one to see (a stop that fails is logged)."""
    try:
        if int(chip.read_status()) & _AT_REST:
            return False
        chip.load_trajectory(stop="abrupt", start=True)
    except BaseException as exc:  # noqa: BLE001 - the link may be what failed
        log.warning("could not stop %r after the error: %s", chip, exc)
        return False
    log.info("%r: stopped (abrupt stop, holding) after the error", chip)
    return True


def stop_at_exit(chip: Watched) -> bool:
    """A normal exit of a script that left ``chip``'s link open
    (:mod:`lm629_host.transports.exiting`): an abrupt stop (the PID holding) when the chip
    carries out a trajectory, and if the chip refuses it (an acceleration change pending),
    motor off.  True when the chip is at rest or stopped, so that closing the link (which
    disarms the bridge's failsafe) leaves nothing moving; False when that is not known (the
    link failed, the stop failed): then the link is left to the failsafe, which stops every
    chip and tells the next process.  Never raises."""
    try:
        if int(chip.read_status()) & _AT_REST:
            return True
        chip.load_trajectory(stop="abrupt", start=True)
    except BaseException as exc:  # noqa: BLE001 - an exit must finish
        if getattr(exc, "stopped", None):  # FailsafeTripped: the bridge stopped it already
            return True
        stopped, note = emergency_stop(chip)
        log.warning("%r at exit: the abrupt stop failed (%s); %s", chip, exc, note)
        return stopped
    log.info("%r: stopped at exit (abrupt stop, holding): the script left it moving", chip)
    return True


@contextmanager
def stop_on_error(chip: Watched) -> Iterator[None]:
    """Run a block that may leave the motor moving; on any exception (Ctrl-C included) stop
    the motor first, note how on the exception (attribute ``lm629_stop_note``), re-raise.

    An :class:`~lm629_host.errors.ArgumentError` is a value refused before its bus cycles:
    bad input touches nothing, so a holding axis is left holding (it turned the motor off, and
    said so, for a move refused as too long); only an axis an earlier step of the block left
    moving is stopped (:func:`stop_if_moving`, the PID holding)."""
    try:
        yield
    except ArgumentError as exc:
        if getattr(exc, STOP_NOTE, None) is None and stop_if_moving(chip):
            setattr(exc, STOP_NOTE, "motor stopped (abrupt stop, holding)")
        raise
    except BaseException as exc:
        if getattr(exc, STOP_NOTE, None) is None:
            _ok, note = emergency_stop(chip)
            try:
                setattr(exc, STOP_NOTE, note)
            except AttributeError:  # pragma: no cover - exceptions with __slots__
                pass
        raise


#: the signals that end a run as Ctrl-C does: a user's kill, a CI job's timeout (SIGTERM), a
#: closed terminal (SIGHUP); without a handler the last two kill Python where it stands, motor on
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C's KeyboardInterrupt so that every ``except
    KeyboardInterrupt`` that stops the motor handles it too; ``signum`` says which (the CLI's
    exit code is 128 + ``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def signal_exception(signum: int) -> KeyboardInterrupt:
    """Ctrl-C as Python's own KeyboardInterrupt, SIGTERM and SIGHUP as :class:`Terminated`."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


class ProgramRunner(Protocol):
    """What holding a signal needs of a transport: whether a bus program is under way, and a
    hook run when the outermost one has ended (:class:`~lm629_host.transports.base.Transport`
    has both)."""

    program_depth: int
    after_program: Callable[[], None] | None


class StopSignals:
    """Turns :data:`STOP_SIGNALS` into an exception (``exception(signum)``: by default
    :func:`signal_exception`) raised in the main thread, so that the code that stops the motor
    (:func:`stop_on_error`, a fixture's teardown) runs.  A signal that comes while the guarded
    transport runs a bus program is held and raised when the program has ended (its
    ``after_program`` hook), so that the stop starts on a clean bus.

    :meth:`install` does nothing outside the main thread (Python delivers signals only there)
    or when already installed; :meth:`restore` puts the previous handlers back."""

    def __init__(self, exception: Callable[[int], BaseException] = signal_exception) -> None:
        self._exception = exception
        self._old: dict[int, Any] = {}
        self._guarded: ProgramRunner | None = None
        self.pending: int | None = None  #: the signal held until the program ends

    @property
    def installed(self) -> bool:
        return bool(self._old)

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread() or self._old:
            return
        self._old = {sig: signal.signal(sig, self._on_signal) for sig in STOP_SIGNALS}

    def guard(self, transport: ProgramRunner) -> None:
        """Hold signals during ``transport``'s bus programs (the last transport guarded)."""
        self._guarded = transport
        self.pending = None
        transport.after_program = self._deliver

    def restore(self) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old = {}

    def _on_signal(self, signum: int, frame: object) -> None:
        if self._guarded is not None and self._guarded.program_depth:
            self.pending = signum
        else:
            raise self._exception(signum)

    def _deliver(self) -> None:
        if self.pending is not None:
            signum, self.pending = self.pending, None
            raise self._exception(signum)


__all__ = ["emergency_stop", "motion_fault", "stop_if_moving", "stop_on_error", "STOP_NOTE", "STOP_SIGNALS",
           "Stoppable", "StopSignals", "Terminated", "signal_exception"]
