"""The ``lm629`` group: global options, the session (the port, opened once), exit codes and
error messages.  The commands are in the family modules beside this one.

``lm629``: the bench command line, from first power-on to a tuned move.

Each command opens the port (``--port``, else ``$LM629_PORT``, else the simulator), does one
job through :class:`lm629_host.LM629` and closes it.  Every number is checked before anything
moves (:mod:`lm629_host.cli.types`).  Moves go through :meth:`LM629.move_to`: done means the
shaft rests on the target, anything else is a motion fault (exit 9).  Commands that start a
move run inside :func:`lm629_host.chip.safety.stop_on_error`: Ctrl-C, SIGTERM, SIGHUP (all
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
import importlib.util
import logging
import os
import signal
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NoReturn

import click

import lm629_host

from lm629_host.errors import (
    AxisError,
    BusyTimeout,
    CommandError,
    LM629Error,
    MotionError,
    ResetError,
    TransportError,
    WaitTimeout,
)
from lm629_host.physics.pid import sample_period_s
from lm629_host.transports.ports import PortSpec, resolve_port
from lm629_host.chip.safety import STOP_NOTE, StopSignals
from lm629_host.urls import PortURL, parse_hz, port_url
from lm629_host.cli.families import COMMAND_FAMILIES, LazyGroup

if TYPE_CHECKING:
    # the driver is imported when a command opens a chip (Session.open, Session.board), the
    # profile's code when --profile is given: every ``lm629`` start imports this module
    from lm629_host.bus.program import BusCycle
    from lm629_host.chip.lm629 import LM629
    from lm629_host.motion.board import Board
    from lm629_host.physics.units import Scale

log = logging.getLogger("lm629_host.cli")

#: exit code -> meaning (one place: the handler and ``--help`` both read it; one meaning per
#: code: tests/cli/test_cli_inputs.py holds every code a command gives to its row)
EXIT_CODES: dict[int, str] = {
    0: "success",
    1: "a check found a problem (bringup verdict, doctor, selftest DIFFERS, twin check, tune "
       "goal not met)",
    2: "bad usage or bad value (nothing was sent that moves the motor)",
    3: "transport error (port missing, busy, no permission, no answer)",
    4: "busy timeout (the chip held its busy bit)",
    5: "reset failure (the chip did not come out of reset)",
    6: "command error (the chip rejected a command)",
    7: "wait timeout (a flag or the index did not come in time)",
    8: "other driver error",
    9: "motion fault: the shaft did not end where it was sent (stall, runaway, position "
       "error, following error, motor off, move timeout); the motor was stopped",
    10: "selftest FAIL: the selftest could not finish (its report says why)",
    129: "hang-up (SIGHUP); a moving motor was stopped first",
    130: "interrupted (Ctrl-C), or a prompt before the motor turns answered no or aborted; "
         "a moving motor was stopped first",
    141: "output closed (broken pipe): output was lost; a moving motor was stopped first",
    143: "terminated (SIGTERM); a moving motor was stopped first",
}

#: a prompt before the motor turns answered no (or aborted): nothing moved
EXIT_DECLINED = 130

_ERROR_EXITS: tuple[tuple[type[BaseException], int], ...] = (
    (ValueError, 2), (TransportError, 3), (BusyTimeout, 4), (ResetError, 5),
    (CommandError, 6), (WaitTimeout, 7), (MotionError, 9), (LM629Error, 8),
)

#: what ended a command, by the stop signal (safety.STOP_SIGNALS): the motor is stopped, then
#: exit 128 + N
_STOP_SIGNALS = {signal.SIGINT: "interrupted (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)",
                 signal.SIGHUP: "hang-up (SIGHUP)"}



def _open(url: str | PortURL, chip: str, trace: Callable[[BusCycle], None] | None) -> LM629:
    """Open the chip (one seam, so that tests can watch what the CLI opened)."""
    return lm629_host.open(url, chip=chip, trace=trace)


def _check_clock(hz: float, where: str) -> float:
    if not 1e6 <= hz <= 8e6:
        raise click.BadParameter(f"{hz:g} Hz is outside the chip's 1-8 MHz", param_hint=where)
    return hz


@dataclass
class Session:
    """The global options and the chip they open (lazily: ``calc`` never opens a port)."""

    port: PortURL  #: the port, parsed once: ``str()`` is what the user (or profile) wrote
    port_given: bool
    chip_name: str
    clock_hz: float
    lines: int | None
    verbose: int
    trace: bool
    stats: bool
    spec: PortSpec  #: the port, settled (lm629_host.transports.ports.resolve_port)
    _chip: LM629 | None = None
    axis_spec: tuple[int, ...] | str | None = None  #: --axis (see cli.axes)
    _board: Any = None
    #: on an in-process simulator, reset each chip and load kp = 20 when it opens (a fresh
    #: simulated chip is useless otherwise); bring-up, which does it itself, sets False
    prepare: bool = True
    #: apply the profile to a chip that lost its settings once the board opens (the profile
    #: commands, which send it themselves, set False)
    reapply: bool = True
    #: Ctrl-C, SIGTERM and SIGHUP, held during the opened chip's bus programs
    signals: StopSignals = field(default_factory=StopSignals)
    profile: Any = None  #: the bench profile (--profile), see cli.profile
    #: --lines (or its environment variable) was given: a profile axis's ``lines`` never
    #: replaces it (:meth:`select_axis`)
    lines_given: bool = False

    @property
    def is_sim(self) -> bool:
        return self.spec.simulated

    @property
    def scale(self) -> Scale | None:
        if not self.lines:
            return None
        from lm629_host.physics.units import Scale  # here: only --lines speaks in units
        return Scale(self.lines, self.clock_hz)

    @property
    def sample_s(self) -> float:
        return sample_period_s(self.clock_hz)

    def url(self) -> PortURL:
        """The port URL; a simulator URL gets the global --chip/--clock/--lines unless it
        names them itself, so that the simulated chip matches the options (the conflict
        rule is :func:`~lm629_host.transports.ports.resolve_port`'s, applied in :func:`main`), and
        ``clock=8MHz`` is written in Hz."""
        if not self.is_sim:
            return self.port
        have = self.port.query()
        add = {"chip": self.chip_name, "clock": str(int(self.clock_hz))}
        if self.lines:
            add["lines"] = str(self.lines)
        values = {k: v for k, v in add.items() if k not in have}
        if "clock" in have:
            values["clock"] = str(int(self.clock_hz))
        return self.port.with_options(values)

    def install_signals(self) -> None:
        """Ctrl-C, SIGTERM and SIGHUP end a command the same way: raised as
        KeyboardInterrupt (Terminated for the last two) so that a moving motor is stopped,
        then the exit code says which.  A signal during a bus program is held until the
        program has finished (:class:`~lm629_host.chip.safety.StopSignals`), so that the safety
        stop starts on a clean bus."""
        self.signals.install()

    def _guard_programs(self, chip: LM629) -> None:
        """Hold a stop signal while a bus program of ``chip`` runs."""
        self.signals.guard(chip.transport)

    def cycle_trace(self) -> Callable[[BusCycle], None] | None:
        """What ``--trace`` subscribes to the transport's bus cycles: None without it, so that
        a simulator keeps its fast path (no cycle is made for nobody to see)."""
        return self._trace if self.trace else None

    @staticmethod
    def _trace(cycle: BusCycle) -> None:
        click.echo(f"bus {cycle}", err=True)

    def open(self, *, prepare: bool = True) -> LM629:
        """The chip.  On an in-process simulator: reset it and load kp = 20 (``prepare``)."""
        from lm629_host.chip.move import MoveRules  # the driver's, loaded with the chip
        if self._chip is None and (self.axis_spec is not None or self.spec.axes is not None):
            self._chip = self._open_axis(prepare)
            return self._chip
        if self._chip is None:
            if not self.port_given:
                click.echo("lm629: no --port or LM629_PORT: using the simulator sim:// (a fresh "
                           "simulated chip for this command only; for one that keeps its state "
                           "run `lm629 sim serve --pty /tmp/lm629` and pass --port /tmp/lm629)",
                           err=True)
            self._chip = _open(self.url(), self.chip_name, self.cycle_trace())
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

    def board(self) -> Board:
        """The board behind the port, with at least the axes named (opened once; on a
        simulator every axis is reset and given kp = 20, as a single simulated chip is)."""
        from lm629_host.chip.move import MoveRules  # the driver's, loaded with the board
        if self._board is None:
            spec = self.axis_spec
            want = max(spec) + 1 if isinstance(spec, tuple) else None
            url = self.url()
            chips = want or 1
            if self.profile is not None and self.profile.axes:  # the bench the profile describes
                chips = max(chips, 1 + max(ax.cs for ax in self.profile.axes.values()))
            if self.is_sim and self.spec.axes is None and chips > 1:
                # a simulator builds the chips named, unless its URL says how many it has
                url = url.with_options({"axes": str(chips)})
            b = lm629_host.open_board(url, chip=self.chip_name, trace=self.cycle_trace())
            if want is not None and len(b.axes) < want:
                b.close()
                raise AxisError(want - 1, len(b.axes), str(self.port))
            self._guard_programs(b.axes[0])
            for a in b.axes:
                a.move_rules = MoveRules(clock_hz=self.clock_hz)
            if self.is_sim and self.prepare:
                b.reset()
                for a in b.axes:
                    a.load_filter(kp=20)
                    a.update_filter()
                    a.sync()
            self._board = b
            if self.profile is not None:
                from lm629_host.cli.profile_session import profile_opened
                profile_opened(self, b)
        return self._board

    def _open_axis(self, prepare: bool) -> LM629:
        """The one chip a single-axis command drives."""
        axes = axes_of(self) if self.axis_spec is not None else (0,)
        if len(axes) > 1:
            names = ", ".join(axis_name(self, k) for k in axes)
            raise click.UsageError(f"axes {names} are chosen (by --axis, or the profile's "
                                   "axes): this command drives one: give --axis NAME (status, "
                                   "watch, move with several targets, bringup and selftest take "
                                   "several)")
        self.prepare = prepare
        return self.board().axis(axes[0])

    def select_axis(self, cs: int) -> None:
        """Make chip select ``cs`` the axis the single-axis commands drive from now on (the
        board stays open): ``lm629 panel`` runs each command on the axis its form names."""
        self.axis_spec = (cs,)
        if self._board is not None:
            self._chip = None
        if self.profile is not None and not self.lines_given:
            # the axis's encoder lines, as `--profile F --axis NAME` takes them: its
            # revolutions and rpm (an axis without lines speaks counts)
            ax = self.profile.by_cs(cs)
            self.lines = ax.lines if ax is not None else None

    def close(self) -> None:
        if self._board is not None:
            if self.stats:
                click.echo(f"stats: {self._board.transport.stats}", err=True)
            self._board.close()
            self._board = self._chip = None
        if self._chip is not None:
            if self.stats:
                click.echo(f"stats: {self._chip.transport.stats}", err=True)
            self._chip.close()
            self._chip = None
        self.signals.restore()


# ---------------------------------------------------------------------- the session's axes
#: more than the largest board (the bridge: 4 chip selects); checked again when it opens
MAX_AXIS = 15


def parse_axes(text: str) -> tuple[int, ...] | str:
    """``"1"`` -> (1,), ``"0,1"`` -> (0, 1), ``"all"`` -> "all" (click.BadParameter else)."""
    text = text.strip().lower()
    if text == "all":
        return "all"
    try:
        axes = tuple(int(t) for t in text.split(",") if t.strip() != "")
    except ValueError:
        raise click.BadParameter(f"{text!r}: an axis number, a list (0,1) or 'all'",
                                 param_hint="--axis") from None
    if not axes or any(not 0 <= a <= MAX_AXIS for a in axes) or len(set(axes)) != len(axes):
        raise click.BadParameter(f"{text!r}: axis numbers 0..{MAX_AXIS}, each once",
                                 param_hint="--axis")
    return axes


def axes_of(s: Session) -> tuple[int, ...]:
    """The axes this command works on (``all``: every chip select of the board, opened)."""
    spec = s.axis_spec
    if spec is None:
        n = s.spec.axes
        return tuple(range(n)) if n else (0,)
    if spec == "all":
        return tuple(range(len(board(s).axes)))
    assert isinstance(spec, tuple)  # parse_axes: a tuple of axes, or "all"
    return spec


def axis_name(s: Session, cs: int) -> str:
    """How output names the axis on chip select ``cs``: the profile's name, else the number."""
    ax = s.profile.by_cs(cs) if s.profile is not None else None
    return ax.name if ax is not None else str(cs)


def several(s: Session) -> bool:
    return len(axes_of(s)) > 1


def board(s: Session) -> Board:
    """The board behind the port (:meth:`Session.board`)."""
    return s.board()


def _help_epilog() -> str:
    codes = "\n".join(f"  {k:>3}  {v}" for k, v in EXIT_CODES.items())
    return ("\b\nExit codes:\n" + codes + "\n\n\bWith neither --port nor LM629_PORT the bundled "
            "simulator is used (a fresh chip per command).\nStart with:  lm629 bringup --yes")


#: bare ``lm629``: click shows the help (click 8.2 raises this for it; older clicks print it)
_NO_ARGS: tuple[type[Exception], ...] = tuple(
    c for c in (getattr(click.exceptions, "NoArgsIsHelpError", None),) if c is not None)


class LM629Group(LazyGroup):
    """A click group that turns exceptions into one stderr line and an exit code (its commands
    load lazily: :class:`~lm629_host.cli.families.LazyGroup`)."""

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """Each command's first sentence whole (click cuts it at 45 characters with "..."):
        the formatter wraps it instead."""
        rows = []
        for name in self.list_commands(ctx):
            cmd = self.get_command(ctx, name)
            if cmd is not None and not cmd.hidden:
                rows.append((name, cmd.get_short_help_str(limit=1000)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        """The group's own options (``lm629 --prot sim:// status``): a mistake there is the
        same one line and exit 2 as a command's, click's suggestion kept."""
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as exc:
            if ctx.resilient_parsing or isinstance(exc, _NO_ARGS):  # completion; bare `lm629`
                raise
            _fail(ctx, f"{exc.format_message()} (see `{ctx.command_path} --help`)", exc, 2)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            result = super().invoke(ctx)
            sys.stdout.flush()  # a closed pipe shows here, not in Python's flush at exit
            return result
        except click.ClickException as exc:  # bad usage or value; a command's own refusal
            message, code = error_line(exc)
            _fail(ctx, message, exc, code)
        except (click.exceptions.Exit, click.exceptions.Abort):
            raise
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            _fail(ctx, _STOP_SIGNALS.get(signum, f"signal {signum}"), exc, 128 + signum)
        except BrokenPipeError as exc:
            # stdout closed early (`lm629 move 0 | head -c 10`): output was lost, so not a
            # success: 141 (128 + SIGPIPE) as a Unix tool ended by the signal. Keep Python from
            # complaining again when it flushes stdout at exit
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            if getattr(exc, STOP_NOTE, None) is not None:  # it ended a move: the motor stopped
                _fail(ctx, "output closed (broken pipe) during a move", exc, 141)
            # after a move or in a command that moves nothing: the motor is as the command
            # left it (holding at the target); silent, as a tool ended by SIGPIPE
            ctx.exit(141)
        except Exception as exc:  # noqa: BLE001 - mapped to exit codes by error_line
            message, code = error_line(exc)
            _fail(ctx, message, exc, code,
                  always_tb=not any(isinstance(exc, cls) for cls, _c in _ERROR_EXITS))


def error_line(exc: Exception) -> tuple[str, int]:
    """The one line (without ``lm629: `` and the stop note) and the exit code a command's
    exception ends it with: the one rule, shared by the command line and ``lm629 panel``."""
    if isinstance(exc, click.UsageError):  # bad usage or value: exit 2
        sub = exc.ctx.command_path if exc.ctx is not None else "lm629"
        return f"{exc.format_message()} (see `{sub} --help`)", 2
    if isinstance(exc, click.ClickException):  # a command's own refusal: the same one line
        return exc.format_message(), exc.exit_code
    code = next((c for cls, c in _ERROR_EXITS if isinstance(exc, cls)), None)
    if code is None:
        return f"internal error ({type(exc).__name__}): {exc}", 8
    kind = "bad value" if isinstance(exc, ValueError) else "error"
    return f"{kind}: {exc}", code


def stop_note_of(exc: BaseException, message: str) -> str:
    """``message`` with how the motor was left, when the exception stopped one."""
    note = getattr(exc, STOP_NOTE, None)
    return message + (f" -- {note}" if note and note not in message else "")


def _fail(ctx: click.Context, message: str, exc: BaseException, code: int,
          always_tb: bool = False) -> NoReturn:
    session = ctx.obj if isinstance(ctx.obj, Session) else None
    if always_tb or (session is not None and session.verbose):
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    try:  # stderr may be closed too (a dropped ssh session): the exit code still tells
        click.echo(f"lm629: {stop_note_of(exc, message)}", err=True)
    except (OSError, ValueError):
        pass
    ctx.exit(code)


@click.group(cls=LM629Group, epilog=_help_epilog(), lazy_commands=COMMAND_FAMILIES,
             context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--port", "-p", envvar="LM629_PORT", default=None, metavar="URL",
              help="sim://, serial://PATH or a device path, socket://HOST:PORT (ser2net, "
                   "`lm629 sim serve --tcp`), ftdi://..., sim+emu://, sim+avr://, sim+ftdi:// "
                   "(env LM629_PORT; default sim://).")
@click.option("--place", "place", default=None, metavar="NAME",
              help="A labgrid place instead of --port: acquired (locked) from the coordinator "
                   "(LG_COORDINATOR), its serial port opened as rfc2217://, released at exit; "
                   "NAME?fast_baud=... adds port URL options (docs/testing.md).")
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
@click.option("--vcd", "vcd_path", default=None, metavar="FILE",
              help="Write a simulated port's bus pins to FILE (VCD, for PulseView and the "
                   "lm629 sigrok decoder; the URL's vcd=).")
@click.option("--stats", is_flag=True, help="Print the transport's counters at exit.")
@click.option("--axis", "axis_text", default=None, metavar="N|N,M|all",
              help="Which chip on a multi-axis board (its chip select; default 0, or every "
                   "chip of the URL's axes=); a list or 'all' for status, watch, move with one "
                   "target per axis, bringup.")
@click.option("--profile", "profile_path", envvar="LM629_PROFILE", default=None,
              metavar="FILE", help="A bench profile (TOML, env LM629_PROFILE): the port, chip, "
                                   "clock, units and named axes (--axis x) of every command, "
                                   "soft limits, gains re-applied after a power cycle.")
@click.version_option(lm629_host.__version__, prog_name="lm629")
@click.pass_context
def main(ctx: click.Context, port: str | PortURL | None, place: str | None, chip_name: str, clock: str,
         lines: int | None, verbose: int, trace: bool, stats: bool, vcd_path: str | None, axis_text: str | None,
         profile_path: str | None) -> None:
    """Bench bring-up and tuning of an LM628/LM629 motion controller."""
    profile = None
    signals = StopSignals()
    if place is not None and ctx.get_parameter_source("port") == click.core.ParameterSource.COMMANDLINE:
        raise click.BadParameter("--port and --place both name a bench: give one",
                                 param_hint="--place")
    lines_given = lines is not None
    if profile_path is not None:
        from lm629_host.cli.profile_session import profile_options
        profile, port, chip_name, clock, lines, axis_text = profile_options(
            ctx, profile_path, port, chip_name, clock, lines, axis_text)
    if place is not None:  # the lab's bench (not a profile's port): locked until the context closes
        from lm629_host.cli.place import open_place
        port = open_place(ctx, place, signals)
    try:
        clock_hz = _check_clock(parse_hz(clock), "--clock")
    except ValueError:
        raise click.BadParameter(f"{clock!r} is not a frequency (8MHz, 6e6)",
                                 param_hint="--clock") from None
    if lines is not None and lines < 1:
        raise click.BadParameter(f"{lines} must be at least 1", param_hint="--lines")
    if port is not None and not str(port).strip():
        raise click.BadParameter("is empty (an unset variable in `--port \"$BOARD\"`?); "
                                 "leave --port out to use the simulator", param_hint="--port")
    try:  # the one parse of the port's text (a profile's port came parsed)
        url = port_url(port or lm629_host.DEFAULT_URL)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--port") from None
    # the rule (lm629_host.transports.ports): a URL's chip= / clock= describe the chip; --chip and --clock
    # given on the command line must agree with them, and when not given, the URL's are used
    given = {name: ctx.get_parameter_source(name) not in (
        click.core.ParameterSource.DEFAULT, None) for name in ("chip_name", "clock")}
    try:
        spec = resolve_port(url, chip=chip_name if given["chip_name"] else None,
                            clock=clock_hz if given["clock"] else None)
    except ValueError as exc:  # ArgumentError, SchemeError: bad usage
        hint = {"chip": "--chip", "clock": "--clock"}.get(getattr(exc, "argument", ""))
        if hint is None or not given["chip_name" if hint == "--chip" else "clock"]:
            hint = "--port"
        raise click.BadParameter(str(exc), param_hint=hint) from None
    chip_name = spec.chip
    clock_hz = spec.clock_hz or clock_hz
    if vcd_path is not None:
        if not spec.simulated:
            raise click.BadParameter(f"{url} is hardware: --vcd writes a simulator's bus; "
                                     "capture a bench with a logic analyzer (docs/debugging.md)",
                                     param_hint="--vcd")
        url = url.with_options({"vcd": vcd_path})
    if "vcd" in url.query() and importlib.util.find_spec("vcd") is None:
        # checked here, before the port opens: the simulator would find it missing only once
        # it builds the chip, as a traceback
        raise click.BadParameter("writing a VCD needs pyvcd, an optional extra: pip install "
                                 "'lm629-host[vcd]'", param_hint="--vcd" if vcd_path else "--port")
    _log_to_stderr({0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG))
    session = Session(url, port is not None, chip_name, clock_hz,
                      lines, verbose, trace, stats, spec, signals=signals)
    if axis_text is not None:
        session.axis_spec = parse_axes(axis_text)
    session.profile = profile
    session.lines_given = lines_given
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
    """The package's log lines on stderr at ``level``: prefixed ``lm629:`` as every other line
    the command prints (a notice is the command's, whichever module logged it), with the
    logger's name from ``-v`` on (where it helps to find the code)."""
    logger = logging.getLogger("lm629_host")
    handler = next((h for h in logger.handlers if isinstance(h, _ClickHandler)), None)
    if handler is None:
        handler = _ClickHandler()
        logger.addHandler(handler)
    handler.setFormatter(logging.Formatter("lm629: %(message)s" if level >= logging.WARNING
                                           else "%(name)s: %(message)s"))
    logger.setLevel(level)


def _session() -> Session:
    session = click.get_current_context().find_object(Session)
    assert session is not None, "main() sets the Session before any command runs"
    return session


# ---------------------------------------------------------------------------------- rendering
