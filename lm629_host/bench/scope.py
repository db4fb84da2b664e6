"""What ``lm629 scope`` shows: desired and actual position and following error of some axes,
over the last few seconds, read without touching the motor.

Why a module apart from the command: the feed is one function, :func:`feed`: rows recorded
on the far side where the transport can (a bridge that records on its side and streams the
samples), the host's polling elsewhere, without the plot knowing; the window (:class:`ScopeWindow`) and the PNG
(:func:`save_png`) are plain data and matplotlib, usable from a lab script.

Reads only: every bus program the feed runs is status and register reads
(:meth:`Board.snapshots <lm629_host.motion.board.Board.snapshots>`), so ending it, by Ctrl-C or
anything else, leaves every motor as it was.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lm629_host.bench.capture import PlotUnavailable
from lm629_host.bus.snapshot import Snapshot


def feed(board: Any, axes: Sequence[int], rate_hz: float,
         duration_s: float | None = None) -> Iterator[list[Snapshot]]:
    """The snapshots of ``axes`` (chip selects of ``board``), ``rate_hz`` times a second of
    the transport's clock, for ``duration_s`` (None: until the caller stops).  The one source
    of :mod:`scope`'s samples.

    One axis on a transport that records on its far side (the bridge's RECORD, the
    simulator's clock: :func:`lm629_host.chip.recording.far_snapshots`): rows timed and streamed
    there, so the host's pauses (a redraw) cost no samples.  Otherwise the host polls, each
    tick's axes in one bus program."""
    if not 0 < rate_hz <= 2000:
        raise ValueError(f"rate_hz={rate_hz} must be in 0..2000 samples per second")
    if len(axes) == 1:
        from lm629_host.chip.recording import far_snapshots
        rows = 0 if duration_s is None else max(1, round(duration_s * rate_hz))
        recorded = far_snapshots(board.axes[axes[0]], 1.0 / rate_hz, rows)
        if recorded is not None:
            try:
                for snap in recorded:
                    yield [snap]
            finally:
                recorded.close()  # stops the far side's recording
            return
    clock = board.clock
    start = clock.now()
    n = 0
    while True:
        snaps = board.snapshots(list(axes))
        yield snaps
        n += 1
        if duration_s is not None and clock.now() - start >= duration_s:
            return
        wait = start + n / rate_hz - clock.now()
        if wait > 0:
            clock.sleep(wait if duration_s is None
                        else min(wait, max(0.0, start + duration_s - clock.now())))


@dataclass
class ScopeTrace:
    """One axis's samples in the window."""

    time: deque[float] = field(default_factory=deque)
    desired: deque[int] = field(default_factory=deque)
    actual: deque[int] = field(default_factory=deque)

    @property
    def error(self) -> list[int]:
        return [d - a for d, a in zip(self.desired, self.actual)]


class ScopeWindow:
    """The last ``window_s`` seconds of each axis, times relative to the first sample."""

    def __init__(self, names: Sequence[str], window_s: float = 2.0) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s={window_s} must be positive (seconds)")
        self.names = list(names)
        self.window_s = window_s
        self.traces = {n: ScopeTrace() for n in self.names}
        self.t0: float | None = None
        self.samples = 0

    def add(self, snaps: Sequence[Snapshot]) -> None:
        for name, s in zip(self.names, snaps):
            if self.t0 is None:
                self.t0 = s.time
            tr = self.traces[name]
            t = s.time - self.t0
            tr.time.append(t)
            tr.desired.append(s.desired_position)
            tr.actual.append(s.real_position)
            while tr.time and tr.time[0] < t - self.window_s:
                tr.time.popleft()
                tr.desired.popleft()
                tr.actual.popleft()
        self.samples += 1

    def last(self, name: str) -> tuple[float, int, int] | None:
        tr = self.traces[name]
        return (tr.time[-1], tr.desired[-1], tr.actual[-1]) if tr.time else None


def save_png(window: ScopeWindow, path: str | Path, title: str = "") -> Path:
    """The window as a PNG: positions above, following errors below (matplotlib)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotUnavailable("matplotlib is not installed, so no PNG was drawn: "
                              "pip install 'lm629-host[scope]'") from exc
    path = Path(path)
    fig, (ax, ax_err) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                     gridspec_kw={"height_ratios": [2, 1]})
    try:
        for name, tr in window.traces.items():
            t = list(tr.time)
            ax.plot(t, list(tr.desired), linewidth=1,
                    label=f"{name} desired")
            ax.plot(t, list(tr.actual), linewidth=1.5, label=f"{name} actual")
            ax_err.plot(t, tr.error, linewidth=1, label=f"{name} following error")
        ax.set_ylabel("position, counts")
        ax_err.set_ylabel("error, counts")
        ax_err.set_xlabel("time, s")
        for a in (ax, ax_err):
            a.grid(True, linewidth=0.3)
            a.legend(loc="best", fontsize="small")
        ax.set_title(title or f"lm629 scope: last {window.window_s:g} s")
        fig.tight_layout()
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return path


__all__ = ["ScopeWindow", "ScopeTrace", "feed", "save_png"]
