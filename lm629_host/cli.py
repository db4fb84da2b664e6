"""``lm629``: the bench command line, from first power-on to a tuned move.

Each command opens the port (``--port``, else ``$LM629_PORT``, else the simulator), does one
job through :class:`lm629_host.LM629` and closes it.  Commands that start a move run inside
:func:`lm629_host.cli_safety.stop_on_error`: Ctrl-C or any error stops the motor (abrupt stop,
then motor off) before the program exits.  Errors are one line on stderr (a traceback with
``-v``) and an exit code per error class (see ``EXIT_CODES``, printed by ``lm629 --help``).

An in-process simulator (``sim://``, ``sim+avr://``, ``sim+ftdi://``, ``sim+emu://``) is a fresh
chip for each command: the CLI resets it and loads kp = 20 first, so that ``move`` and friends
do something, and says so on stderr.  For a simulated chip that keeps its state between
commands run ``lm629 sim serve --pty /tmp/lm629`` and use ``--port /tmp/lm629``.
"""

from __future__ import annotations

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
from typing import Any

import click

import lm629_host

from .bringup import BringupOptions, StepResult, run_bringup
from .capture import PlotUnavailable, capture_move, summary, write_csv, write_png
from .cli_calc import calc
from .cli_tune import tune as _tune
from .cli_safety import STOP_NOTE, stop_on_error
from .errors import (
    BusyTimeout,
    CommandError,
    LM629Error,
    ResetError,
    TransportError,
    WaitTimeout,
)
from .lm629 import LM629, Snapshot, check_int
from .opcodes import Signals, Status
from .program import BusCycle, Program
from .transports import query_params, scheme_of
from .units import FIXED_ONE, Scale

log = logging.getLogger("lm629_host.cli")

#: exit code -> meaning (one place: the handler and ``--help`` both read it)
EXIT_CODES: dict[int, str] = {
    0: "success",
    1: "a check failed (bringup verdict)",
    2: "bad usage or bad value (nothing was sent to the chip)",
    3: "transport error (port missing, busy, no permission, no answer)",
    4: "busy timeout (the chip held its busy bit)",
    5: "reset failure (the chip did not come out of reset)",
    6: "command error (the chip rejected a command)",
    7: "wait timeout (a move or flag did not come in time)",
    8: "other driver error",
    130: "interrupted (Ctrl-C); a moving motor was stopped first",
}

_ERROR_EXITS: tuple[tuple[type[BaseException], int], ...] = (
    (ValueError, 2), (TransportError, 3), (BusyTimeout, 4), (ResetError, 5),
    (CommandError, 6), (WaitTimeout, 7), (LM629Error, 8),
)

SIM_PREFIX = "sim"


def _open(url: str, chip: str, trace: Callable[[BusCycle], None] | None) -> LM629:
    """Open the chip (one seam, so that tests can watch what the CLI opened)."""
    return lm629_host.open(url, chip=chip, trace=trace)


def parse_int(text: str) -> int:
    """Decimal, 0x hex, 0b binary; a trailing 'h' also means hex (datasheet style)."""
    t = text.strip().replace("_", "")
    try:
        if t.lower().endswith("h") and not t.lower().startswith("0x"):
            return int(t[:-1], 16)
        return int(t, 0)
    except ValueError:
        raise click.BadParameter(f"{text!r} is not an integer (decimal, 0x.. hex, or ..h)") from None


class IntWord(click.ParamType):
    name = "INT"

    def convert(self, value: Any, param: Any, ctx: Any) -> int:
        return value if isinstance(value, int) else parse_int(str(value))


INT = IntWord()


