"""Commands that move the motor: ``move``, ``velocity``, ``stop``, ``home``.  Each runs inside
:func:`lm629_host.chip.safety.stop_on_error`: any way it ends stops the motor first."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import click

from lm629_host.errors import MotionError, MotionFault
from lm629_host.chip.lm629 import LM629
from lm629_host.bus.snapshot import Snapshot
from lm629_host.chip.move import LONG_MOVE_HINT, Move, MoveRules, MoveTooLong, span
from lm629_host.bus.opcodes import ACCELERATION_MAX, FIXED_ONE, VELOCITY_MAX, Status
from lm629_host.physics.pid import sample_period_s
from lm629_host.chip.safety import stop_on_error
from lm629_host.chip.supervise import run_velocity
from lm629_host.cli.app import Session, _session, main
from lm629_host.cli.common import _isatty, _live, _position, _progress_line, _show_position
from lm629_host.cli.types import FINITE, SIGNED_ARGS, positive

if TYPE_CHECKING:
    from lm629_host.chip.shapes import SCurve


def _motion_words(s: Session, velocity: float | None, acceleration: float | None,
                  raw: bool) -> tuple[int, int]:
    """(velocity, acceleration) raw words from the options: rpm and rev/s^2 with --lines."""
    scale = None if raw else s.scale
    if scale is None:
        v = FIXED_ONE if velocity is None else velocity  # 1 count/sample
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


def _s_curve(s: Session, shape: str, jerk: float | None, velocity: int, acceleration: int,
             raw: bool) -> SCurve | None:
    """The S-curve of ``--shape s-curve`` in counts and seconds (its limits the --vel and
    --acc words, ``--jerk`` in rev/s^3 with --lines, else counts/s^3), or None."""
    if shape != "s-curve":
        if jerk is not None:
            raise click.BadParameter("needs --shape s-curve", param_hint="--jerk")
        return None
    if jerk is None:
        raise click.BadParameter("--shape s-curve needs --jerk", param_hint="--jerk")
    positive("--jerk", jerk)
    from lm629_host.chip.shapes import SCurve  # here: a trapezoid (most moves) needs no shapes
    sample_s = s.scale.sample_period if s.scale is not None else sample_period_s(
        s.open().clock_hz)
    per_count = 1.0 if raw or s.scale is None else s.scale.counts_per_rev
    try:
        return SCurve(velocity / FIXED_ONE / sample_s, acceleration / FIXED_ONE / sample_s ** 2,
                      jerk * per_count)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--jerk") from None


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


def _tolerance(s: Session, tolerance: float | None, raw: bool) -> int | None:
    if tolerance is None:
        return None
    if tolerance < 0:
        raise click.BadParameter(f"{tolerance:g} must be >= 0", param_hint="--tolerance")
    return _position(s, tolerance, "--tolerance", raw)


@main.command(context_settings=SIGNED_ARGS)
@click.argument("targets", type=FINITE, nargs=-1, required=True, metavar="TARGET...")
@click.option("--linear", is_flag=True, help="With one target per --axis: a straight line, "
                                             "the words scaled by each axis's share.")
@click.option("--relative", "-r", is_flag=True, help="TARGET is a distance from where it is.")
@click.option("--velocity", "--vel", "vel", type=FINITE,
              help="Velocity: rpm with --lines (default 60), else raw 16.16 counts/sample "
                   "(default 65536).")
@click.option("--acceleration", "--acc", "--accel", "acc", type=FINITE,
              help="Acceleration: rev/s^2 with --lines (default 10), else raw 16.16 "
                   "counts/sample^2 (default 655).")
@click.option("--raw", is_flag=True, help="Counts and raw words even with --lines.")
@click.option("--tolerance", type=FINITE, default=None,
              help=f"Done when the shaft rests this close to the target (counts; revolutions "
                   f"with --lines; default {MoveRules().tolerance} counts).")
@click.option("--no-wait", is_flag=True, help="Start the move and return (it keeps running).")
@click.option("--timeout", type=FINITE, default=None,
              help="Seconds to wait (default: 1.5 x the profile + 2 s).")
@click.option("--shape", type=click.Choice(["trapezoid", "s-curve"]), default="trapezoid",
              show_default=True, help="s-curve: jerk-limited, in pieces the host times "
                                      "(AN-706 4.5.3); --vel and --acc are its limits.")
@click.option("--jerk", type=FINITE, default=None,
              help="With --shape s-curve: rev/s^3 with --lines, else counts/s^3 (required).")
@click.option("--max-duration", "max_duration", type=FINITE, default=None,
              help=f"Refuse a move whose plan takes longer than this many seconds (default "
                   f"{MoveRules().max_duration:g}, or the profile's max_move_s), before it "
                   "starts.")
def move(targets: tuple[float, ...], linear: bool, relative: bool, vel: float | None,
         acc: float | None, raw: bool, tolerance: float | None, no_wait: bool,
         timeout: float | None, shape: str, jerk: float | None,
         max_duration: float | None) -> None:
    """Move to TARGET (counts; revolutions with --lines; negative as typed: move -5000) and
    wait until the shaft rests on it.  A move that does not end on target is a motion fault:
    the motor is stopped and the exit code is 9.  A move planned longer than --max-duration
    (10 minutes) is refused before it starts (exit 2)."""
    s = _session()
    v, a = _motion_words(s, vel, acc, raw)
    tol = _tolerance(s, tolerance, raw)
    positive("--timeout", timeout)
    positive("--max-duration", max_duration)
    curve = _s_curve(s, shape, jerk, v, a, raw)
    if curve is not None and (len(targets) > 1 or linear or no_wait):
        raise click.UsageError("--shape s-curve moves one axis to one target and waits (the "
                               "host times its pieces): no --linear, --no-wait or more targets")
    from lm629_host.cli import axes
    if s.profile is not None:  # its soft limits (the profile's code loads with a profile)
        from lm629_host.cli import profile
        profile.check_move(s, [_position(s, t, "TARGET", raw) for t in targets], v, a, relative,
                           linear)
    if len(targets) > 1 or linear or axes.several(s):
        if relative:
            raise click.UsageError("--relative moves one axis")
        goals = [_position(s, t, "TARGET", raw) for t in targets]
        axes.check_targets(s, goals)
        if max_duration is not None:
            for ax in axes.board(s).axes:
                ax.move_rules = replace(ax.move_rules, max_duration=max_duration)
        with stop_on_error(axes.board(s).axes[0]):
            axes.move_many(s, goals, v, a, linear, tol, timeout, no_wait)
        return
    target = targets[0]
    counts = _position(s, target, "TARGET", raw)
    chip = s.open()
    # every check before anything moves: the words, the goal, and whether the chip would
    # refuse a new acceleration because the motor is still moving (AN-706 4.6.1)
    chip.trajectory_program(acceleration=a, velocity=v, position=None if relative else counts)
    if relative:
        # the goal in the register's terms (extended positions wrap back into it)
        chip.trajectory_program(position=chip.positions.to_register(
            chip.read_desired_position() + counts))
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    if max_duration is not None:
        chip.move_rules = replace(chip.move_rules, max_duration=max_duration)
    _check_length(s, chip, counts, v, acceleration, relative)
    scale = None if raw else s.scale
    with stop_on_error(chip):
        m: Move
        if curve is not None:
            shaped = chip.move_profile(counts, curve, relative=relative)
            p = shaped.plan
            click.echo(f"moving to {_show_position(s, shaped.target)} along an S-curve: "
                       f"{len(p.pieces)} pieces {p.piece_s * 1e3:g} ms apart, "
                       f"{p.duration:.3f} s planned (top velocity word "
                       f"{p.peak_velocity}, acceleration word {p.acceleration})")
            m = shaped
        else:
            m = chip.move_to(counts, velocity=v, acceleration=acceleration, relative=relative)
            click.echo(f"moving to {_show_position(s, m.target)} (velocity word {v}, "
                       f"acceleration word "
                       f"{a if acceleration is not None else 'as loaded (moving)'})")
        if no_wait:
            return
        with _live(_isatty()) as show:
            shown = [-1.0]

            def progress(snap: Snapshot) -> None:
                if snap.time - shown[0] >= 0.05:  # 20 updates a second of the chip's clock
                    shown[0] = snap.time
                    show(_progress_line(snap, m.target, scale))
            try:
                r = m.wait(timeout=timeout, tolerance=tol, progress=progress)
            except MotionError as exc:
                raise _no_gains(m, exc) or exc from None
    click.echo(f"done: at {_show_position(s, r.position)}, {r.error:+d} counts from the target "
               f"{m.target} (tolerance {tol if tol is not None else chip.move_rules.tolerance}), "
               f"at rest {r.duration:.3f} s after the start")


def _check_length(s: Session, chip: LM629, counts: int, velocity: int,
                  acceleration: int | None, relative: bool) -> None:
    """Refuse, before anything moves, a move planned longer than the chip's
    ``move_rules.max_duration``, in the command line's words (an S-curve takes at least what
    its top speed, the --vel word, takes)."""
    try:
        chip.check_move(counts, velocity=velocity, acceleration=acceleration, relative=relative)
    except MoveTooLong as exc:
        raise click.BadParameter(
            f"{_show_position(s, counts)}{' from here' if relative else ''} is a move of "
            f"{exc.distance} counts, planned to take {exc.seconds:.0f} s ({span(exc.seconds)}), "
            f"longer than --max-duration {exc.limit:g} s; nothing moved.  {LONG_MOVE_HINT[0].upper()}"
            f"{LONG_MOVE_HINT[1:]}; if it is meant, give --max-duration "
            f"{math.ceil(exc.seconds)} (or max_move_s in the profile)",
            param_hint="TARGET") from None


def _no_gains(m: Move, exc: MotionError) -> MotionError | None:
    """The stall of a chip that has no gains, said as that: the motor was off before the move
    (as after a reset or power-up, which leave kp = ki = kd = 0: no register reads the gains
    back) and the shaft never moved a count, so the filter drove nothing.  None otherwise."""
    if exc.reason is not MotionFault.STALL or not m.start.status & Status.MOTOR_OFF \
            or exc.position != m.start.real_position:
        return None
    return MotionError(exc.reason, "no gains loaded: run `lm629 profile apply` or `lm629 filter "
                       "--kp N` (the motor was off before this move, as after a reset or power-up, "
                       "which leave kp = 0, and the shaft never moved a count; if gains are loaded: "
                       f"{exc.detail})", axis=exc.axis, position=exc.position, error=exc.error)


@main.command(context_settings=SIGNED_ARGS)
@click.argument("speed", type=FINITE)
@click.option("--acceleration", "--acc", "--accel", "acc", type=FINITE,
              help="rev/s^2 with --lines, else raw (default 655).")
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
    if s.profile is not None:  # its soft limits (the profile's code loads with a profile)
        from lm629_host.cli import profile
        profile.check_velocity_mode(s, v, a)
    scale = None if raw else s.scale

    def speed_text(word: int) -> str:
        return (f"{scale.rpm(word):.1f} rpm" if scale is not None
                else f"{word / FIXED_ONE:.4f} counts/sample")

    chip = s.open()
    chip.trajectory_program(acceleration=a, velocity=v, velocity_mode=True)
    acceleration = _acceleration_unless_moving(chip, a, acc is not None)
    with stop_on_error(chip):
        run = run_velocity(chip, v, acceleration, forward=not reverse)
        click.echo(f"velocity mode {'backward' if reverse else 'forward'}: {speed_text(v)} "
                   f"(velocity word {v}, acceleration word {a})")
        if run_s is None:
            return
        chip.clock.sleep(run_s)
        snap = chip.snapshot()
        click.echo(f"after {run_s:g} s: actual {speed_text(snap.real_velocity * FIXED_ONE)} "
                   f"(desired {speed_text(snap.desired_velocity)}), position "
                   f"{_show_position(s, snap.real_position)}")
        run.check(snap)  # the shaft turns the way and at the speed asked, or a motion fault
        rest = run.stop(a)
    click.echo(f"smooth stop: at rest at {_show_position(s, rest.real_position)}")


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


