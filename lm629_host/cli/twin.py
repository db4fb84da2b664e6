"""``lm629 identify`` and ``lm629 twin check``: the axis's plant kept in the profile, and the
twin built from it checked against the bench.

Thin front ends to :func:`lm629_host.bench.identify.identify` and :func:`lm629_host.bench.twin.check_twin`
(docs/twin.md); registered with ``@main.command()`` as every command is.  Both ask
before the motor turns (unless ``--yes``); any fault stops the motor (the CLI's error handler
gives the exit code and says how the motor was left).
"""

from __future__ import annotations

from pathlib import Path

import click

from lm629_host.config.profile import AxisProfile, save_gains
from lm629_host.chip.safety import stop_on_error
from lm629_host.bench.identify import identify
from lm629_host.physics.axis import Gains
from lm629_host.bench.twin import Plant, check_twin, plant_record, twin_profile
from lm629_host.urls import query_params, with_query
from lm629_host.cli.app import EXIT_DECLINED, axes_of, main, _session, Session
from lm629_host.cli.motion import _motion_words
from lm629_host.cli.types import FINITE

#: ``twin check``'s exit code when the twin differs from the bench
EXIT_DIFFERS = 1


def _travel(travel: int, interval: float) -> None:
    if travel < 100:
        raise ValueError(f"--travel={travel} must be at least 100 counts")
    if not 0 < interval <= 0.05:
        raise ValueError(f"--interval={interval} must be > 0 and at most 0.05 seconds")


def _confirm(yes: bool, travel: int) -> None:
    if not yes and not click.confirm(f"The motor will turn, up to {travel} counts either way "
                                     "from here. Is the axis free to move that far?",
                                     default=False):
        click.echo("nothing moved")
        click.get_current_context().exit(EXIT_DECLINED)


def _profile_gains(ax: AxisProfile | None) -> Gains | None:
    """The axis's gains in the profile (None where it names no kp)."""
    if ax is None or ax.kp is None:
        return None
    return Gains(ax.kp, ax.ki or 0, ax.kd or 0, ax.il or 0, ax.ds)


@main.command("identify")
@click.option("--travel", type=int, required=True, metavar="COUNTS",
              help="How far the shaft may go either way from where it is now (counts).")
@click.option("--interval", type=float, default=0.001, show_default=True,
              help="Seconds between snapshots (timed by the bridge where it records).")
@click.option("--yes", "-y", is_flag=True, help="Do not ask before the motor turns (scripts).")
@click.option("--save", "save_path", is_flag=False, flag_value="", default=None,
              metavar="[FILE]", help="Write the plant into [axis.NAME.plant] of the profile "
                                     "(FILE, else --profile's), keeping its comments.")
def identify_cmd(travel: int, interval: float, yes: bool, save_path: str | None) -> None:
    """Identify the axis (the tuner's phasing check and P-only steps), print its plant, and
    with --save keep it in the profile; no gains are designed or saved (the profile's are
    loaded again after)."""
    _travel(travel, interval)
    s = _session()
    chip = s.open()
    from lm629_host.cli import profile
    save_to = profile.save_target(s, chip, save_path)
    profile.tune_band(chip, travel)
    ax = s.profile.by_cs(chip.chip_select) if s.profile is not None else None
    restore = _profile_gains(ax)
    click.echo(f"identifying {chip.variant.upper()} on {chip.transport.describe()}, inside "
               f"+/-{travel} counts of where the shaft is")
    _confirm(yes, travel)
    with profile.tuning(s, chip), stop_on_error(chip):
        found = identify(chip, travel=travel, poll_s=interval, clock_hz=s.clock_hz,
                         restore=restore, progress=lambda text: click.echo(f"  {text}", err=True))
    plant = plant_record(found.model, found.sample_s, rms=found.fit_rms,
                         steps=found.fit_steps, port=str(s.port))
    click.echo(f"axis: {found.model.describe(found.sample_s)}")
    click.echo("plant: " + ", ".join(f"{k} = {v}" for k, v in plant.items()
                                      if k not in ("date", "port")))
    click.echo(f"gains: {restore} loaded again (the profile's)" if restore is not None else
               "gains: the filter holds the identification's P-only gain (no profile gains)")
    if save_to is not None:
        path, name = save_to
        save_gains(path, name, {}, plant=plant)
        click.echo(f"saved the plant into [axis.{name}.plant] of {path}")


def twin_url(s: Session, ax: AxisProfile) -> str:
    """The twin of the axis: ``sim://`` built from its profile's plant, alone."""
    assert s.profile is not None
    return with_query("sim://", {"profile": str(s.profile.path), "axis": ax.name})


#: what a simulator URL may name and still build its axes from the profile's plants alone:
#: the profile and its axis, the board (chip, clock, axes, cs), the encoder's lines, and what
#: only records or checks (any other parameter is a motor, a fault or a wiring of its own)
_TWIN_KEEPS = frozenset({"profile", "axis", "chip", "clock", "axes", "cs", "lines", "vcd",
                         "record", "strict"})


