"""``lm629 scope``: a live terminal plot of desired and actual position and following error
(plotext, the optional extra ``lm629-host[scope]``), so that it works over SSH.

Read-only (:mod:`lm629_host.bench.scope`): Ctrl-C, ``--duration`` or a closed terminal end it and
leave every motor as it was.  On a terminal the plot is redrawn ``--refresh`` times a second;
otherwise (a pipe, a log) only the last window is printed once at the end.
"""

from __future__ import annotations

import shutil
import sys
from typing import Any

import click

from lm629_host.bench.capture import PlotUnavailable
from lm629_host.bench.scope import ScopeWindow, feed, save_png
from lm629_host.cli.app import _session, axes_of, board, main
from lm629_host.cli.types import FINITE, check_writable, positive


def _plotext() -> Any:
    try:
        import plotext
    except ImportError:  # an extra not installed: bad usage (exit 2), as a missing renderer is
        raise click.UsageError("the terminal plot needs plotext: pip install "
                               "'lm629-host[scope]'") from None
    return plotext


def _key(window: ScopeWindow) -> str:
    """The lines of each pane, in the order drawn (so in plotext's colour order): a legend
    inside the canvas would hide the data under it."""
    names = list(window.traces)
    top = ", ".join(f"{n} desired, {n} actual" for n in names)
    return f"top: {top}; bottom: {', '.join(f'{n} error' for n in names)} (in colour order)"


def render(window: ScopeWindow, width: int, height: int, title: str) -> str:
    """The window as text: positions above, following errors below, on one time axis (the
    same limits in both panes), with the key under the plot, never over the data (plotext
    6, or 5)."""
    plt = _plotext()
    times = [t for tr in window.traces.values() for t in (tr.time[0], tr.time[-1]) if tr.time]
    lo, hi = (min(times), max(times)) if times else (0.0, 1.0)
    hi = hi if hi > lo else lo + 1e-3  # one sample: a range plotext can scale
    figure = getattr(plt, "figure", None)
    if figure is not None and hasattr(figure, "signal"):  # plotext 6
        figure.clear()
        figure.subplots(2, 1)
        top, low = figure.subplot(1, 1), figure.subplot(2, 1)
        for tr in window.traces.values():
            t = list(tr.time) or [0.0]
            top.draw(top.signal(t, list(tr.desired) or [0]))
            top.draw(top.signal(t, list(tr.actual) or [0]))
            low.draw(low.signal(t, tr.error or [0]))
        for pane in (top, low):
            pane.ruler("x").lim(lo, hi)
        top.title(title)
        low.title("following error, counts")
        figure.plot_size(width, height)
        return str(figure.build().string()) + "\n" + _key(window)
    plt.clf()  # plotext 5
    plt.subplots(2, 1)
    plt.subplot(1, 1)
    for tr in window.traces.values():
        plt.plot(list(tr.time), list(tr.desired))
        plt.plot(list(tr.time), list(tr.actual))
    plt.xlim(lo, hi)
    plt.title(title)
    plt.subplot(2, 1)
    for tr in window.traces.values():
        plt.plot(list(tr.time), tr.error)
    plt.xlim(lo, hi)
    plt.title("following error, counts")
    plt.plotsize(width, height)
    return str(plt.build()) + "\n" + _key(window)


def _names(s: Any) -> list[str]:
    prof = s.profile
    out = []
    for cs in axes_of(s):
        ax = prof.by_cs(cs) if prof is not None else None
        out.append(ax.name if ax is not None else f"axis {cs}")
    return out


@main.command()
@click.option("--duration", type=FINITE, default=None,
              help="End by itself after this many seconds (default: Ctrl-C ends it).")
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None,
              help="Also save the last window as a PNG (matplotlib) when it ends.")
@click.option("--rate", type=FINITE, default=100.0, show_default=True,
              help="Samples per second (recorded on the bridge where it can, else polled: "
                   "at most one per round trip).")
@click.option("--window", "window_s", type=FINITE, default=2.0, show_default=True,
              help="Seconds shown.")
@click.option("--refresh", type=FINITE, default=5.0, show_default=True,
              help="Redraws per second on a terminal.")
def scope(duration: float | None, png_path: str | None, rate: float, window_s: float,
          refresh: float) -> None:
    """A live plot of desired and actual position and following error (every axis named by
    --axis or the profile).  Reads only: ending it never touches a motor."""
    positive("--duration", duration)
    positive("--window", window_s)
    positive("--refresh", refresh)
    if not 0 < rate <= 2000:
        raise click.BadParameter(f"{rate:g} must be in 0..2000 samples per second",
                                 param_hint="--rate")
    if png_path:
        check_writable(png_path, "--png")
    _plotext()  # missing: say so before the port is opened
    s = _session()
    names = _names(s)
    b = board(s)
    win = ScopeWindow(names, window_s)
    live = sys.stdout.isatty()
    size = shutil.get_terminal_size((100, 30))
    width, height = max(40, size.columns), max(12, size.lines - 5)  # the key and 3 lines below
    where = s.port

    def title() -> str:
        parts = []
        for n in names:
            last = win.last(n)
            if last is not None:
                parts.append(f"{n}: {last[1]} / {last[2]} ({last[1] - last[2]:+d})")
        text = "desired / actual  " + "  ".join(parts) + f"  on {where}"
        return text if len(text) <= width - 4 else text[:width - 7] + "..."  # plotext drops
        # a title wider than the plot

    clock = b.clock
    drawn = clock.now()
    try:
        for snaps in feed(b, axes_of(s), rate, duration):
            win.add(snaps)
            if live and clock.now() - drawn >= 1.0 / refresh:
                drawn = clock.now()
                click.echo("\x1b[H\x1b[2J" + render(win, width, height, title()), nl=False)
    finally:  # Ctrl-C included: the last window is still shown and saved; nothing is sent
        if win.samples:
            if live:
                click.echo("\x1b[H\x1b[2J", nl=False)
            click.echo(render(win, width, height, title()))
            if png_path:
                try:
                    click.echo(f"wrote {save_png(win, png_path, title())}")
                except PlotUnavailable as exc:
                    click.echo(f"lm629: {exc}", err=True)
    click.echo(f"{win.samples} samples of {len(names)} axis/axes in "
               f"{(win.last(names[0]) or (0.0,))[0]:.2f} s", err=True)


__all__ = ["render", "scope"]
