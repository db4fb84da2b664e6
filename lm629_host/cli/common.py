"""What several command families share: positions in counts or revolutions, the status
flags in words, progress lines, waits that say what they waited for."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import click

from lm629_host.bus.snapshot import Snapshot
from lm629_host.errors import ArgumentError
from lm629_host.bus.opcodes import FIXED_ONE, POSITION_MAX, POSITION_MIN, Signals, Status
from lm629_host.cli.app import Session
from lm629_host.cli.types import shown

if TYPE_CHECKING:  # the driver loads when a command opens a chip, the units with --lines
    from lm629_host.chip.lm629 import LM629
    from lm629_host.physics.units import Scale


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


def failsafe_info(transport: Any) -> tuple[dict[str, Any] | None, str]:
    """The link failsafe for ``status`` and ``doctor``: a JSON-able dict (None when the port
    has no far-side failsafe) and one line.  A trip this open found (and acknowledged) is
    reported with it: the process that opens after a dead host is the one told."""
    state = transport.failsafe_state()
    if state is None:
        beat = getattr(transport, "heartbeat", None)
        if beat is not None:
            return None, (f"none on this port (no timer on its side of the link); the heartbeat "
                          f"on {beat.upper()} feeds an external watchdog while this process lives")
        return None, ("none on this port: a host that dies mid-move leaves the axis moving "
                      "(only a bridge keeps a timer on its side of the link; on the FT232H, "
                      "?heartbeat=adbus7 feeds an external watchdog)")
    found = transport.failsafe_report
    d: dict[str, Any] = {"armed_s": state.timeout_ms / 1e3,
                         "action": ("abrupt", "smooth", "off")[state.action]
                         if state.action < 3 else state.action,
                         "tripped": state.tripped,
                         "trip": None if found is None else {
                             "text": found.describe(), "cs": found.stopped,
                             "silent_s": found.silent_ms / 1e3, "at_s": found.at_ms / 1e3}}
    line = (f"armed, {state.timeout_ms / 1e3:g} s, {d['action']} stop" if state.timeout_ms
            else "disarmed (failsafe=0)")
    if state.tripped:
        line += f"; TRIPPED: {state.describe()} (acknowledge: lm629 clear)"
    elif found is not None:
        line += f"; {found.describe()} (acknowledged by this open)"
    return d, line


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
            raise click.BadParameter(f"{shown(value)} must be whole counts without --lines",
                                     param_hint=name)
        counts = int(value)
    if not POSITION_MIN <= counts <= POSITION_MAX:
        said = shown(value)  # as typed: 2000000000, not 2e+09
        what = (f"{said} rev is {counts} counts" if s.scale is not None and not raw else
                f"{said} counts" if said == str(counts) else f"{said} ({counts} counts)")
        raise click.BadParameter(f"{what}, outside {POSITION_MIN}..{POSITION_MAX}",
                                 param_hint=name)
    return counts


def _show_position(s: Session, counts: int) -> str:
    return (f"{counts} counts ({s.scale.revolutions(counts):.4f} rev)" if s.scale is not None
            else f"{counts} counts")


def _wait_flag(chip: LM629, flag: Status, words: str, timeout: float) -> Status:
    """``wait_for`` whose timeout says in words what it waited for."""
    return chip.wait_for(flag, timeout=timeout, poll=0.001, what=words)


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


def check_filter_options(chip: LM629, kp: int | None, ki: int | None, kd: int | None,
                         il: int | None, ds: int | None) -> None:
    """The filter options against the chip's ranges, before any traffic: an error names the
    option the user typed (``--kp``, ``--ds``), not the library's argument."""
    try:
        chip.filter_program(kp, ki, kd, il, ds=ds)
    except ArgumentError as exc:  # named as the options are: kp, ki, kd, il, ds
        raise click.BadParameter(str(exc), param_hint=f"--{exc.argument}") from None
