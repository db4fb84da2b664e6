"""``lm629 calc``: the units calculator (no port is opened).

rpm, revolutions and rev/s^2 <-> the chip's raw words (AN-868's formulas, in
:class:`lm629_host.physics.units.Scale`), and the trapezoid of AN-706 5.3 from distance, time and ramp
time.  Raw words are printed in decimal and hex, with what the chip really runs with them (the
words are rounded, the inverse is exact).
"""

from __future__ import annotations

import click

from lm629_host.cli.app import main
from lm629_host.physics.units import Scale
from lm629_host.cli.types import FINITE


def _word(value: int, digits: int = 8) -> str:
    return f"{value} (0x{value & (16 ** digits - 1):0{digits}X})"


@main.command(context_settings={"ignore_unknown_options": True})
@click.option("--lines", type=int, default=None, help="Encoder lines (else the global --lines).")
@click.option("--clock", "clock_hz", type=FINITE, default=None,
              help="Chip clock in Hz (else the global --clock).")
@click.option("--rpm", type=FINITE, multiple=True, help="Velocity in rpm -> raw word.")
@click.option("--rev", type=FINITE, multiple=True, help="Revolutions -> counts.")
@click.option("--acceleration", "--acc", "--accel", "accel", type=FINITE, multiple=True,
              help="rev/s^2 -> raw word.")
@click.option("--velocity-word", type=str, multiple=True, help="Raw velocity word -> rpm.")
@click.option("--acceleration-word", type=str, multiple=True, help="Raw acceleration -> rev/s^2.")
@click.option("--counts", type=str, multiple=True, help="Counts -> revolutions.")
@click.option("--trapezoid", nargs=3, type=FINITE, default=None,
              metavar="REV SECONDS RAMP_S",
              help="A move of REV revolutions in SECONDS with RAMP_S of acceleration (AN-706 5.3).")
@click.pass_context
def calc(ctx: click.Context, lines: int | None, clock_hz: float | None, rpm: tuple[float, ...],
         rev: tuple[float, ...], accel: tuple[float, ...], velocity_word: tuple[str, ...],
         acceleration_word: tuple[str, ...], counts: tuple[str, ...],
         trapezoid: tuple[float, float, float] | None) -> None:
    """Units calculator: physical units <-> raw words (decimal and hex)."""
    from lm629_host.cli.types import parse_int  # the one integer parser of the CLI
    session = ctx.find_object(object)  # the global options, when run under `lm629`
    lines = lines or getattr(session, "lines", None)
    if clock_hz is None:
        clock_hz = getattr(session, "clock_hz", 8_000_000)
    if not lines:
        raise click.UsageError("calc needs the encoder's lines: lm629 --lines 500 calc ... "
                               "(or calc --lines 500)")
    if not (rpm or rev or accel or velocity_word or acceleration_word or counts or trapezoid):
        raise click.UsageError("nothing to calculate: give --rpm, --rev, --accel, "
                               "--velocity-word, --acceleration-word, --counts or --trapezoid")
    sc = Scale(lines, clock_hz)
    click.echo(f"{lines} lines = {sc.counts_per_rev} counts/rev; sample {sc.sample_period * 1e6:g} "
               f"us at {clock_hz / 1e6:g} MHz")
    for x in rev:
        click.echo(f"{x:g} rev = position {_word(sc.position(x))} counts")
    for x in rpm:
        w = sc.velocity(x)
        click.echo(f"{x:g} rpm = velocity {_word(w)}  (runs {sc.rpm(w):.4f} rpm)")
    for x in accel:
        w = sc.acceleration(x)
        click.echo(f"{x:g} rev/s^2 = acceleration {_word(w)}  (runs {sc.rev_per_s2(w):.4f} rev/s^2)")
    for text in velocity_word:
        w = parse_int(text)
        click.echo(f"velocity {_word(w)} = {sc.rpm(w):.4f} rpm")
    for text in acceleration_word:
        w = parse_int(text)
        click.echo(f"acceleration {_word(w)} = {sc.rev_per_s2(w):.4f} rev/s^2")
    for text in counts:
        c = parse_int(text)
        click.echo(f"{c} counts = {sc.revolutions(c):.6f} rev")
    if trapezoid:
        r, dur, ramp = trapezoid
        t = sc.trapezoid(r, dur, ramp)
        click.echo(f"trapezoid {r:g} rev in {dur:g} s, {ramp:g} s ramps:")
        click.echo(f"  position     {_word(t.position)}")
        click.echo(f"  velocity     {_word(t.velocity)}  ({sc.rpm(t.velocity):.3f} rpm)")
        click.echo(f"  acceleration {_word(t.acceleration)}  "
                   f"({sc.rev_per_s2(t.acceleration):.4f} rev/s^2)")
        click.echo(f"  the chip runs it: ramps {t.accel_time_s:.4f} s, whole move "
                   f"{t.duration_s:.4f} s")


__all__ = ["calc"]
