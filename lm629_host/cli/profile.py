"""``lm629 --profile FILE`` and ``lm629 profile init|apply|show``: the bench profile on the
command line (the file, its checks and what is sent: :mod:`lm629_host.config.profile`).

With ``--profile`` (or ``$LM629_PROFILE``) every command gets the profile's port, chip and
clock unless the command line gives them, the encoder lines of the axis it drives (``--lines``
unless given), axis names (``--axis x``, ``--axis x,y``; without ``--axis``, every axis of the
profile), and once the port is open: each axis's soft limits, and the profile applied to a chip
that has lost its settings, in one line on stderr (:func:`lm629_host.config.profile.ensure_applied`).
The options a profile gives and what is done once the board opens are in
:mod:`.profile_session`, which :mod:`.app` calls.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from lm629_host.chip.lm629 import LM629
from lm629_host.bus.opcodes import Signals
from lm629_host.config.profile import (
    AXIS_KEYS,
    Profile,
    ProfileError,
    apply_profile,
    load_profile,
    save_gains,
    settings_lost,
    template,
)
from lm629_host.physics.pid import sample_period_s
from lm629_host.physics.units import to_fixed
from lm629_host.cli.app import Session, _session, axes_of, board, main
from lm629_host.cli.profile_session import named_axes
from lm629_host.cli.common import _flags

log = logging.getLogger("lm629_host.cli")

#: the file ``profile init`` writes when neither FILE nor --profile names one
DEFAULT_FILE = "lm629.toml"




# ---------------------------------------------------------------------------- checks for commands
def limits_of(s: Session) -> dict[int, Any]:
    """chip select -> its SoftLimits (the profile's axes that set any)."""
    prof: Profile | None = s.profile
    if prof is None:
        return {}
    return {ax.cs: lim for ax in prof.axes.values() if (lim := prof.limits(ax)) is not None}


def check_move(s: Session, targets: list[int], velocity: int, acceleration: int,
               relative: bool = False, linear: bool = False) -> None:
    """A move's targets and words against the profile's limits, before the port is opened
    (the library checks them again as the trajectory is built).  A straight line's words
    are the path's: each axis gets its share, checked when the line is planned."""
    limits = limits_of(s)
    if not limits:
        return
    for cs, target in zip(axes_of(s) if len(targets) > 1 else axes_of(s)[:1], targets):
        lim = limits.get(cs)
        if lim is None:
            continue
        if linear:
            lim.check_position(target)
        else:
            lim.check_trajectory(acceleration, velocity, None if relative else target)


def check_velocity_mode(s: Session, velocity: int, acceleration: int) -> None:
    """``lm629 velocity`` against the limits of its axis, before the port is opened."""
    lim = limits_of(s).get(axes_of(s)[0])
    if lim is not None:
        lim.check_trajectory(acceleration, velocity, None, velocity_mode=True)


def index_search(s: Session, word: int | None) -> tuple[int | None, bool]:
    """``index --search [WORD]``: (velocity word, forward).  No WORD (0): the profile's
    ``index_velocity`` of the axis; the direction is its sign (forward when not set)."""
    if word is None:
        return None, True
    prof: Profile | None = s.profile
    ax = prof.by_cs(axes_of(s)[0]) if prof is not None else None
    speed = ax.index_velocity if ax is not None else None
    forward = speed is None or speed > 0
    if word == 0:
        if speed is None:
            raise click.BadParameter("give a velocity WORD (no index_velocity in a profile for "
                                     "this axis)", param_hint="--search")
        word = max(1, to_fixed(abs(speed) * sample_period_s(s.clock_hz)))
    return word, forward


def tune_band(chip: LM629, travel: int) -> None:
    """``tune --travel N`` stays within N counts of where the shaft is: that band must lie
    inside the soft limits (ValueError before anything moves)."""
    lim = chip.limits
    if lim is None or not lim.has_travel:
        return
    snap = chip.snapshot()
    origin = snap.real_position if snap.signals & Signals.MOTOR_OFF else snap.desired_position
    for end in (origin - travel, origin + travel):
        try:
            lim.check_position(end, f"--travel {travel} from {origin}: the band reaches")
        except ValueError as exc:
            raise ValueError(f"{exc}; give a smaller --travel or move the axis first") from None


def save_target(s: Session, chip: LM629, save: str | None) -> tuple[Path, str] | None:
    """Where ``tune --save [FILE]`` writes: FILE, else the --profile file; and the axis name
    there of the chip tuned.  Checked before anything moves."""
    if save is None:
        return None
    path = Path(save) if save else None
    if path is None:
        if s.profile is None:
            raise click.BadParameter("no FILE and no --profile: nowhere to save the gains",
                                     param_hint="--save")
        path = s.profile.path
    prof = s.profile if s.profile is not None and path == s.profile.path else load_profile(path)
    ax = prof.by_cs(chip.chip_select)
    if ax is None:
        raise ProfileError(f"{path}: no [axis.NAME] with cs = {chip.chip_select} to save the "
                           "gains into")
    if not os.access(path, os.W_OK) or not os.access(path.parent, os.W_OK):
        raise click.BadParameter(f"{path} is not writable", param_hint="--save")
    return path, ax.name


@contextmanager
def tuning(s: Session, chip: LM629) -> Iterator[None]:
    """Around ``autotune`` (inside the motor's stop on error): the profile's following-error
    stop armed again however tuning ends (it arms its own at the travel and leaves LPEI 7FFF
    when it succeeds, which would read as lost settings)."""
    try:
        yield
    finally:
        ax = s.profile.by_cs(chip.chip_select) if s.profile is not None else None
        if ax is not None:
            try:
                chip.load_position_error(ax.threshold, stop=True)
            except Exception as exc:  # noqa: BLE001 - the error that ended tuning matters more
                log.warning("could not arm the profile's following error again: %s", exc)


def after_tune(s: Session, chip: LM629, gains: Any, target: tuple[Path, str] | None,
               ok: bool, plant: dict[str, Any] | None = None) -> None:
    """After ``tune``: the gains, and the plant identified (``[axis.NAME.plant]``), saved
    when asked and good."""
    if target is None:
        return
    path, name = target
    if not ok:
        click.echo(f"lm629: gains not saved to {path}: the test move missed the tolerance",
                   err=True)
        return
    save_gains(path, name, {"kp": gains.kp, "ki": gains.ki, "kd": gains.kd, "il": gains.il,
                            "ds": gains.ds}, plant=plant)
    click.echo(f"saved kp={gains.kp} ki={gains.ki} kd={gains.kd} il={gains.il} "
               f"ds={gains.ds} into [axis.{name}] of {path}")
    if plant:
        click.echo(f"saved the plant into [axis.{name}.plant] of {path}")


# ---------------------------------------------------------------------------- commands
@main.group("profile")
def profile_group() -> None:
    """The bench profile: init (a commented template), apply (load it into the chips), show."""


def _need_profile(s: Session) -> Profile:
    if s.profile is None:
        path = click.get_current_context().meta.get("lm629.profile_path")
        raise click.UsageError(f"{path} does not exist (`lm629 --profile {path} profile init` "
                               "writes one)" if path else "give --profile FILE (or "
                               "$LM629_PROFILE)")
    prof: Profile = s.profile
    return prof


@profile_group.command("init")
@click.argument("file", required=False, type=click.Path(dir_okay=False))
@click.option("--force", is_flag=True, help="Overwrite an existing file.")
def init_cmd(file: str | None, force: bool) -> None:
    """Write a commented profile from the current options (--port, --chip, --clock, --lines,
    --axis) to FILE (default: the --profile file, else lm629.toml)."""
    s = _session()
    ctx = click.get_current_context()
    path = Path(file or ctx.meta.get("lm629.profile_path") or DEFAULT_FILE)
    if path.exists() and not force:
        raise click.BadParameter(f"{path} exists (--force to overwrite)", param_hint="FILE")
    if not path.parent.is_dir() if str(path.parent) else False:
        raise click.BadParameter(f"the directory {path.parent} does not exist", param_hint="FILE")
    spec = s.axis_spec
    axes = spec if isinstance(spec, tuple) else tuple(axes_of(s)) if spec is None else (0,)
    text = template(port=str(s.port) if s.port_given else None, chip=s.chip_name,
                    clock=f"{s.clock_hz / 1e6:g}MHz", lines=s.lines, axes=axes)
    path.write_text(text, encoding="utf-8")
    load_profile(path)  # what it wrote reads back
    click.echo(f"wrote {path} ({len(axes)} axis/axes; edit it, then `lm629 --profile {path} "
               "profile apply`)")


@profile_group.command("apply")
def apply_cmd() -> None:
    """Load the profile into the chips: filter (LFIL + UDF), following-error stop (LPES),
    output mode; refused while an axis moves."""
    s = _session()
    prof = _need_profile(s)
    s.reapply = False  # what it sends is the command itself
    b = board(s)
    for line in apply_profile(named_axes(s, b), prof):
        click.echo(line)
    click.echo(f"applied {prof.path}")


@profile_group.command("show")
def show_cmd() -> None:
    """Print the profile and how each axis stands now (nothing is sent but reads)."""
    s = _session()
    prof = _need_profile(s)
    s.reapply = False  # what it sends is the command itself
    port = prof.port or f"none in the file (this command: {s.port})"
    click.echo(f"profile {prof.path}: port {port}, chip {prof.chip}, "
               f"clock {prof.clock_hz / 1e6:g} MHz" + (f"  # {prof.note}" if prof.note else ""))
    b = board(s)
    chips = named_axes(s, b)
    for name, ax in prof.axes.items():
        keys = " ".join(f"{k}={getattr(ax, k)}" for k in AXIS_KEYS
                        if k not in ("cs", "note") and getattr(ax, k) is not None)
        click.echo(f"axis {name}: cs {ax.cs}  {keys}" + (f"  # {ax.note}" if ax.note else ""))
        chip = chips.get(name)
        if chip is None:
            click.echo(f"  not on this board ({len(b.axes)} chip selects)")
            continue
        lost = settings_lost(chip)
        chip.sync()  # RDSIGS's busy over: the status reads as `lm629 status` reads it
        snap = chip.snapshot()
        state = ("settings LOST (signals bit 9 clear: reset or powered up since applied; the "
                 "next command applies the profile)" if lost is not None
                 else "settings applied (LPES armed)")
        click.echo(f"  now: {state}; status {int(snap.status):02X} {_flags(snap.status)}, "
                   f"desired {snap.desired_position}, actual {snap.real_position}, error "
                   f"{snap.following_error:+d}")
        if chip.limits is not None:
            click.echo(f"  limits: {chip.limits.describe()}")


__all__ = ["after_tune", "check_move", "check_velocity_mode", "tuning", "profile_group",
           "save_target", "tune_band"]
