"""The step plot that tuning needs (``lm629 step``, ``lm629 tune --plot``).

Three panels against time after the STT (ms): position (counts; revolutions on a second axis
with ``--lines``) with the rise time, overshoot and settle markers; following error
(counts); the filter's output (% of full scale) with the saturation limits, so that a step
that saturates the drive shows it.  Every gain is in the title.

The chip does not report its output.  It is rebuilt from each snapshot with the chip's own
arithmetic (AN-706 5.2.3): ``kp x e + RDSUM + kd x (derivative difference)``, the difference
being (desired - real velocity) x derivative interval (RDDV, RDRV), saturated to 16 bits, top
8 bits (12 in LM628 12-bit mode).  It is exact between samples where the velocities are steady,
an estimate around a jump; the panel says "rebuilt".

matplotlib is optional: :class:`lm629_host.bench.capture.PlotUnavailable` says how to get it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lm629_host.bench.capture import Capture, PlotUnavailable
from lm629_host.bus.snapshot import Snapshot
from lm629_host.physics.pid import derivative_term, filter_sum, full_scale, output_code, sat16
from lm629_host.physics.axis import Gains
from lm629_host.physics.metrics import MoveMetrics, step_metrics
from lm629_host.physics.units import FIXED_ONE

COLORS = ("tab:red", "tab:green", "tab:orange", "tab:purple")


@dataclass
class Response:
    """One step response to draw: snapshots, times after the STT, and what is known of the
    filter (``gains`` None: as loaded, unknown; then no output trace)."""

    label: str
    times: Sequence[float]
    rows: Sequence[Snapshot]
    start: int
    target: int
    gains: Gains | None
    twelve_bit: bool = False

    def metrics(self, tolerance: int) -> MoveMetrics:
        return step_metrics(self.times, [s.real_position for s in self.rows],
                            [s.desired_position for s in self.rows], self.start, self.target,
                            tolerance)


def rebuilt_output(s: Snapshot, g: Gains, twelve_bit: bool = False) -> int:
    """The output code the filter computes for the state in snapshot ``s`` (see module doc)."""
    e = sat16(s.following_error)
    diff = round((s.desired_velocity / FIXED_ONE - s.real_velocity) * g.ds)
    u = filter_sum(g.kp, e, s.integration_sum, derivative_term(g.kd, diff))
    return output_code(u, twelve_bit)


def response_from_capture(cap: Capture, label: str = "response") -> Response:
    """A :class:`Response` of an ``lm629 step`` capture (gains from the filter it loaded;
    ki and kd not given count as 0 for the rebuilt output, RDSUM carries the integral)."""
    f = cap.filter
    gains = None
    if "kp" in f:
        gains = Gains(f["kp"], f.get("ki", 0), f.get("kd", 0), f.get("il", 0),
                      f.get("derivative_interval", 1))
    start = cap.rows[0].desired_position if cap.rows else cap.target
    return Response(label, cap.times(), cap.rows, start, cap.target, gains)


def _gain_text(g: Gains | None, given: dict[str, int] | None = None) -> str:
    if g is None:
        return "filter as loaded"
    if given is not None:
        names = {"kp": "kp", "ki": "ki", "kd": "kd", "il": "il", "derivative_interval": "ds"}
        return " ".join(f"{names[k]}={given[k]}" if k in given else f"{names[k]}=(as loaded)"
                        for k in names)
    return str(g)


def plot_responses(path: str | Path, responses: Sequence[Response], *, title: str = "",
                   lines: int | None = None, tolerance: int = 2,
                   gain_texts: Sequence[str] | None = None) -> Path:
    """Draw ``responses`` (one colour each) in one figure; returns the path."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotUnavailable(
            "matplotlib is not installed, so no PNG was drawn (the CSV has the data): "
            "pip install 'lm629-host[plot]'") from exc
    path = Path(path)
    fig, (ax, ax_err, ax_out) = plt.subplots(3, 1, sharex=True, figsize=(9, 8),
                                             gridspec_kw={"height_ratios": [3, 1.2, 1.2]})
    texts = list(gain_texts or [_gain_text(r.gains) for r in responses])
    try:
        for i, r in enumerate(responses):
            color = COLORS[i % len(COLORS)]
            t_ms = [t * 1e3 for t in r.times]
            m = r.metrics(tolerance)
            if i == 0:
                ax.plot(t_ms, [s.desired_position for s in r.rows], color="tab:blue",
                        drawstyle="steps-post", label="desired position", linewidth=1)
                for y in (r.target - tolerance, r.target + tolerance):
                    ax.axhline(y, color="grey", linewidth=0.5, linestyle=":")
            real = [s.real_position for s in r.rows]
            ax.plot(t_ms, real, color=color, label=f"{r.label}: actual ({texts[i]})")
            # markers: rise 10-90 %, overshoot peak, settle time
            dist = r.target - r.start
            for frac in (0.1, 0.9):
                level = r.start + frac * dist
                t_hit = next((t for t, p in zip(t_ms, real)
                              if (p - r.start) * (1 if dist >= 0 else -1) >= abs(frac * dist)),
                             None)
                if t_hit is not None:
                    ax.plot([t_hit], [level], marker="|", markersize=14, color=color)
            if m.rise_s is not None:
                ax.annotate(f"rise {m.rise_s * 1e3:.1f} ms", xy=(0.01, 0.93 - 0.08 * i),
                            xycoords="axes fraction", color=color, fontsize=8)
            if m.overshoot > 0:
                sign = 1 if dist >= 0 else -1
                k = max(range(len(real)), key=lambda j: sign * real[j])
                ax.plot([t_ms[k]], [real[k]], marker="v", color=color)
                ax.annotate(f"overshoot {m.overshoot}", xy=(t_ms[k], real[k]), color=color,
                            fontsize=8, xytext=(4, 4), textcoords="offset points")
            if m.settle_s is not None:
                ax.axvline(m.settle_s * 1e3, color=color, linewidth=0.8, linestyle="--")
                ax.annotate(f"settled +/-{tolerance} at {m.settle_s * 1e3:.0f} ms",
                            xy=(m.settle_s * 1e3, r.start + 0.5 * dist), color=color,
                            fontsize=8, rotation=90, xytext=(3, 0), textcoords="offset points")
            ax_err.plot(t_ms, [s.following_error for s in r.rows], color=color)
            if r.gains is not None:
                fs = full_scale(r.twelve_bit)
                ax_out.plot(t_ms, [100 * rebuilt_output(s, r.gains, r.twelve_bit) / fs
                                   for s in r.rows], color=color, drawstyle="steps-post")
        ax.set_ylabel("position (counts)")
        if lines:
            per_rev = 4 * lines
            sec = ax.secondary_yaxis("right", functions=(lambda c: c / per_rev,
                                                         lambda rev: rev * per_rev))
            sec.set_ylabel(f"position (revolutions, {lines} lines)")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(True, alpha=0.3)
        ax.set_title(title or "step response: " + "; ".join(texts), fontsize=10)
        ax_err.set_ylabel("following error\n(counts)")
        ax_err.grid(True, alpha=0.3)
        for y in (100, -100):
            ax_out.axhline(y, color="grey", linewidth=0.8, linestyle="--")
        ax_out.set_ylim(-115, 115)
        ax_out.set_ylabel("output, rebuilt\n(% of full scale)")
        ax_out.set_xlabel("time after STT (ms)")
        ax_out.grid(True, alpha=0.3)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return path


def plot_capture(cap: Capture, path: str | Path, *, lines: int | None = None,
                 tolerance: int = 2, title: str = "") -> Path:
    """The ``lm629 step`` picture of one capture."""
    r = response_from_capture(cap, "step")
    return plot_responses(path, [r], title=title, lines=lines, tolerance=tolerance,
                          gain_texts=[_gain_text(r.gains, cap.filter) if cap.filter
                                      else "filter as loaded"])


__all__ = ["Response", "plot_responses", "plot_capture", "rebuilt_output",
           "response_from_capture"]
