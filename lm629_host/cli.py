"""``lm629``: the bench command line, from first power-on to a tuned move.

Each command opens the port (``--port``, else ``$LM629_PORT``, else the simulator), does one
job through :class:`lm629_host.LM629` and closes it.  Every number is checked before anything
moves (:mod:`lm629_host.cli_types`).  Moves go through :meth:`LM629.move_to`: done means the
shaft rests on the target, anything else is a motion fault (exit 9).  Commands that start a
move run inside :func:`lm629_host.safety.stop_on_error`: Ctrl-C, SIGTERM, SIGHUP (all
raised as KeyboardInterrupt, after the bus program under way), a closed pipe or any error
stops the motor (abrupt stop, then motor off) before the program exits; commands that only
read or wait never stop anything.  Errors are one line on stderr (a traceback with ``-v``) and
an exit code per way of ending (see ``EXIT_CODES``, printed by ``lm629 --help``).

An in-process simulator (``sim://``, ``sim+avr://``, ``sim+ftdi://``, ``sim+emu://``) is a fresh
chip for each command: the CLI resets it and loads kp = 20 first, so that ``move`` and friends
do something, and says so on stderr.  For a simulated chip that keeps its state between
commands run ``lm629 sim serve --pty /tmp/lm629`` and use ``--port /tmp/lm629``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, NoReturn

import click

import lm629_host

from .bringup import BringupOptions, StepResult, run_bringup
from .capture import PlotUnavailable, capture_move, summary, write_csv
from .cli_calc import calc
from .safety import STOP_NOTE, emergency_stop, stop_on_error
from .cli_types import FINITE, INT, SIGNED_ARGS, check_writable, parse_int, positive
from .cli_tune import tune as _tune
from .errors import (
    BusyTimeout,
    CommandError,
    LM629Error,
    MotionError,
    ResetError,
    TransportError,
    WaitTimeout,
)
from .lm629 import LM629, Snapshot, check_int
from .move import MoveRules
from .opcodes import ACCELERATION_MAX, POSITION_MAX, POSITION_MIN, VELOCITY_MAX, Signals, Status
from .program import BusCycle, Program, ProgramResult
from .transports import is_simulated
from .urls import parse_hz, query_params, with_query
from .units import FIXED_ONE, Scale

log = logging.getLogger("lm629_host.cli")

#: exit code -> meaning (one place: the handler and ``--help`` both read it)
EXIT_CODES: dict[int, str] = {
    0: "success",
    1: "a check failed (bringup verdict, doctor found problems)",
    2: "bad usage or bad value (nothing was sent that moves the motor)",
    3: "transport error (port missing, busy, no permission, no answer)",
    4: "busy timeout (the chip held its busy bit)",
    5: "reset failure (the chip did not come out of reset)",
    6: "command error (the chip rejected a command)",
    7: "wait timeout (a flag or the index did not come in time)",
    8: "other driver error",
    9: "motion fault: the shaft did not end where it was sent (stall, runaway, position "
       "error, following error, motor off, move timeout); the motor was stopped",
    129: "hang-up (SIGHUP); a moving motor was stopped first",
    130: "interrupted (Ctrl-C, or the prompt aborted); a moving motor was stopped first",
    141: "output closed (broken pipe) while the motor moved; it was stopped first",
    143: "terminated (SIGTERM); a moving motor was stopped first",
}

_ERROR_EXITS: tuple[tuple[type[BaseException], int], ...] = (
    (ValueError, 2), (TransportError, 3), (BusyTimeout, 4), (ResetError, 5),
    (CommandError, 6), (WaitTimeout, 7), (MotionError, 9), (LM629Error, 8),
)

#: the signals that end a command like Ctrl-C does: the motor is stopped, then exit 128 + N
_STOP_SIGNALS = {signal.SIGINT: "interrupted (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)",
                 signal.SIGHUP: "hang-up (SIGHUP)"}


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C's KeyboardInterrupt so that every ``except
    KeyboardInterrupt`` that stops the motor handles it too; ``signum`` picks the exit code."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum



def _simulated(url: str) -> bool:
    """Whether ``url`` names a simulator (False for an unknown scheme: opening it says why)."""
    try:
        return is_simulated(url)
    except TransportError:
        return False


def _open(url: str, chip: str, trace: Callable[[BusCycle], None] | None) -> LM629:
    """Open the chip (one seam, so that tests can watch what the CLI opened)."""
    return lm629_host.open(url, chip=chip, trace=trace)


def _check_clock(hz: float, where: str) -> float:
    if not 1e6 <= hz <= 8e6:
        raise click.BadParameter(f"{hz:g} Hz is outside the chip's 1-8 MHz", param_hint=where)
    return hz


@dataclass
class Session:
    """The global options and the chip they open (lazily: ``calc`` never opens a port)."""

    port: str
    port_given: bool
    chip_name: str
    clock_hz: float
    lines: int | None
    verbose: int
    trace: bool
    stats: bool
    _chip: LM629 | None = None
    _old_handlers: dict[int, Any] | None = None
    _bus_depth: int = 0
    _pending: int | None = None

    @property
    def is_sim(self) -> bool:
        return _simulated(self.port)

    @property
    def scale(self) -> Scale | None:
        return Scale(self.lines, self.clock_hz) if self.lines else None

    @property
    def sample_s(self) -> float:
        return 2048 / self.clock_hz

    def url(self) -> str:
        """The port URL; a simulator URL gets the global --chip/--clock/--lines unless it
        names them itself, so that the simulated chip matches the options (the conflict
        rule is applied by :func:`main`), and ``clock=8MHz`` is written in Hz."""
        if not self.is_sim:
            return self.port
        have = query_params(self.port)
        add = {"chip": self.chip_name, "clock": str(int(self.clock_hz))}
        if self.lines:
            add["lines"] = str(self.lines)
        values = {k: v for k, v in add.items() if k not in have}
        if "clock" in have:
            values["clock"] = str(int(self.clock_hz))
        return with_query(self.port, values) if values else self.port

    @staticmethod
    def _raise_signal(signum: int) -> None:
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)

    def install_signals(self) -> None:
        """Ctrl-C, SIGTERM and SIGHUP end a command the same way: raised as
        KeyboardInterrupt (Terminated for the last two) so that a moving motor is stopped,
        then the exit code says which.  A signal during a bus program is held until the
        program has finished, so that the safety stop starts on a clean bus."""
        if threading.current_thread() is not threading.main_thread() or self._old_handlers:
            return

        def on_signal(signum: int, frame: Any) -> None:
            if self._bus_depth:
                self._pending = signum
            else:
                self._raise_signal(signum)

        self._old_handlers = {sig: signal.signal(sig, on_signal) for sig in _STOP_SIGNALS}

    def _guard_programs(self, chip: LM629) -> None:
        """Run every bus program of ``chip`` whole: a stop signal waits for its end."""
        execute = chip.transport.execute

        def guarded(program: Program) -> ProgramResult:
            self._bus_depth += 1
            try:
                result = execute(program)
            finally:
                self._bus_depth -= 1
            if self._pending is not None and not self._bus_depth:
                signum, self._pending = self._pending, None
                self._raise_signal(signum)
            return result

        chip.transport.execute = guarded  # type: ignore[method-assign]  # this CLI run's transport only

    def _trace(self, cycle: BusCycle) -> None:
        if self.trace:
            click.echo(f"bus {cycle}", err=True)

    def open(self, *, prepare: bool = True) -> LM629:
        """The chip.  On an in-process simulator: reset it and load kp = 20 (``prepare``)."""
        if self._chip is None:
            if not self.port_given:
                click.echo("lm629: no --port or LM629_PORT: using the simulator sim:// (a fresh "
                           "simulated chip for this command only; for one that keeps its state "
                           "run `lm629 sim serve --pty /tmp/lm629` and pass --port /tmp/lm629)",
                           err=True)
            self._chip = _open(self.url(), self.chip_name, self._trace)
            self._guard_programs(self._chip)
            self._chip.move_rules = MoveRules(clock_hz=self.clock_hz)
            log.info("opened %s", self._chip.transport.describe())
            if self.is_sim and prepare:
                self._chip.reset()
                self._chip.load_filter(kp=20)
                self._chip.update_filter()
                self._chip.sync()  # UDF's busy over before the command's reads
                log.info("fresh simulated chip: reset, kp = 20 loaded")
        return self._chip

    def close(self) -> None:
        if self._chip is not None:
            if self.stats:
                click.echo(f"stats: {self._chip.transport.stats}", err=True)
            self._chip.close()
            self._chip = None
        if self._old_handlers:
            for sig, handler in self._old_handlers.items():
                signal.signal(sig, handler)
            self._old_handlers = None


def _help_epilog() -> str:
    codes = "\n".join(f"  {k:>3}  {v}" for k, v in EXIT_CODES.items())
    return ("\b\nExit codes:\n" + codes + "\n\n\bWith neither --port nor LM629_PORT the bundled "
            "simulator is used (a fresh chip per command).\nStart with:  lm629 bringup --yes")


class LM629Group(click.Group):
    """A click group that turns exceptions into one stderr line and an exit code."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:  # bad usage or value: one line, exit 2
            sub = exc.ctx.command_path if exc.ctx is not None else "lm629"
            _fail(ctx, f"{exc.format_message()} (see `{sub} --help`)", exc, 2)
        except (click.exceptions.Exit, click.ClickException, click.exceptions.Abort):
            raise
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            _fail(ctx, _STOP_SIGNALS.get(signum, f"signal {signum}"), exc, 128 + signum)
        except BrokenPipeError as exc:
            # stdout closed early (`lm629 calc ... | head`): not an error while nothing moved;
            # keep Python from complaining again when it flushes stdout at exit
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            if getattr(exc, STOP_NOTE, None) is not None:  # it ended a move: not a success
                _fail(ctx, "output closed (broken pipe) during a move", exc, 141)
            ctx.exit(0)
        except Exception as exc:  # noqa: BLE001 - mapped to exit codes below
            code = next((c for cls, c in _ERROR_EXITS if isinstance(exc, cls)), None)
            if code is None:
                _fail(ctx, f"internal error ({type(exc).__name__}): {exc}", exc, 8, always_tb=True)
            kind = "bad value" if isinstance(exc, ValueError) else "error"
            _fail(ctx, f"{kind}: {exc}", exc, code)