def _hz(text: str) -> float:
    t = str(text).strip().lower().replace("hz", "")
    mult = 1.0
    if t.endswith("m"):
        mult, t = 1e6, t[:-1]
    elif t.endswith("k"):
        mult, t = 1e3, t[:-1]
    return float(t) * mult


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
    _old_sigint: Any = None

    @property
    def is_sim(self) -> bool:
        return scheme_of(self.port).startswith(SIM_PREFIX)

    @property
    def scale(self) -> Scale | None:
        return Scale(self.lines, self.clock_hz) if self.lines else None

    @property
    def sample_s(self) -> float:
        return 2048 / self.clock_hz

    def url(self) -> str:
        """The port URL; a simulator URL gets the global --chip/--clock/--lines unless it
        names them itself, so that the simulated chip matches the options."""
        if not self.is_sim:
            return self.port
        have = query_params(self.port)
        add = {"chip": self.chip_name, "clock": str(int(self.clock_hz))}
        if self.lines:
            add["lines"] = str(self.lines)
        extra = "&".join(f"{k}={v}" for k, v in add.items() if k not in have)
        if not extra:
            return self.port
        sep = "&" if "?" in self.port else "?"
        return self.port + sep + extra

    def _guard_programs(self, chip: LM629) -> None:
        """Ctrl-C never cuts a bus program in half: SIGINT during a program is held until
        the program has finished, then raised as KeyboardInterrupt (so that the safety stop
        that follows starts on a clean bus)."""
        if threading.current_thread() is not threading.main_thread():
            return
        state = {"depth": 0, "pending": False}

        def on_sigint(signum: int, frame: Any) -> None:
            if state["depth"]:
                state["pending"] = True
            else:
                raise KeyboardInterrupt

        execute = chip.transport.execute

        def guarded(program: Program):  # type: ignore[no-untyped-def]
            state["depth"] += 1
            try:
                result = execute(program)
            finally:
                state["depth"] -= 1
            if state["pending"] and not state["depth"]:
                state["pending"] = False
                raise KeyboardInterrupt
            return result

        chip.transport.execute = guarded  # type: ignore[method-assign]
        self._old_sigint = signal.signal(signal.SIGINT, on_sigint)

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
        if self._old_sigint is not None:
            signal.signal(signal.SIGINT, self._old_sigint)
            self._old_sigint = None


def _help_epilog() -> str:
    codes = "\n".join(f"  {k:>3}  {v}" for k, v in EXIT_CODES.items())
    return ("\b\nExit codes:\n" + codes + "\n\n\bWith neither --port nor LM629_PORT the bundled "
            "simulator is used (a fresh chip per command).\nStart with:  lm629 bringup --yes")


