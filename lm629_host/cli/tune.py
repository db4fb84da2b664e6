"""``lm629 tune``: PID gains for the axis on the bench, in one command.

A thin front end to :func:`lm629_host.bench.tuning.autotune`: it asks before the motor turns
(unless ``--yes``), prints progress, the gains, the ``lm629 filter`` line that sets them, and
the test move measured before (with ``--before`` gains) and after; ``--plot`` draws both.
Registered with ``@main.command()`` as every command is; the CLI's error handler
gives the exit code and prints how the motor was left (``autotune`` stops it on any fault).
"""

from __future__ import annotations

import os

import click

from lm629_host.bench.capture import PlotUnavailable, capture_move, summary, write_csv
from lm629_host.chip.safety import stop_on_error
from lm629_host.bench.tuning import TuneResult, autotune
from lm629_host.cli.app import EXIT_DECLINED, _session, axis_name, main
from lm629_host.cli.common import _position, check_filter_options
from lm629_host.cli.motion import _motion_words, _tolerance
from lm629_host.physics.axis import Gains
from lm629_host.physics.design import integral_note
from lm629_host.cli.types import FINITE, INT, SIGNED_ARGS, check_writable, parse_int, positive

#: exit code when tuning ran but the test move did not end within the tolerance
EXIT_NOT_MET = 1



def parse_gains(text: str) -> Gains | None:
    """``kp=20,kd=300,ki=0,il=0,ds=1`` (ds: the derivative interval in samples, as in
    ``lm629 filter --ds``) -> :class:`Gains`; ``none`` -> None."""
    if text.strip().lower() in ("none", "no", ""):
        return None
    values = {"kp": 0, "ki": 0, "kd": 0, "il": 0, "ds": 1}
    for part in text.replace(" ", "").split(","):
        name, sep, value = part.partition("=")
        if not sep or name not in values:
            raise ValueError(f"--before {text!r}: expected name=value pairs of kp, ki, kd, il, "
                             "ds separated by commas, or 'none'")
        values[name] = parse_int(value)
    if not 1 <= values["ds"] <= 256:
        raise ValueError(f"--before ds={values['ds']} must be 1..256 samples")
    g = Gains(values["kp"], values["ki"], values["kd"], values["il"], values["ds"])
    for name in ("kp", "ki", "kd", "il"):
        if not 0 <= getattr(g, name) <= 0x7FFF:
            raise ValueError(f"--before {name}={getattr(g, name)} is outside 0..32767")
    return g


def _plot(result: TuneResult, path: str, lines: int | None) -> str:
    from lm629_host.bench.plot import Response, plot_responses
    responses, texts = [], []
    for name, label in (("before", "before"), ("after", "tuned")):
        rec = result.record(name)
        if rec is None or not rec.steps:
            continue
        _t, _real, _des, start, target = rec.segment(0)
        t_k = rec.steps[0][0]
        rows = [s for s in rec.rows if s.time <= (rec.steps[1][0] if len(rec.steps) > 1
                                                   else float("inf"))]
        responses.append(Response(label, [s.time - t_k for s in rows], rows, start, target,
                                  rec.gains, result.model.twelve_bit))
        texts.append(str(rec.gains))
    title = (f"lm629 tune: {result.distance:+d}-count step; tuned {result.gains}"
             + (f"; before {texts[0]}" if len(texts) > 1 else ""))
    return str(plot_responses(path, responses, title=title, lines=lines,
                              tolerance=result.tolerance, gain_texts=texts))


@main.command("tune")
@click.option("--travel", "travel_typed", type=FINITE, required=True, metavar="DISTANCE",
              help="How far the shaft may go either way from where it is now (counts; "
                   "revolutions with --lines); tuning stays inside this band.")
@click.option("--distance", "distance_typed", type=FINITE, default=None, metavar="DISTANCE",
              help="The test move, a step out and back (counts; revolutions with --lines; "
                   "default: 2000 counts or travel/2).")
@click.option("--tolerance", "tolerance_typed", type=FINITE, default=None,
              help="The test moves must end within this of their targets (counts; "
                   "revolutions with --lines; default 2 counts).")