def _fail(ctx: click.Context, message: str, exc: BaseException, code: int,
          always_tb: bool = False) -> NoReturn:
    session = ctx.obj if isinstance(ctx.obj, Session) else None
    if always_tb or (session is not None and session.verbose):
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    note = getattr(exc, STOP_NOTE, None)
    try:  # stderr may be closed too (a dropped ssh session): the exit code still tells
        click.echo(f"lm629: {message}" + (f" -- {note}" if note and note not in message
                                          else ""), err=True)
    except (OSError, ValueError):
        pass
    ctx.exit(code)


@click.group(cls=LM629Group, epilog=_help_epilog(),
             context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--port", "-p", envvar="LM629_PORT", default=None, metavar="URL",
              help="sim://, serial://PATH or a device path, ftdi://..., sim+avr:// "
                   "(env LM629_PORT; default sim://).")
@click.option("--chip", "chip_name", type=click.Choice(["lm628", "lm629"]), default="lm629",
              show_default=True, help="Which chip is on the board (a simulator URL's chip= "
                                      "is used when --chip is not given; both must agree).")
@click.option("--clock", default="8MHz", show_default=True, metavar="HZ",
              help="The chip's clock (8MHz, 6e6...): sample period 2048/clock (a simulator "
                   "URL's clock= is used when --clock is not given; both must agree).")
@click.option("--lines", type=int, default=None, metavar="N",
              help="Encoder lines per revolution: positions in revolutions, velocities in rpm, "
                   "accelerations in rev/s^2.")