def _bench_is_the_twin(s: Session) -> bool:
    """Whether the session's port builds the same simulated axes the twin does (the CLI gives
    a simulator ``profile=`` with ``--profile``): such a check can only say "matches"."""
    if not s.is_sim or s.profile is None:
        return False
    params = query_params(s.url())
    if "profile" not in params or set(params) - _TWIN_KEEPS:
        return False
    return Path(params["profile"]).resolve() == Path(s.profile.path).resolve()


@main.group("twin")
def twin_group() -> None:
    """The twin of the bench built from the profile (sim://?profile=FILE): check it."""


@twin_group.command("check")
@click.option("--travel", type=int, required=True, metavar="COUNTS",
              help="How far the shaft may go either way from where it is now (counts).")
@click.option("--distance", type=int, default=None, metavar="COUNTS",
              help="The step and the move, out and back (default: 2000 or travel/2).")
@click.option("--velocity", "--vel", "velocity", type=FINITE, default=None,
              help="The trapezoid move's velocity, a raw word (rpm with --lines); default "
                   "the tuner's for this plant.")
@click.option("--acceleration", "--acc", "acceleration", type=FINITE, default=None,
              help="... and its acceleration, a raw word (rev/s^2 with --lines).")
@click.option("--time", "duration", type=float, default=0.4, show_default=True,
              help="Seconds recorded after each step (after the profile's end for the move).")
@click.option("--interval", type=float, default=0.001, show_default=True,
              help="Seconds between snapshots (timed by the bridge where it records).")
@click.option("--yes", "-y", is_flag=True, help="Do not ask before the motor turns (scripts).")
def check_cmd(travel: int, distance: int | None, velocity: float | None,
              acceleration: float | None, duration: float, interval: float, yes: bool) -> None:
    """The same short step and trapezoid move with the profile's gains on the bench and on
    its twin, recorded on the far side, side by side: the rms difference of the positions,
    the overshoot, the settle time; "matches" (exit 0) or "differs" (exit 1) against the
    threshold of docs/twin.md."""
    _travel(travel, interval)
    if distance is None:
        distance = min(2000, travel // 2)
    if not 10 <= distance <= travel * 3 // 4:
        raise ValueError(f"--distance={distance} must be 10..{travel * 3 // 4} (3/4 of --travel)")
    if not 0.05 <= duration <= 10:
        raise ValueError(f"--time={duration} must be 0.05..10 seconds")
    s = _session()
    if s.profile is None:
        raise click.UsageError("twin check needs --profile FILE (the plant and the gains)")
    words = _motion_words(s, velocity, acceleration, raw=False)
    cs = axes_of(s)[0] if s.axis_spec != "all" else 0  # the profile checked before the port
    ax = s.profile.by_cs(cs)
    if ax is None:
        raise click.UsageError(f"{s.profile.path} has no [axis.NAME] with cs = {cs}")
    if not ax.plant:
        raise click.UsageError(f"{s.profile.path}: [axis.{ax.name}] has no plant: "
                               "`lm629 identify --save` (or `tune --save`) first")
    gains = _profile_gains(ax)
    if gains is None:
        raise click.UsageError(f"{s.profile.path}: [axis.{ax.name}] has no kp: the check "
                               "runs the profile's gains on both")
    if _bench_is_the_twin(s):
        raise click.UsageError(
            f"the bench {s.port} is the twin itself: a simulator given with --profile builds "
            f"each axis from the profile's plant, so the check would compare the twin with "
            f"itself. Give the bench's port (--port /dev/ttyACM0, or the profile's port = "
            f"...), or a simulated bench of its own (--port 'sim://?inertia=4e-5&load_torque="
            f"0.004': a motor parameter in the URL keeps its own motor)")
    plant = Plant.from_values(ax.plant)
    chip = s.open()
    from lm629_host.cli import profile
    profile.tune_band(chip, travel)
    move = twin_profile(plant, s.sample_s, None if velocity is None else words[0],
                        None if acceleration is None else words[1])
    import lm629_host
    url = twin_url(s, ax)
    click.echo(f"twin check of axis {ax.name}: {chip.transport.describe()} against {url}; "
               f"{distance:+d} counts out and back, a step and a move ({move}), {gains}")
    _confirm(yes, travel)
    with lm629_host.open(url) as twin:
        twin.reset()
        with profile.tuning(s, chip), stop_on_error(chip):
            result = check_twin(chip, twin, gains, travel=travel, distance=distance,
                                profile=move, duration_s=duration, poll_s=interval,
                                progress=lambda text: click.echo(f"  {text}", err=True))
    for line in result.lines():
        click.echo(line)
    click.echo("matches" if result.matches else "differs")  # the verdict, once, last
    if not result.matches:
        click.get_current_context().exit(EXIT_DIFFERS)


__all__ = ["identify_cmd", "twin_group", "twin_url"]