@click.option("--before", "before_text", default="kp=20", show_default=True, metavar="GAINS",
              help="Gains to measure the test move with first, for comparison "
                   "('kp=40,kd=300', ds in samples), or 'none'.")
@click.option("--interval", type=float, default=0.001, show_default=True,
              help="Seconds between snapshots (timed by the bridge where it records; "
                   "host-polled elsewhere, at least one round trip).")
@click.option("--velocity", "--vel", "velocity", type=FINITE, default=None,
              help="The trapezoid move the gains are judged and checked on besides the step "
                   "(--distance out and back): its velocity, a raw word (rpm with --lines); "
                   "default 0x40000 where the axis can follow it.")
@click.option("--acceleration", "--acc", "--accel", "acceleration", type=FINITE, default=None,
              help="... and its acceleration, a raw word (rev/s^2 with --lines); default "
                   "0x2000 where the axis can follow it.")
@click.option("--yes", "-y", is_flag=True, help="Do not ask before the motor turns (scripts).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="PNG of the test move before and after.")
@click.option("--save", "save_path", is_flag=False, flag_value="", default=None,
              metavar="[FILE]", help="Write the gains into the profile (FILE, else --profile's), "
                                     "keeping its comments.")
def tune(travel_typed: float, distance_typed: float | None, tolerance_typed: float | None,
         before_text: str, interval: float, velocity: float | None,
         acceleration: float | None, yes: bool, plot_path: str | None,
         save_path: str | None) -> None:
    """Find PID gains for this axis (phasing check, identification, design, a checked test
    move), leave them loaded and applied, and print the `lm629 filter` line that sets them."""
    from lm629_host.cli.app import _session  # the CLI's session: port, options, safety
    s = _session()
    travel = _position(s, travel_typed, "--travel")  # counts, as every distance below
    if travel < 100:
        raise ValueError(f"--travel={travel_typed:g} is {travel} counts: it must be at least "
                         "100 counts")
    distance = None if distance_typed is None else _position(s, distance_typed, "--distance")
    if distance is not None and not 10 <= distance <= travel * 3 // 4:
        raise ValueError(f"--distance={distance_typed:g} is {distance} counts: it must be "
                         f"10..{travel * 3 // 4} counts (3/4 of --travel)")
    tol = _tolerance(s, tolerance_typed, raw=False)
    tolerance = 2 if tol is None else tol
    if not 0 < interval <= 0.05:
        raise ValueError(f"--interval={interval} must be > 0 and at most 0.05 seconds")
    before = parse_gains(before_text)
    # the move's words, validated before anything is opened (None: the tuner's default)
    words = _motion_words(s, velocity, acceleration, raw=False)
    v_word = None if velocity is None else words[0]
    a_word = None if acceleration is None else words[1]
    chip = s.open()
    from lm629_host.cli import profile
    save_to = profile.save_target(s, chip, save_path)
    profile.tune_band(chip, travel)
    on = (f"axis {axis_name(s, chip.chip_select)} (cs {chip.chip_select}), "
          if s.profile is not None else "")
    click.echo(f"tuning {on}{chip.variant.upper()} on {chip.transport.describe()}, inside "
               f"+/-{travel} counts of where the shaft is")
    if not yes and not click.confirm(f"The motor will turn, up to {travel} counts either way "
                                     "from here. Is the axis free to move that far?",
                                     default=False):
        click.echo("nothing moved")
        click.get_current_context().exit(EXIT_DECLINED)
    with profile.tuning(s, chip), stop_on_error(chip):
        result = autotune(chip, travel=travel, distance=distance, tolerance=tolerance,
                          before=before, poll_s=interval, clock_hz=s.clock_hz,
                          velocity=v_word, acceleration=a_word,
                          progress=lambda text: click.echo(f"  {text}", err=True))
    from lm629_host.bench.twin import plant_record
    plant = plant_record(result.model, result.sample_s, rms=result.fit_rms,
                         steps=result.fit_steps, port=str(s.port))
    scale = s.scale
    click.echo(f"axis: {result.model.describe(result.sample_s)}")
    d = f"{result.distance:+d}-count step out and back"
    if result.before is not None:
        click.echo(f"before ({before}): {result.before.line()}")
    click.echo(f"tuned, predicted:  {result.predicted.line()}")
    click.echo(f"tuned, measured:   {result.measured.line()}  [{d}]")
    if result.measured_move is not None and result.predicted_move is not None:
        m = (f"{result.distance:+d}-count move out and back, {result.profile}; settle after "
             "the profile's end")
        click.echo(f"move, predicted:   {result.predicted_move.line()}")
        click.echo(f"move, measured:    {result.measured_move.line()}  [{m}]")
    click.echo(f"gains: {result.gains} (loaded and applied: LFIL + UDF)")
    click.echo(integral_note(result.model, result.gains, result.sample_s))
    named = axis_name(s, chip.chip_select) if s.profile is not None else None
    click.echo(f"set them again with:  {result.gains.cli(named)}")
    if scale is not None:
        click.echo(f"({scale.counts_per_rev} counts/rev: travel "
                   f"{travel / scale.counts_per_rev:.3f} rev)")
    # last, where it is seen: whether the profile now holds these gains
    profile.after_tune(s, chip, result.gains, save_to, result.ok, plant)
    if plot_path:
        try:
            click.echo(f"wrote {_plot(result, plot_path, s.lines)}")
        except PlotUnavailable as exc:
            click.echo(f"lm629: {exc}", err=True)
    if not result.ok:
        worst = max((m for m in (result.measured, result.measured_move) if m is not None),
                    key=lambda m: abs(m.final_error))
        click.echo(f"lm629: a test move ended {worst.final_error:+d} counts from "
                   f"target (tolerance {tolerance}): the gains are loaded, but check the axis "
                   "(backlash, a load that changes with position) and run tune again", err=True)
        click.get_current_context().exit(EXIT_NOT_MET)


__all__ = ["tune", "parse_gains"]


@main.command(context_settings=SIGNED_ARGS)
@click.argument("distance", type=FINITE, default=200)
@click.option("--kp", type=INT, help="Proportional gain to load first (0..32767; default: "
                                      "the chip's as it is).")
@click.option("--ki", type=INT, help="Integral gain to load first (0..32767).")
@click.option("--kd", type=INT, help="Derivative gain to load first (0..32767).")
@click.option("--il", type=INT, help="Integration limit to load first (0..32767).")
@click.option("--ds", type=int, help="Derivative sampling interval, samples.")
@click.option("--velocity", "--vel", "vel", type=FINITE, default=None,
              help="Velocity: rpm with --lines, else a raw word (default: a step).")
@click.option("--acceleration", "--acc", "--accel", "acc", type=FINITE, default=None,
              help="Acceleration: rev/s^2 with --lines, else a raw word (default: a step).")
@click.option("--raw", is_flag=True, help="Counts and raw words even with --lines.")
@click.option("--tolerance", type=FINITE, default=None,
              help="Done when the shaft rests this close to the target (counts; revolutions "
                   "with --lines).")
@click.option("--time", "duration", type=FINITE, default=0.5, show_default=True,
              help="Seconds to record.")
@click.option("--interval", type=FINITE, default=0.001, show_default=True,
              help="Seconds between snapshots (timed by the bridge where it records; "
                   "host-polled elsewhere, at least one round trip).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default="step.csv",
              show_default=True, help="Where to write the recorded rows (CSV).")
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
    from lm629_host.physics.pid import STEP_ACCELERATION, STEP_VELOCITY
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
    from lm629_host.bench.plot import plot_capture
    filt = {k: v for k, v in dict(kp=kp, ki=ki, kd=kd, il=il,
                                  derivative_interval=ds).items() if v is not None}
    chip = s.open()
    check_filter_options(chip, kp, ki, kd, il, ds)  # before anything moves
    from lm629_host.physics.limits import clip_step
    if vel is None and acc is None and chip.limits is not None:  # a step in the caps
        v, a = clip_step(chip, v, a)
        if (v, a) != (STEP_VELOCITY, STEP_ACCELERATION):
            click.echo(f"a step brought down to the soft caps: velocity word {v}, acceleration "
                       f"word {a} ({chip.limits.where})")
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