@click.option("-v", "--verbose", count=True, help="-v: info, -vv: debug with the bus hex trace.")
@click.option("--trace", is_flag=True, help="Print every bus cycle on stderr.")
@click.option("--stats", is_flag=True, help="Print the transport's counters at exit.")
@click.version_option(lm629_host.__version__, prog_name="lm629")
@click.pass_context
def main(ctx: click.Context, port: str | None, chip_name: str, clock: str, lines: int | None,
         verbose: int, trace: bool, stats: bool) -> None:
    """Bench bring-up and tuning of an LM628/LM629 motion controller."""
    try:
        clock_hz = _check_clock(parse_hz(clock), "--clock")
    except ValueError:
        raise click.BadParameter(f"{clock!r} is not a frequency (8MHz, 6e6)",
                                 param_hint="--clock") from None
    if lines is not None and lines < 1:
        raise click.BadParameter(f"{lines} must be at least 1", param_hint="--lines")
    if port is not None and not port.strip():
        raise click.BadParameter("is empty (an unset variable in `--port \"$BOARD\"`?); "
                                 "leave --port out to use the simulator", param_hint="--port")
    url = port or lm629_host.DEFAULT_URL
    if _simulated(url):
        # the rule: a simulator URL's chip= / clock= describe the simulated chip; --chip and
        # --clock given on the command line must agree with them, and when not given, the
        # URL's values are used
        q = query_params(url)
        given = {name: ctx.get_parameter_source(name) not in (
            click.core.ParameterSource.DEFAULT, None) for name in ("chip_name", "clock")}
        if "chip" in q:
            url_chip = q["chip"].lower()
            if given["chip_name"] and url_chip != chip_name:
                raise click.BadParameter(f"{chip_name} conflicts with chip={q['chip']} in "
                                         f"{url}: give one of them", param_hint="--chip")
            chip_name = url_chip
        if "clock" in q:
            try:
                url_hz = _check_clock(parse_hz(q["clock"]), "--port clock=")
            except ValueError:
                raise click.BadParameter(f"clock={q['clock']!r} in {url} is not a frequency",
                                         param_hint="--port") from None
            if given["clock"] and url_hz != clock_hz:
                raise click.BadParameter(f"{clock} conflicts with clock={q['clock']} in {url}: "
                                         "give one of them", param_hint="--clock")
            clock_hz = url_hz
    _log_to_stderr({0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG))
    session = Session(url, port is not None, chip_name, clock_hz,
                      lines, verbose, trace, stats)
    ctx.obj = session
    ctx.call_on_close(session.close)
    session.install_signals()


