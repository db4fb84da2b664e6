"""``lm629 wiring``: the connections for the adapter in use, as a table with the pin numbers on
both sides (``--svg``/``--png``: drawn), and ``--check``: find the wrong wire, moving nothing
(:mod:`lm629_host.bench.wiring_check`; this module only prints)."""

from __future__ import annotations

import click

from lm629_host.wiring.connections import ADAPTERS, MAX_AXES, text_table
from lm629_host.bench.wiring_check import adapter_for, check_wiring
from lm629_host.bench import wiring_draw as wiring_svg
from lm629_host.bench.wiring_draw import write_png, write_svg
from lm629_host.cli.app import _session, main
from lm629_host.cli.types import check_writable


@main.command()
@click.option("--adapter", type=click.Choice(ADAPTERS, case_sensitive=False), default=None,
              help="The adapter wired to the LM629 (default: from --port: ftdi:// and "
                   "sim+ftdi:// the FT232H, anything else the Uno bridge).")
@click.option("--axes", type=int, default=1, show_default=True,
              help="Chips on the bus (each has its own /CS; the Uno takes 4, the FT232H 2).")
@click.option("--svg", "svg", type=click.Path(dir_okay=False, writable=True), default=None,
              help="Also draw the wiring into this SVG file.")
@click.option("--png", "png", type=click.Path(dir_okay=False, writable=True), default=None,
              help="Also draw it as PNG (needs rsvg-convert or cairosvg).")
@click.option("--check", is_flag=True,
              help="Test every data line and what can be seen of the control lines on the "
                   "chip at --port, moving nothing; exit 1 when a line is suspect.")
def wiring(adapter: str | None, axes: int, svg: str | None, png: str | None,
           check: bool) -> None:
    """The wires between the adapter and the LM629, with the physical pins at both ends.

    With --check: reset the chip, write patterns (zero-gain filter: the shaft does not move),
    read them back, and print one line per suspect wire; the chip is left reset, motor off."""
    s = _session()
    name = (adapter or adapter_for(s.port)).lower()
    if not 1 <= axes <= MAX_AXES[name]:
        raise click.BadParameter(f"{axes}: the {name} wiring has 1..{MAX_AXES[name]} chip "
                                 "selects", param_hint="--axes")
    for path, opt in ((svg, "--svg"), (png, "--png")):
        if path:
            check_writable(path, opt)
    if png and wiring_svg.png_renderer() is None:  # before the check touches the chip
        raise click.UsageError(wiring_svg.NO_RENDERER)
    if check:
        chip = s.open(prepare=False)
        report = check_wiring(chip, name)
        for line in report.lines():
            click.echo(line)
        _draw(name, axes, svg, png)
        click.get_current_context().exit(0 if report.passed else 1)
    click.echo(text_table(name, axes), nl=False)
    _draw(name, axes, svg, png)


def _draw(name: str, axes: int, svg: str | None, png: str | None) -> None:
    if svg:
        click.echo(f"drawing written to {write_svg(svg, name, axes)}")
    if png:
        try:
            click.echo(f"drawing written to {write_png(png, name, axes)}")
        except RuntimeError as exc:
            raise click.UsageError(str(exc)) from None