class LM629Group(click.Group):
    """A click group that turns exceptions into one stderr line and an exit code."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.exceptions.Abort):
            raise
        except KeyboardInterrupt as exc:
            _fail(ctx, "interrupted", exc, 130)
        except BrokenPipeError:
            # stdout closed early (`lm629 calc ... | head`): not an error; keep Python from
            # complaining again when it flushes stdout at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            ctx.exit(0)
        except Exception as exc:  # noqa: BLE001 - mapped to exit codes below
            code = next((c for cls, c in _ERROR_EXITS if isinstance(exc, cls)), None)
            if code is None:
                _fail(ctx, f"internal error ({type(exc).__name__}): {exc}", exc, 8, always_tb=True)
            kind = "bad value" if isinstance(exc, ValueError) else "error"
            _fail(ctx, f"{kind}: {exc}", exc, code)


def _fail(ctx: click.Context, message: str, exc: BaseException, code: int,
          always_tb: bool = False) -> None:
    session = ctx.obj if isinstance(ctx.obj, Session) else None
    if always_tb or (session is not None and session.verbose):
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    note = getattr(exc, STOP_NOTE, None)
    click.echo(f"lm629: {message}" + (f" -- {note}" if note else ""), err=True)
    ctx.exit(code)


@click.group(cls=LM629Group, epilog=_help_epilog(),
             context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--port", "-p", envvar="LM629_PORT", default=None, metavar="URL",
              help="sim://, serial://PATH or a device path, ftdi://..., sim+avr:// "
                   "(env LM629_PORT; default sim://).")
@click.option("--chip", "chip_name", type=click.Choice(["lm628", "lm629"]), default="lm629",
              show_default=True, help="Which chip is on the board.")
@click.option("--clock", default="8MHz", show_default=True, metavar="HZ",
              help="The chip's clock (8MHz, 6e6...): sample period 2048/clock.")
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
        clock_hz = _hz(clock)
    except ValueError:
        raise click.BadParameter(f"{clock!r} is not a frequency (8MHz, 6e6)",
                                 param_hint="--clock") from None
    if not 1e6 <= clock_hz <= 8e6:
        raise click.BadParameter(f"{clock_hz:g} Hz is outside the chip's 1-8 MHz",
                                 param_hint="--clock")
    if lines is not None and lines < 1:
        raise click.BadParameter(f"{lines} must be at least 1", param_hint="--lines")
    _log_to_stderr({0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG))
    session = Session(port or lm629_host.DEFAULT_URL, port is not None, chip_name, clock_hz,
                      lines, verbose, trace, stats)
    ctx.obj = session
    ctx.call_on_close(session.close)


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
    return click.get_current_context().find_object(Session)  # type: ignore[return-value]


# ---------------------------------------------------------------------------------- rendering
def _flags(status: int) -> str:
    names = [f.name.lower() for f in Status if status & f]  # type: ignore[union-attr]
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


def _progress_line(s: Snapshot, target: int | None = None) -> str:
    tgt = f" -> {target}" if target is not None else ""
    return (f"t={s.time:8.3f}s  desired {s.desired_position:>10d}{tgt}  actual "
            f"{s.real_position:>10d}  error {s.following_error:>+6d}  v {s.real_velocity:+d}")


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
@click.option("--move", "move_distance", type=INT, default=1000, show_default=True,
              help="Counts of the small move.")
@click.option("--hold-kp", type=int, default=20, show_default=True, help="kp of the hold step.")
def bringup(yes: bool, move_distance: int, hold_kp: int) -> None:
    """The AN-706 2.12 bring-up: reset, phasing at kp = 1, kp = 20 hold, a small move,
    following error and settle time, next steps."""
    s = _session()
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
        return yes or click.confirm(question, default=False)

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
                raise ValueError(f"{name}={x} must be a whole raw word without --lines")
        return int(v), int(a)
    v = scale.velocity(60.0 if velocity is None else velocity)
    a = scale.acceleration(10.0 if acceleration is None else acceleration)
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


def _wait_move(chip: LM629, target: int | None, timeout: float, poll: float) -> Snapshot:
    clock = chip.clock
    deadline = clock.now() + timeout
    with _live(_isatty()) as show:
        while True:
            snap = chip.snapshot()
            show(_progress_line(snap, target))
            if snap.status & Status.TRAJECTORY_COMPLETE:
                return snap
            if clock.now() >= deadline:
                raise WaitTimeout(Status.TRAJECTORY_COMPLETE, timeout, int(snap.status))
            clock.sleep(poll)


@main.command()
@click.argument("target", type=float)
@click.option("--relative", "-r", is_flag=True, help="TARGET is a distance from where it is.")
@click.option("--vel", type=float, help="Velocity: rpm with --lines (default 60), else raw "
                                         "16.16 counts/sample (default 65536).")
@click.option("--acc", type=float, help="Acceleration: rev/s^2 with --lines (default 10), else "
                                         "raw 16.16 counts/sample^2 (default 655).")
@click.option("--raw", is_flag=True, help="Counts and raw words even with --lines.")
@click.option("--no-wait", is_flag=True, help="Start the move and return.")
@click.option("--timeout", type=float, default=60.0, show_default=True, help="Seconds to wait.")
def move(target: float, relative: bool, vel: float | None, acc: float | None, raw: bool,
         no_wait: bool, timeout: float) -> None:
    """Move to TARGET (counts; revolutions with --lines) and wait with a progress line."""
    s = _session()
    v, a = _motion_words(s, vel, acc, raw)
    if s.scale is not None and not raw:
        counts = s.scale.position(target)
    else:
        if float(target) != int(target):
            raise ValueError(f"TARGET={target} must be whole counts without --lines")
        counts = int(target)
    if timeout <= 0:
        raise ValueError(f"--timeout={timeout} must be positive (seconds)")
    chip = s.open()
    # every check before anything moves: the words, the goal, and whether the chip would
    # refuse a new acceleration because the motor is still moving (AN-706 4.6.1)
    chip.trajectory_program(acceleration=a, velocity=v, position=0)
    goal = chip.read_desired_position() + counts if relative else counts
    chip.trajectory_program(position=goal)
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    with stop_on_error(chip):
        chip.load_trajectory(acceleration=acceleration, velocity=v, position=goal, start=True)
        click.echo(f"moving to {goal} counts (velocity word {v}, acceleration word {a})")
        if no_wait:
            return
        snap = _wait_move(chip, goal, timeout, poll=0.05)
        done_at = snap.time
        snap = _wait_still(chip, 1.0)
    click.echo(f"done: desired {snap.desired_position}, actual {snap.real_position} "
               f"(error {snap.following_error:+d}); trajectory complete at t={done_at:.3f} s, "
               f"shaft at rest at t={snap.time:.3f} s")


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


@main.command()
@click.argument("speed", type=float)
@click.option("--acc", type=float, help="rev/s^2 with --lines, else raw (default 655).")
@click.option("--reverse", is_flag=True, help="Turn backwards.")
@click.option("--raw", is_flag=True, help="Raw words even with --lines.")
@click.option("--time", "run_s", type=float, default=None,
              help="Run this many seconds, then stop smoothly (else leave it running).")
def velocity(speed: float, acc: float | None, reverse: bool, raw: bool,
             run_s: float | None) -> None:
    """Velocity mode at SPEED (rpm with --lines, else raw 16.16 counts/sample)."""
    s = _session()
    if speed < 0:
        raise ValueError(f"SPEED={speed} must be >= 0; use --reverse to turn backwards")
    v, a = _motion_words(s, speed, acc, raw)
    if run_s is not None and run_s <= 0:
        raise ValueError(f"--time={run_s} must be positive (seconds)")
    chip = s.open()
    chip.trajectory_program(acceleration=a, velocity=v, velocity_mode=True)
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    with stop_on_error(chip):
        chip.load_trajectory(acceleration=acceleration, velocity=v, velocity_mode=True,
                             forward=not reverse, start=True)
        click.echo(f"velocity mode {'backward' if reverse else 'forward'}: velocity word {v}, "
                   f"acceleration word {a}")
        if run_s is None:
            return
        chip.clock.sleep(run_s)
        snap = chip.snapshot()
        click.echo(f"after {run_s:g} s: actual velocity {snap.real_velocity} counts/sample, "
                   f"position {snap.real_position}")
        chip.load_trajectory(stop="smooth", start=True)
        click.echo("smooth stop")


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
@click.option("--wait", "wait_s", type=float, default=None,
              help="Wait up to this many seconds for the index pulse and print where it was.")
@click.option("--search", type=INT, default=None, metavar="WORD",
              help="Turn slowly (velocity mode, raw word) until the index is seen, then stop.")
def index(wait_s: float | None, search: int | None) -> None:
    """Latch the position at the next index pulse (SIP)."""
    chip = _session().open()
    if search is not None:
        chip.trajectory_program(acceleration=655, velocity=search, velocity_mode=True)
    chip.reset_interrupts(Status.INDEX_PULSE)
    chip.set_index_position()
    if search is None and wait_s is None:
        click.echo("index armed (SIP): read it later with `lm629 status` / RDIP")
        return
    with stop_on_error(chip):
        if search is not None:
            chip.load_trajectory(acceleration=655, velocity=search, velocity_mode=True, start=True)
        chip.wait_for(Status.INDEX_PULSE, timeout=wait_s or 10.0, poll=0.001)
        if search is not None:
            chip.load_trajectory(stop="abrupt", start=True)
    click.echo(f"index at position {chip.read_index_position()}")


@main.command()
@click.argument("position", type=INT)
@click.option("--relative", "-r", is_flag=True, help="Relative to the current target (SBPR).")
@click.option("--wait", "wait_s", type=float, default=None, help="Wait for it (seconds).")
def breakpoint(position: int, relative: bool, wait_s: float | None) -> None:  # noqa: A001
    """Set a breakpoint (SBPA/SBPR); status bit 6 when the position passes it."""
    chip = _session().open()
    chip.set_breakpoint(position, relative=relative)
    chip.reset_interrupts(Status.BREAKPOINT)
    click.echo(f"breakpoint {'relative ' if relative else ''}{position} set")
    if wait_s is not None:
        chip.wait_for(Status.BREAKPOINT, timeout=wait_s)
        click.echo(f"breakpoint reached at {chip.read_real_position()}")


@main.command()
@click.argument("threshold", type=INT)
@click.option("--stop", "stop_motor", is_flag=True,
              help="Also turn the motor off when exceeded (LPES); default flag only (LPEI).")
def limit(threshold: int, stop_motor: bool) -> None:
    """Following-error limit in counts (LPEI, or LPES with --stop)."""
    chip = _session().open()
    chip.load_position_error(threshold, stop=stop_motor)
    click.echo(f"{'LPES' if stop_motor else 'LPEI'} {threshold} counts: status bit 5"
               + (" and motor off" if stop_motor else "") + " when the error exceeds it")


@main.command()
@click.option("--rate", type=float, default=10.0, show_default=True, help="Rows per second.")
@click.option("--count", type=int, default=None, help="Stop after this many rows.")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default=None,
              help="Also log every row to this CSV file.")
def watch(rate: float, count: int | None, csv_path: str | None) -> None:
    """A live table of desired/actual position, velocity, error and flags (Ctrl-C ends it).

    The rows are timed on the chip's clock: simulated time on sim://."""
    import csv as csvmod
    if not 0 < rate <= 1000:
        raise ValueError(f"--rate={rate} must be in 0..1000 rows per second")
    if count is not None and count < 1:
        raise ValueError(f"--count={count} must be at least 1")
    chip = _session().open()
    f = open(csv_path, "w", newline="") if csv_path else None  # noqa: SIM115
    writer = csvmod.writer(f) if f else None
    header = ("t_s", "desired_position", "real_position", "following_error",
              "desired_velocity", "real_velocity", "status", "flags")
    if writer:
        writer.writerow(header)
    click.echo(f"{'t_s':>9} {'desired':>10} {'actual':>10} {'error':>7} {'dv':>10} {'rv':>6} "
               f"{'st':>3} flags")
    n = 0
    start = chip.clock.now()
    try:
        while count is None or n < count:
            snap = chip.snapshot()
            row = (f"{snap.time:.4f}", snap.desired_position, snap.real_position,
                   snap.following_error, f"{snap.desired_velocity / FIXED_ONE:.4f}",
                   snap.real_velocity, f"{int(snap.status):02X}", _flags(snap.status))
            click.echo(f"{row[0]:>9} {row[1]:>10} {row[2]:>10} {row[3]:>+7} {row[4]:>10} "
                       f"{row[5]:>+6} {row[6]:>3} {row[7]}")
            if writer:
                writer.writerow(row)
            n += 1
            if count is None or n < count:  # a fixed cadence: the rows do not drift
                chip.clock.sleep(max(0.0, start + n / rate - chip.clock.now()))
    except KeyboardInterrupt:
        click.echo(f"({n} rows)", err=True)  # watching does not move anything: a clean end
    finally:
        if f:
            f.close()