class _ClickHandler(logging.Handler):
    """Log lines to click's stderr (whatever stream that is at the time: tests swap it)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            click.echo(self.format(record), err=True)
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def _log_to_stderr(level: int) -> None:
    logger = logging.getLogger("lm629_host")
    if not any(isinstance(h, _ClickHandler) for h in logger.handlers):
        handler = _ClickHandler()
        handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
        logger.addHandler(handler)
    logger.setLevel(level)


def _session() -> Session:
    session = click.get_current_context().find_object(Session)
    assert session is not None, "main() sets the Session before any command runs"
    return session


# ---------------------------------------------------------------------------------- rendering
def _flags(status: int) -> str:
    names = [(f.name or "").lower() for f in Status if status & f]
    return ",".join(names) or "-"


def snapshot_dict(s: Snapshot, scale: Scale | None = None) -> dict[str, Any]:
    d: dict[str, Any] = {
        "status": f"{int(s.status):02X}",
        "status_flags": [f.name for f in Status if s.status & f],
        "signals": f"{int(s.signals):04X}",
        "signals_flags": [f.name for f in Signals if s.signals & f],
        "desired_position": s.desired_position,
        "real_position": s.real_position,
        "following_error": s.following_error,
        "desired_velocity": s.desired_velocity,
        "real_velocity": s.real_velocity,
        "integration_sum": s.integration_sum,
        "time_s": round(s.time, 6),
    }
    if scale is not None:
        d["desired_position_rev"] = scale.revolutions(s.desired_position)
        d["real_position_rev"] = scale.revolutions(s.real_position)
        d["desired_velocity_rpm"] = scale.rpm(s.desired_velocity)
        d["real_velocity_rpm"] = scale.rpm(s.real_velocity * FIXED_ONE)
    return d


def _progress_line(s: Snapshot, target: int | None = None, scale: Scale | None = None) -> str:
    if scale is not None:
        tgt = f" -> {scale.revolutions(target):.4f}" if target is not None else ""
        return (f"t={s.time:8.3f}s  desired {scale.revolutions(s.desired_position):>10.4f}{tgt} "
                f"rev  actual {scale.revolutions(s.real_position):>10.4f} rev  error "
                f"{s.following_error:>+6d} counts  v {scale.rpm(s.real_velocity * FIXED_ONE):+.1f} rpm")
    tgt = f" -> {target}" if target is not None else ""
    return (f"t={s.time:8.3f}s  desired {s.desired_position:>10d}{tgt}  actual "
            f"{s.real_position:>10d}  error {s.following_error:>+6d}  v {s.real_velocity:+d}")


def _position(s: Session, value: float, name: str, raw: bool = False) -> int:
    """A position or distance as typed: revolutions with --lines (unless raw), else counts."""
    if s.scale is not None and not raw:
        counts = round(value * s.scale.counts_per_rev)
    else:
        if float(value) != int(value):
            raise click.BadParameter(f"{value:g} must be whole counts without --lines",
                                     param_hint=name)
        counts = int(value)
    if not POSITION_MIN <= counts <= POSITION_MAX:
        raise click.BadParameter(f"{value:g} is {counts} counts, outside "
                                 f"{POSITION_MIN}..{POSITION_MAX}", param_hint=name)
    return counts


def _show_position(s: Session, counts: int) -> str:
    return (f"{counts} counts ({s.scale.revolutions(counts):.4f} rev)" if s.scale is not None
            else f"{counts} counts")


def _wait_flag(chip: LM629, flag: Status, words: str, timeout: float) -> Status:
    """``wait_for`` whose timeout says in words what it waited for."""
    try:
        return chip.wait_for(flag, timeout=timeout, poll=0.001)
    except WaitTimeout as exc:
        raise WaitTimeout(words, timeout, exc.status) from None


def _abort_is_interrupt(ask: Callable[[], bool]) -> bool:
    """A prompt ended by Ctrl-C or end of input ends the command like Ctrl-C (exit 130)."""
    try:
        return ask()
    except (click.exceptions.Abort, EOFError):
        raise KeyboardInterrupt from None


@contextmanager
def _live(enabled: bool) -> Iterator[Callable[[str], None]]:
    """A progress line rewritten in place on a terminal; silent otherwise."""
    shown = False

    def show(text: str) -> None:
        nonlocal shown
        if enabled:
            click.echo("\r" + text + "\x1b[K", nl=False, err=True, color=True)
            shown = True

    try:
        yield show
    finally:
        if shown:
            click.echo("", err=True)


def _isatty() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


# ---------------------------------------------------------------------------------- commands
@main.command()
@click.option("--yes", "-y", is_flag=True, help="Do not ask before the motor turns (scripts).")
@click.option("--move", "move_distance", type=FINITE, default=None,
              help="The small move: counts (default 1000), revolutions with --lines.")
@click.option("--hold-kp", type=int, default=20, show_default=True, help="kp of the hold step.")
def bringup(yes: bool, move_distance: float | None, hold_kp: int) -> None:
    """The AN-706 2.12 bring-up: reset, phasing at kp = 1, kp = 20 hold, a small move,
    following error and settle time, next steps.  A prompt ended by Ctrl-C or end of input
    exits 130 with nothing moved."""
    s = _session()
    move_distance = 1000 if move_distance is None else _position(s, move_distance, "--move")
    check_int("--move", move_distance, -100_000, 100_000)
    check_int("--hold-kp", hold_kp, 1, 0x7FFF)
    options = BringupOptions(hold_kp=hold_kp, move_distance=move_distance)
    chip = s.open(prepare=False)
    click.echo(f"bring-up of {chip.variant.upper()} on {chip.transport.describe()}")

    def report(step: StepResult) -> None:
        color = {True: "green", False: "red", None: "yellow"}[step.ok]
        click.echo(f"  [{click.style(step.verdict, fg=color)}] {step.name:8s} {step.summary}")
        for d in step.details:
            click.echo(f"             {d}")

    def confirm(question: str) -> bool:
        return yes or _abort_is_interrupt(lambda: click.confirm(question, default=False))

    result = run_bringup(chip, options, confirm=confirm, report=report, clock_hz=s.clock_hz,
                         announce=lambda text: log.info("step: %s", text))
    click.echo("verdict: " + ("PASS, every step" if result.passed else "FAIL" if any(
        st.ok is False for st in result.steps) else "INCOMPLETE"))
    click.get_current_context().exit(result.exit_code)


@main.command()
@click.option("--json", "as_json", is_flag=True, help="One JSON object on stdout.")
def status(as_json: bool) -> None:
    """Status byte and signals register decoded, positions, velocities, integration sum."""
    s = _session()
    snap = s.open().snapshot()
    d = snapshot_dict(snap, s.scale)
    if as_json:
        click.echo(json.dumps(d, indent=2))
        return
    click.echo(f"status   {d['status']}  {' '.join(d['status_flags']) or '-'}")
    click.echo(f"signals  {d['signals']}  {' '.join(d['signals_flags']) or '-'}")
    click.echo(f"position desired {snap.desired_position}  actual {snap.real_position}  "
               f"error {snap.following_error:+d} counts")
    click.echo(f"velocity desired {snap.desired_velocity / FIXED_ONE:.5f}  actual "
               f"{snap.real_velocity} counts/sample")
    if s.scale is not None:
        click.echo(f"         actual {d['real_position_rev']:.4f} rev, "
                   f"{d['real_velocity_rpm']:.1f} rpm (desired {d['desired_velocity_rpm']:.1f})")
    click.echo(f"integration sum {snap.integration_sum}")


@main.command()
def reset() -> None:
    """Reset the chip and check it came back (AN-706 4.4.1)."""
    from .bringup import reset_with_statuses
    chip = _session().open(prepare=False)
    st, seen = reset_with_statuses(chip)
    click.echo(f"reset ok: status bytes {' '.join(f'{x:02X}' for x in seen)}, now {int(st):02X}")


@main.command("filter")
@click.option("--kp", type=INT)
@click.option("--ki", type=INT)
@click.option("--kd", type=INT)
@click.option("--il", type=INT, help="Integration limit.")
@click.option("--ds", type=int, help="Derivative sampling interval, 1..256 samples.")
@click.option("--no-update", is_flag=True, help="Load only (LFIL), no UDF.")
def filter_cmd(kp: int | None, ki: int | None, kd: int | None, il: int | None, ds: int | None,
               no_update: bool) -> None:
    """Load PID coefficients (LFIL) and apply them (UDF)."""
    if all(v is None for v in (kp, ki, kd, il, ds)):
        raise click.UsageError("give at least one of --kp --ki --kd --il --ds")
    s = _session()
    chip = s.open()
    chip.filter_program(kp, ki, kd, il, ds)  # validate before any traffic
    if ds is None and not s.is_sim:
        # the chip cannot report its derivative interval and every LFIL carries it (AN-706
        # 4.5.1): a new process does not know the last one, so say what is sent
        click.echo("lm629: no --ds: the derivative interval is set to 1 sample (pass --ds N "
                   "to keep another one)", err=True)
    chip.load_filter(kp, ki, kd, il, ds)
    if not no_update:
        chip.update_filter()
    loaded = ", ".join(f"{k}={v}" for k, v in dict(kp=kp, ki=ki, kd=kd, il=il, ds=ds).items()
                       if v is not None)
    click.echo(f"filter loaded{'' if no_update else ' and updated'}: {loaded}")


def _motion_words(s: Session, velocity: float | None, acceleration: float | None,
                  raw: bool) -> tuple[int, int]:
    """(velocity, acceleration) raw words from the options: rpm and rev/s^2 with --lines."""
    scale = None if raw else s.scale
    if scale is None:
        v = 65536 if velocity is None else velocity
        a = 655 if acceleration is None else acceleration
        for name, x in (("--vel", v), ("--acc", a)):
            if float(x) != int(x):
                raise click.BadParameter(f"{x:g} must be a whole raw word without --lines",
                                         param_hint=name)
        v, a = int(v), int(a)
    else:
        try:
            v = scale.velocity(60.0 if velocity is None else velocity)
            a = scale.acceleration(10.0 if acceleration is None else acceleration)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--vel/--acc") from None
    for name, word, hi, what in (("--vel", v, VELOCITY_MAX, "the motor would never move"),
                                 ("--acc", a, ACCELERATION_MAX, "the move would never start")):
        if word < 1:
            raise click.BadParameter(f"gives the word {word}: {what} (the word must be "
                                     f"1..{hi})", param_hint=name)
        if word > hi:
            raise click.BadParameter(f"gives the word {word}, above the chip's {hi}",
                                     param_hint=name)
    return v, a


def _acceleration_unless_moving(chip: LM629, acceleration: int, given: bool) -> int | None:
    """The acceleration word to load, or None while the motor moves: the chip refuses an STT
    that changes the acceleration during a move with the drive on (AN-706 4.6.1), so velocity
    and target change on the fly with the acceleration already loaded."""
    if not chip.is_moving():
        return acceleration
    if given:
        raise ValueError("--acc: the motor is moving, and the chip refuses a new acceleration "
                         "until the move has ended or the motor is off (AN-706 4.6.1); leave "
                         "--acc out to change velocity or target on the fly, or `lm629 stop` first")
    return None


def _wait_still(chip: LM629, limit_s: float, poll: float = 0.01) -> Snapshot:
    """Wait (at most ``limit_s``) until the shaft has not moved for 5 polls."""
    snap = chip.snapshot()
    end = snap.time + limit_s
    still = 0
    while still < 5 and snap.time < end:
        chip.clock.sleep(poll)
        last, snap = snap, chip.snapshot()
        still = still + 1 if (snap.real_position == last.real_position
                              and snap.real_velocity == 0) else 0
    return snap


def _tolerance(s: Session, tolerance: float | None, raw: bool) -> int | None:
    if tolerance is None:
        return None
    if tolerance < 0:
        raise click.BadParameter(f"{tolerance:g} must be >= 0", param_hint="--tolerance")
    return _position(s, tolerance, "--tolerance", raw)


@main.command(context_settings=SIGNED_ARGS)
@click.argument("target", type=FINITE)
@click.option("--relative", "-r", is_flag=True, help="TARGET is a distance from where it is.")
@click.option("--vel", type=FINITE, help="Velocity: rpm with --lines (default 60), else raw "
                                          "16.16 counts/sample (default 65536).")
@click.option("--acc", type=FINITE, help="Acceleration: rev/s^2 with --lines (default 10), else "
                                          "raw 16.16 counts/sample^2 (default 655).")
@click.option("--raw", is_flag=True, help="Counts and raw words even with --lines.")
@click.option("--tolerance", type=FINITE, default=None,
              help=f"Done when the shaft rests this close to the target (counts; revolutions "
                   f"with --lines; default {MoveRules().tolerance} counts).")
@click.option("--no-wait", is_flag=True, help="Start the move and return (it keeps running).")
@click.option("--timeout", type=FINITE, default=None,
              help="Seconds to wait (default: 1.5 x the profile + 2 s).")
def move(target: float, relative: bool, vel: float | None, acc: float | None, raw: bool,
         tolerance: float | None, no_wait: bool, timeout: float | None) -> None:
    """Move to TARGET (counts; revolutions with --lines; negative as typed: move -5000) and
    wait until the shaft rests on it.  A move that does not end on target is a motion fault:
    the motor is stopped and the exit code is 9."""
    s = _session()
    v, a = _motion_words(s, vel, acc, raw)
    counts = _position(s, target, "TARGET", raw)
    tol = _tolerance(s, tolerance, raw)
    positive("--timeout", timeout)
    chip = s.open()
    # every check before anything moves: the words, the goal, and whether the chip would
    # refuse a new acceleration because the motor is still moving (AN-706 4.6.1)
    chip.trajectory_program(acceleration=a, velocity=v, position=0)
    if relative:
        chip.trajectory_program(position=chip.read_desired_position() + counts)
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    scale = None if raw else s.scale
    with stop_on_error(chip):
        m = chip.move_to(counts, velocity=v, acceleration=acceleration, relative=relative)
        click.echo(f"moving to {_show_position(s, m.target)} (velocity word {v}, acceleration "
                   f"word {a if acceleration is not None else 'as loaded (moving)'})")
        if no_wait:
            return
        with _live(_isatty()) as show:
            shown = [-1.0]

            def progress(snap: Snapshot) -> None:
                if snap.time - shown[0] >= 0.05:  # 20 updates a second of the chip's clock
                    shown[0] = snap.time
                    show(_progress_line(snap, m.target, scale))
            r = m.wait(timeout=timeout, tolerance=tol, progress=progress)
    click.echo(f"done: at {_show_position(s, r.position)}, {r.error:+d} counts from the target "
               f"{m.target} (tolerance {tol if tol is not None else chip.move_rules.tolerance}), "
               f"at rest {r.duration:.3f} s after the start")


@main.command(context_settings=SIGNED_ARGS)
@click.argument("speed", type=FINITE)
@click.option("--acc", type=FINITE, help="rev/s^2 with --lines, else raw (default 655).")
@click.option("--reverse", is_flag=True, help="Turn backwards.")
@click.option("--raw", is_flag=True, help="Raw words even with --lines.")
@click.option("--time", "run_s", type=FINITE, default=None,
              help="Run this many seconds, check the shaft turns at the speed, then stop "
                   "smoothly and wait until it rests (else leave it running).")
def velocity(speed: float, acc: float | None, reverse: bool, raw: bool,
             run_s: float | None) -> None:
    """Velocity mode at SPEED (rpm with --lines, else raw 16.16 counts/sample)."""
    s = _session()
    if speed < 0:
        raise click.BadParameter(f"{speed:g} must be >= 0; use --reverse to turn backwards",
                                 param_hint="SPEED")
    v, a = _motion_words(s, speed, acc, raw)
    positive("--time", run_s)
    scale = None if raw else s.scale

    def speed_text(word: int) -> str:
        return (f"{scale.rpm(word):.1f} rpm" if scale is not None
                else f"{word / FIXED_ONE:.4f} counts/sample")

    chip = s.open()
    chip.trajectory_program(acceleration=a, velocity=v, velocity_mode=True)
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    with stop_on_error(chip):
        chip.load_trajectory(acceleration=acceleration, velocity=v, velocity_mode=True,
                             forward=not reverse, start=True)
        click.echo(f"velocity mode {'backward' if reverse else 'forward'}: {speed_text(v)} "
                   f"(velocity word {v}, acceleration word {a})")
        if run_s is None:
            return
        chip.clock.sleep(run_s)
        snap = chip.snapshot()
        want = snap.desired_velocity  # where the ramp is now (the target speed or on the way)
        got = snap.real_velocity * FIXED_ONE
        click.echo(f"after {run_s:g} s: actual {speed_text(got)} (desired "
                   f"{speed_text(snap.desired_velocity)}), position "
                   f"{_show_position(s, snap.real_position)}")
        if abs(want) >= FIXED_ONE:
            # from 1 count/sample up the shaft must turn the desired way at least at half the
            # desired speed (the real velocity is whole counts/sample)
            if got * want < 0:
                raise _motion_fault(chip, MotionError.RUNAWAY, snap,
                                    "the shaft turns the wrong way: swap the motor leads or "
                                    "the encoder's A and B channels")
            if abs(got) < abs(want) // 2:
                raise _motion_fault(chip, MotionError.STALL, snap,
                                    f"the shaft turns at {speed_text(got)}, not "
                                    f"{speed_text(want)}: check the amplifier, the motor "
                                    "and the encoder, or lower the speed")
        chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)  # the stop's own completion, below
        chip.load_trajectory(stop="smooth", start=True)
        decel_s = abs(snap.desired_velocity) / max(a, 1) * s.sample_s
        _wait_flag(chip, Status.TRAJECTORY_COMPLETE, "the smooth stop to complete",
                   decel_s * 1.5 + 1.0)
        rest = _wait_still(chip, 1.0)
        if rest.real_velocity != 0:
            raise _motion_fault(chip, MotionError.FOLLOWING_ERROR, rest,
                                "the shaft did not come to rest after the smooth stop")
    click.echo(f"smooth stop: at rest at {_show_position(s, rest.real_position)}")


def _motion_fault(chip: LM629, reason: str, snap: Snapshot, message: str) -> MotionError:
    """Stop the motor (abrupt, then off) and make the MotionError that says so."""
    _ok, note = emergency_stop(chip)
    exc = MotionError(reason, f"{message}; {note}", position=snap.real_position,
                      error=snap.following_error)
    setattr(exc, STOP_NOTE, note)
    return exc


@main.command()
@click.option("--smooth", "mode", flag_value="smooth", help="Decelerate at the loaded rate.")
@click.option("--abrupt", "mode", flag_value="abrupt", default=True,
              help="Stop at once, hold position (default).")
@click.option("--off", "mode", flag_value="off", help="Motor off (output zero).")
def stop(mode: str) -> None:
    """Stop the motor."""
    chip = _session().open()
    chip.load_trajectory(stop=mode, start=True)
    click.echo(f"{mode} stop sent")


@main.command()
def home() -> None:
    """Define the current position as 0 (DFH)."""
    chip = _session().open()
    chip.define_home()
    click.echo("home defined: position 0 is here")


@main.command()
@click.option("--wait", "wait_s", type=FINITE, default=None,
              help="Wait up to this many seconds for the index pulse and print where it was.")
@click.option("--search", type=INT, default=None, metavar="WORD",
              help="Turn slowly (velocity mode, raw word) until the index is seen, then stop.")
def index(wait_s: float | None, search: int | None) -> None:
    """Latch the position at the next index pulse (SIP).  Without --search nothing moves, and
    a wait that times out leaves the motor as it was."""
    positive("--wait", wait_s)
    if search is not None and not 1 <= search <= VELOCITY_MAX:
        raise click.BadParameter(f"{search} must be a velocity word 1..{VELOCITY_MAX}",
                                 param_hint="--search")
    s = _session()
    chip = s.open()
    if search is not None:
        chip.trajectory_program(acceleration=655, velocity=search, velocity_mode=True)
    chip.reset_interrupts(Status.INDEX_PULSE)
    chip.set_index_position()
    if search is None and wait_s is None:
        click.echo("index armed (SIP): read it later with `lm629 status` / RDIP")
        return
    words = "the index pulse (status bit 3)"
    if search is None:  # only waiting: a timeout must not touch a servo holding position
        _wait_flag(chip, Status.INDEX_PULSE, words, wait_s or 10.0)
    else:
        with stop_on_error(chip):
            chip.load_trajectory(acceleration=655, velocity=search, velocity_mode=True,
                                 start=True)
            _wait_flag(chip, Status.INDEX_PULSE, words + " while turning", wait_s or 10.0)
            chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
            chip.load_trajectory(stop="abrupt", start=True)
            _wait_still(chip, 1.0)
    click.echo(f"index at position {_show_position(s, chip.read_index_position())}")


@main.command(context_settings=SIGNED_ARGS)
@click.argument("position", type=FINITE)
@click.option("--relative", "-r", is_flag=True, help="Relative to the current target (SBPR).")
@click.option("--raw", is_flag=True, help="Counts even with --lines.")
@click.option("--wait", "wait_s", type=FINITE, default=None, help="Wait for it (seconds).")
def breakpoint(position: float, relative: bool, raw: bool, wait_s: float | None) -> None:  # noqa: A001 - the command is `lm629 breakpoint`
    """Set a breakpoint (SBPA/SBPR) at POSITION (counts; revolutions with --lines); status
    bit 6 when the position passes it."""
    s = _session()
    counts = _position(s, position, "POSITION", raw)
    positive("--wait", wait_s)
    chip = s.open()
    chip.set_breakpoint(counts, relative=relative)
    chip.reset_interrupts(Status.BREAKPOINT)
    click.echo(f"breakpoint {'relative ' if relative else ''}{_show_position(s, counts)} set")
    if wait_s is not None:
        _wait_flag(chip, Status.BREAKPOINT, "the breakpoint (status bit 6)", wait_s)
        click.echo(f"breakpoint reached at {_show_position(s, chip.read_real_position())}")


@main.command(context_settings=SIGNED_ARGS)
@click.argument("threshold", type=INT)
@click.option("--stop", "stop_motor", is_flag=True,
              help="Also turn the motor off when exceeded (LPES); default flag only (LPEI).")
def limit(threshold: int, stop_motor: bool) -> None:
    """Following-error limit in counts (LPEI, or LPES with --stop)."""
    check_int("THRESHOLD", threshold, 0, 0x7FFF)
    chip = _session().open()
    chip.load_position_error(threshold, stop=stop_motor)
    click.echo(f"{'LPES' if stop_motor else 'LPEI'} {threshold} counts: status bit 5"
               + (" and motor off" if stop_motor else "") + " when the error exceeds it")


@main.command()
@click.option("--rate", type=FINITE, default=10.0, show_default=True, help="Rows per second.")
@click.option("--count", type=int, default=None, help="Stop after this many rows.")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default=None,
              help="Also log every row to this CSV file.")
def watch(rate: float, count: int | None, csv_path: str | None) -> None:
    """A live table of desired/actual position, velocity, error and flags (Ctrl-C ends it).

    The rows are timed on the chip's clock: simulated time on sim://."""
    import csv as csvmod
    if not 0 < rate <= 1000:
        raise click.BadParameter(f"{rate:g} must be in 0..1000 rows per second",
                                 param_hint="--rate")
    if count is not None and count < 1:
        raise click.BadParameter(f"{count} must be at least 1", param_hint="--count")
    if csv_path:
        check_writable(csv_path, "--csv")
    s = _session()
    scale = s.scale
    chip = s.open()
    f = open(csv_path, "w", newline="") if csv_path else None  # noqa: SIM115 - closed in finally
    writer = csvmod.writer(f) if f else None
    header: tuple[str, ...] = ("t_s", "desired_position", "real_position", "following_error",
              "desired_velocity", "real_velocity", "status", "flags")
    if scale is not None:
        header = header[:6] + ("real_position_rev", "real_velocity_rpm") + header[6:]
    if writer:
        writer.writerow(header)
    click.echo(f"{'t_s':>9} {'desired':>10} {'actual':>10} {'error':>7} {'dv':>10} {'rv':>6} "
               + (f"{'rev':>10} {'rpm':>8} " if scale is not None else "") + f"{'st':>3} flags")
    n = 0
    start = chip.clock.now()
    try:
        while count is None or n < count:
            snap = chip.snapshot()
            row: tuple[Any, ...] = (
                f"{snap.time:.4f}", snap.desired_position, snap.real_position,
                snap.following_error, f"{snap.desired_velocity / FIXED_ONE:.4f}",
                snap.real_velocity)
            units = ""
            if scale is not None:
                extra = (f"{scale.revolutions(snap.real_position):.4f}",
                         f"{scale.rpm(snap.real_velocity * FIXED_ONE):.1f}")
                row += extra
                units = f"{extra[0]:>10} {extra[1]:>8} "
            row += (f"{int(snap.status):02X}", _flags(snap.status))
            click.echo(f"{row[0]:>9} {row[1]:>10} {row[2]:>10} {row[3]:>+7} {row[4]:>10} "
                       f"{row[5]:>+6} {units}{row[-2]:>3} {row[-1]}")
            if writer:
                writer.writerow(row)
            n += 1
            if count is None or n < count:  # a fixed cadence: the rows do not drift
                chip.clock.sleep(max(0.0, start + n / rate - chip.clock.now()))
    except KeyboardInterrupt:
        # watching moves nothing, so nothing is stopped; the exit code says how it ended
        with contextlib.suppress(OSError, ValueError):
            click.echo(f"({n} rows)", err=True)
        raise
    finally:
        if f:
            f.close()


