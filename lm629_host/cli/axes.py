"""The command line on a multi-axis board: ``--axis N``, ``--axis 0,1`` or ``--axis all``.

Why a module of its own: the commands in :mod:`lm629_host.cli` drive one chip; the few that
make sense on several (``status``, ``watch``, ``move`` with several targets, ``bringup`` one
axis after the other) call in here when more than one axis is named, and every other command
gets the one axis it names.  All the axes of a command share one transport (one
:class:`~lm629_host.motion.board.Board`), so a status of every axis is one bus program.

Which axes: ``--axis`` as given; without it, every chip of the port URL's ``axes=`` (a
simulator ``sim://?axes=2``, or a bridge URL ``...?axes=2``), else axis 0 alone (a one-chip
board).
"""

from __future__ import annotations

from typing import Any

import click



from lm629_host.chip.lm629 import LM629
from lm629_host.bus.opcodes import FIXED_ONE
from lm629_host.cli.app import MAX_AXIS, Session, axes_of, axis_name, board, parse_axes, several

__all__ = ["MAX_AXIS", "axes_of", "axis_name", "board", "check_targets", "move_many",
           "parse_axes", "several", "status", "watch_rows"]

def status(s: Session, as_json: bool, snapshot_dict: Any) -> None:
    b = board(s)
    axes = axes_of(s)
    snaps = b.snapshots(list(axes))
    rows = [dict(axis=k, **({"name": axis_name(s, k)} if s.profile is not None else {}),
                 **snapshot_dict(snap, s.scale)) for k, snap in zip(axes, snaps)]
    from lm629_host.cli.common import failsafe_info
    fs, fs_line = failsafe_info(b.transport)
    if as_json:
        import json  # here: a status is text unless asked (this module loads with every status)
        click.echo(json.dumps({"axes": rows, "failsafe": fs}, indent=2))
        return
    for k, snap, d in zip(axes, snaps, rows):
        click.echo(f"axis {axis_name(s, k)}: status {d['status']} {' '.join(d['status_flags']) or '-'}  "
                   f"signals {d['signals']}  desired {snap.desired_position}  actual "
                   f"{snap.real_position}  error {snap.following_error:+d}  velocity "
                   f"{snap.desired_velocity / FIXED_ONE:.5f}/{snap.real_velocity}")
    click.echo(f"failsafe {fs_line}")


def watch_rows(s: Session, count: int | None, rate: float, flags: Any,
               csv_path: str | None = None) -> None:
    """One row per axis at each tick, every axis read in one program; ``csv_path``: the same
    rows, with their axis, in a CSV file."""
    import csv

    b = board(s)
    axes = list(axes_of(s))
    names = {k: axis_name(s, k) for k in axes}
    width = max(4, *(len(n) for n in names.values()))
    f = open(csv_path, "w", newline="") if csv_path else None  # noqa: SIM115 - closed in finally
    writer = csv.writer(f) if f else None
    if writer:
        writer.writerow(("t_s", "axis", "desired_position", "real_position", "following_error",
                         "desired_velocity", "real_velocity", "status", "flags"))
    click.echo(f"{'t_s':>9} {'axis':>{width}} {'desired':>10} {'actual':>10} {'error':>7} "
               f"{'rv':>6} {'st':>3} flags")
    n = 0
    start = b.clock.now()
    t0: float | None = None  # t_s from the first row, as `lm629 watch` on one axis
    try:
        while count is None or n < count:
            for k, snap in zip(axes, b.snapshots(axes)):
                if t0 is None:
                    t0 = snap.time
                t = snap.time - t0
                click.echo(f"{t:9.4f} {names[k]:>{width}} {snap.desired_position:>10} "
                           f"{snap.real_position:>10} {snap.following_error:>+7} "
                           f"{snap.real_velocity:>+6} {int(snap.status):02X} "
                           f"{flags(snap.status)}")
                if writer:
                    writer.writerow((f"{t:.4f}", names[k], snap.desired_position,
                                     snap.real_position, snap.following_error,
                                     f"{snap.desired_velocity / FIXED_ONE:.4f}", snap.real_velocity,
                                     f"{int(snap.status):02X}", flags(snap.status)))
            n += 1
            if count is None or n < count:
                b.clock.sleep(max(0.0, start + n / rate - b.clock.now()))
    finally:
        if f:
            f.close()


def check_targets(s: Session, targets: list[int]) -> None:
    """One target per axis, or a usage error (before anything moves or stops)."""
    axes = axes_of(s)
    if len(targets) != len(axes):
        raise click.UsageError(f"{len(targets)} target(s) for {len(axes)} axis/axes "
                               f"({', '.join(axis_name(s, k) for k in axes)}): give one target "
                               "per axis")


def move_many(s: Session, targets: list[int], velocity: int, acceleration: int, linear: bool,
              tolerance: int | None, timeout: float | None, no_wait: bool) -> None:
    """``lm629 --axis 0,1 move X Y [--linear]``: one target per axis, started together."""
    axes = axes_of(s)  # as many as targets: checked by check_targets before anything moves
    b = board(s)
    goal: dict[LM629 | int | str, int] = dict(zip(axes, targets))
    try:
        if linear:
            m = b.move_linear(goal, velocity=velocity, acceleration=acceleration)
            words = ", ".join(f"axis {axis_name(s, p.axis)}: v {p.velocity} a {p.acceleration}"
                              for p in m.plan.axes if p.distance)  # type: ignore[union-attr]  # a linear move has a plan
            if words:
                click.echo(f"straight line to {targets} ({words})")
        else:
            m = b.move(goal, velocity=velocity, acceleration=acceleration)
            click.echo(f"moving axes {', '.join(axis_name(s, k) for k in axes)} to {targets} (velocity word {velocity}, "
                       f"acceleration word {acceleration}), started together")
        if no_wait:
            return
        results = m.wait(timeout=timeout, tolerance=tolerance)
    except BaseException:
        b.stop(list(axes))
        raise
    if not m.moves:  # every axis already on its target: a straight line of length 0
        click.echo(f"done: axes {', '.join(axis_name(s, k) for k in axes)} already at {targets}, "
                   "nothing moved")
    for k, r in zip((mv.chip.chip_select for mv in m.moves), results):
        click.echo(f"done: axis {axis_name(s, k)} at {r.position}, {r.error:+d} counts from {r.target}, "
                   f"at rest {r.duration:.3f} s after the start")