@main.command()
@click.argument("distance", type=INT, default=200)
@click.option("--kp", type=INT)
@click.option("--ki", type=INT)
@click.option("--kd", type=INT)
@click.option("--il", type=INT)
@click.option("--ds", type=int, help="Derivative sampling interval, samples.")
@click.option("--vel", type=INT, default=None, help="Raw velocity word (default: a step).")
@click.option("--acc", type=INT, default=None, help="Raw acceleration word (default: a step).")
@click.option("--time", "duration", type=float, default=0.5, show_default=True,
              help="Seconds to record.")
@click.option("--interval", type=float, default=0.001, show_default=True,
              help="Seconds between snapshots (on a bridge, at least one round trip).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default="step.csv",
              show_default=True)
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None,
              help="Plot file (default: the CSV name with .png).")
@click.option("--no-png", is_flag=True, help="CSV only.")
def step(distance: int, kp: int | None, ki: int | None, kd: int | None, il: int | None,
         ds: int | None, vel: int | None, acc: int | None, duration: float, interval: float,
         csv_path: str, png_path: str | None, no_png: bool) -> None:
    """Record a step (or, with --vel/--acc, a move) of DISTANCE counts: CSV and PNG of desired
    and actual position over time, for tuning (AN-706 figure 11)."""
    from .capture import STEP_ACCELERATION, STEP_VELOCITY
    from .plot import plot_capture
    filt = {k: v for k, v in dict(kp=kp, ki=ki, kd=kd, il=il,
                                  derivative_interval=ds).items() if v is not None}
    s = _session()
    chip = s.open()
    cap = capture_move(chip, distance, duration_s=duration, interval_s=interval,
                       velocity=STEP_VELOCITY if vel is None else vel,
                       acceleration=STEP_ACCELERATION if acc is None else acc, filter=filt)
    for line in summary(cap):
        click.echo(line)
    click.echo(f"wrote {write_csv(cap, csv_path)}")
    if no_png:
        return
    png = png_path or os.path.splitext(csv_path)[0] + ".png"
    try:
        click.echo(f"wrote {plot_capture(cap, png, lines=s.lines)}")
    except PlotUnavailable as exc:
        click.echo(f"lm629: {exc}", err=True)