@main.command(context_settings=SIGNED_ARGS)
@click.argument("distance", type=FINITE, default=200)
@click.option("--kp", type=INT)
@click.option("--ki", type=INT)
@click.option("--kd", type=INT)
@click.option("--il", type=INT)
@click.option("--ds", type=int, help="Derivative sampling interval, samples.")
@click.option("--vel", type=FINITE, default=None,
              help="Velocity: rpm with --lines, else a raw word (default: a step).")
@click.option("--acc", type=FINITE, default=None,
              help="Acceleration: rev/s^2 with --lines, else a raw word (default: a step).")
@click.option("--raw", is_flag=True, help="Counts and raw words even with --lines.")
@click.option("--tolerance", type=FINITE, default=None,
              help="Done when the shaft rests this close to the target (counts; revolutions "
                   "with --lines).")
@click.option("--time", "duration", type=FINITE, default=0.5, show_default=True,
              help="Seconds to record.")
@click.option("--interval", type=FINITE, default=0.001, show_default=True,
              help="Seconds between snapshots (on a bridge, at least one round trip).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default="step.csv",
              show_default=True)
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None,
              help="Plot file (default: the CSV name with .png).")
@click.option("--no-png", is_flag=True, help="CSV only.")
def step(distance: float, kp: int | None, ki: int | None, kd: int | None, il: int | None,
         ds: int | None, vel: float | None, acc: float | None, raw: bool,
         tolerance: float | None, duration: float, interval: float, csv_path: str,
         png_path: str | None, no_png: bool) -> None:
    """Record a step (or, with --vel/--acc, a move) of DISTANCE (counts; revolutions with
    --lines): CSV and PNG of desired and actual position over time, for tuning (AN-706
    figure 11).  Then wait until the shaft rests on the target (else a motion fault, exit 9;
    the files are written either way)."""
    from .capture import STEP_ACCELERATION, STEP_VELOCITY
    s = _session()
    counts = _position(s, distance, "DISTANCE", raw)
    v, a = _motion_words(s, vel, acc, raw)
    v = STEP_VELOCITY if vel is None else v
    a = STEP_ACCELERATION if acc is None else a
    tol = _tolerance(s, tolerance, raw)
    positive("--time", duration)
    positive("--interval", interval)
    if interval > duration:
        raise click.BadParameter(f"{interval:g} is longer than --time {duration:g}",
                                 param_hint="--interval")
    check_writable(csv_path, "--csv")
    png = None if no_png else png_path or os.path.splitext(csv_path)[0] + ".png"
    if png:
        check_writable(png, "--png")
    from .plot import plot_capture
    filt = {k: v for k, v in dict(kp=kp, ki=ki, kd=kd, il=il,
                                  derivative_interval=ds).items() if v is not None}
    chip = s.open()
    cap = capture_move(chip, counts, duration_s=duration, interval_s=interval,
                       velocity=v, acceleration=a, filter=filt, tolerance=tol)
    for line in summary(cap):
        click.echo(line)
    if s.scale is not None and not raw:
        sc = s.scale
        click.echo(f"in revolutions: target {sc.revolutions(cap.target):.4f}, largest following "
                   f"error {sc.revolutions(cap.max_following_error):+.4f}, overshoot "
                   f"{sc.revolutions(cap.overshoot):.4f}, final error "
                   f"{sc.revolutions(cap.final_error):+.4f}")
    click.echo(f"wrote {write_csv(cap, csv_path)}")
    if png:
        try:
            click.echo(f"wrote {plot_capture(cap, png, lines=s.lines)}")
        except PlotUnavailable as exc:
            click.echo(f"lm629: {exc}", err=True)
    if cap.fault is not None:
        raise cap.fault


@main.command()
@click.argument("command", type=INT)
@click.argument("words", type=INT, nargs=-1)
@click.option("--read", "read_n", type=int, default=0, help="Words to read after the command.")
def raw(command: int, words: tuple[int, ...], read_n: int) -> None:
    """Send a COMMAND byte (0x1F, 1Fh) with WORDS to write, or --read N words: for experts.
    Exit 6 when the chip sets its command-error bit in answer."""
    check_int("command", command, 0, 0xFF, hex_digits=2)
    for w in words:
        check_int("word", w, 0, 0xFFFF, hex_digits=4)
    check_int("--read", read_n, 0, 16)
    if words and read_n:
        raise click.BadParameter("a command either writes words or reads them, not both",
                                 param_hint="--read")
    chip = _session().open()
    chip.reset_interrupts(Status.COMMAND_ERROR)  # so that the flag after it is its own
    got = chip.raw(command, words, read_n)
    st = chip.sync()
    out = " ".join(f"{w:04X}" for w in got)
    click.echo((f"read {out}  " if got else "") + f"status {int(st):02X} ({_flags(st)})")
    if st & Status.COMMAND_ERROR:
        raise CommandError(f"command {command:02X}h", int(st))


@main.command("list")
def list_cmd() -> None:
    """Ports that can be found: simulators, serial bridges, FT232H adapters."""
    from .transports import transport_classes
    for scheme, cls, problem in transport_classes():
        if cls is None:
            click.echo(f"{scheme}://  not available: {problem}")
            continue
        try:
            ports = cls.list_ports()
        except Exception as exc:  # noqa: BLE001 - one backend's failure is one line
            click.echo(f"{scheme}://  listing failed: {exc}")
            continue
        for p in ports:
            mark = "" if p.usable else f"  [cannot open: {p.problem}]"
            click.echo(f"{p.url:27s} {p.description}{mark}")