@main.command()
@click.argument("command", type=INT)
@click.argument("words", type=INT, nargs=-1)
@click.option("--read", "read_n", type=int, default=0, help="Words to read after the command.")
def raw(command: int, words: tuple[int, ...], read_n: int) -> None:
    """Send a COMMAND byte (0x1F, 1Fh) with WORDS to write, or --read N words: for experts."""
    chip = _session().open()
    got = chip.raw(command, words, read_n)
    st = chip.read_status()
    out = " ".join(f"{w:04X}" for w in got)
    click.echo((f"read {out}  " if got else "") + f"status {int(st):02X} ({_flags(st)})")


def _transport_modules() -> Iterator[tuple[str, Any, str | None]]:
    """(scheme, module or None, import problem) for every registered transport."""
    import importlib

    from .transports import SCHEMES
    seen: set[str] = set()
    for scheme, target in SCHEMES.items():
        name = target.split(":")[0]
        if name in seen:
            continue
        seen.add(name)
        try:
            yield scheme, importlib.import_module(name), None
        except Exception as exc:  # noqa: BLE001 - a missing optional backend is a doctor line
            yield scheme, None, f"{type(exc).__name__}: {exc}"


@main.command("list")
def list_cmd() -> None:
    """Ports that can be found: simulators, serial bridges, FT232H adapters."""
    click.echo("sim://                      the bundled chip simulator (always there)")
    for scheme, mod, problem in _transport_modules():
        if mod is None:
            click.echo(f"{scheme}://  not available: {problem}")
            continue
        lister = getattr(mod, "list_ports", None)
        if lister is None:
            continue
        try:
            ports = lister()
        except Exception as exc:  # noqa: BLE001
            click.echo(f"{scheme}://  listing failed: {exc}")
            continue
        for p in ports:
            mark = "" if p.usable else f"  [cannot open: {p.problem}]"
            click.echo(f"{p.url:27s} {p.description}{mark}")


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
    for scheme, mod, problem in _transport_modules():
        if mod is None:
            click.echo(f"{scheme}://")
            line(scheme, False, f"transport not available: {problem}")
            continue
        checker = getattr(mod, "doctor", None)
        if checker is None:
            continue
        click.echo(f"{scheme}://")
        try:
            checks = checker()
        except Exception as exc:  # noqa: BLE001
            line(scheme, False, f"doctor failed: {exc}")
            continue
        for c in checks:
            line(c.name, c.ok, c.message)
    if s.port_given:
        click.echo(f"port {s.port}")
        try:
            chip = s.open(prepare=False)
            line("open", True, chip.transport.describe())
            t0 = time.perf_counter()
            n = 20
            for _ in range(n):
                st = chip.read_status()
            dt = (time.perf_counter() - t0) / n
            line("status read", True, f"{int(st):02X} ({_flags(st)}), {dt * 1e3:.3f} ms per "
                                      "round trip (wall clock)")
        except LM629Error as exc:
            line("open", False, str(exc))
    click.echo("no problems found" if not problems else f"{problems} problem(s) above")


main.add_command(calc)
main.add_command(_tune)  # lm629 tune (lm629_host/cli_tune.py)

try:  # the serial-bridge groups: `lm629 bridge list|flash`, `lm629 sim serve`
    from .cli_bridge import bridge as _bridge
    from .cli_bridge import sim as _sim
    main.add_command(_bridge)
    main.add_command(_sim)
except ImportError:  # pragma: no cover - before the bridge work landed
    pass


__all__ = ["main", "EXIT_CODES", "Session", "parse_int", "snapshot_dict"]