@main.command()
@click.option("--path", "path_only", is_flag=True, help="Print only the rule file's path.")
def udev(path_only: bool) -> None:
    """The udev rule that lets your user open FT232H adapters (ftdi://) without root: where
    this installation keeps it, and the commands that install it."""
    from . import data
    if path_only:
        click.echo(str(data.udev_rule()))
        return
    click.echo(f"rule file: {data.udev_rule()}")
    click.echo("install it (once per machine), then replug the adapter:")
    for command in data.udev_install_commands():
        click.echo(f"    {command}")


@main.command()
def doctor() -> None:
    """What is installed, what can be found and what is wrong (backends, permissions, latency,
    firmware version, round-trip time)."""
    import platform
    import time
    s = _session()
    problems = 0

    def line(name: str, ok: bool, msg: str) -> None:
        nonlocal problems
        problems += not ok
        click.echo(f"  [{click.style('ok' if ok else '!!', fg='green' if ok else 'red')}] "
                   f"{name}: {msg}")

    click.echo("python and packages")
    line("python", sys.version_info >= (3, 10), platform.python_version())
    line("lm629-host", True, lm629_host.__version__)
    try:
        import matplotlib
        line("matplotlib", True, f"{matplotlib.__version__} (lm629 step draws PNGs)")
    except ImportError:
        line("matplotlib", False, "missing: lm629 step writes CSV only; "
                                  "pip install 'lm629-host[plot]'")
    from .transports import transport_classes
    for scheme, cls, problem in transport_classes():
        if cls is None:
            click.echo(f"{scheme}://")
            line(scheme, False, f"transport not available: {problem}")
            continue
        try:
            checks = cls.doctor()
        except Exception as exc:  # noqa: BLE001 - one backend's failure is one line
            click.echo(f"{scheme}://")
            line(scheme, False, f"doctor failed: {exc}")
            continue
        if checks:
            click.echo(f"{scheme}://")
        for c in checks:
            line(c.name, c.ok, c.message)
    if s.port_given:
        click.echo(f"port {s.port}")
        try:
            chip = s.open(prepare=False)
            line("open", True, chip.transport.describe())
            t0 = time.perf_counter()
            n = 20
            busy = 0
            for _ in range(n):
                st = chip.read_status()
                busy += bool(st & Status.BUSY)
            dt = (time.perf_counter() - t0) / n
            stuck = (f"; the busy bit was set in all {n} reads: the chip is stuck busy (check "
                     "its clock input, its supply and /RST)") if busy == n else ""
            line("status read", busy < n, f"{int(st):02X} ({_flags(st)}), {dt * 1e3:.3f} ms "
                                          f"per round trip (wall clock){stuck}")
        except LM629Error as exc:
            line("open", False, str(exc))
    click.echo("no problems found" if not problems else f"{problems} problem(s) above")
    if problems:
        click.get_current_context().exit(1)


main.add_command(calc)
main.add_command(_tune)  # lm629 tune (lm629_host/cli_tune.py)

try:  # the serial-bridge groups: `lm629 bridge list|flash`, `lm629 sim serve`
    from .cli_bridge import bridge as _bridge
    from .cli_bridge import sim as _sim
    main.add_command(_bridge)
    main.add_command(_sim)
except ImportError:  # pragma: no cover - before the bridge work landed
    pass


__all__ = ["main", "EXIT_CODES", "Session", "Terminated", "parse_int", "snapshot_dict"]
