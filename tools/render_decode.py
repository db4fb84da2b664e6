#!/usr/bin/env python3
"""The picture of docs/debugging.md: the ``lm629`` decoder's annotations over a simulated capture,
drawn as PulseView lays them out (the lines on top, one row of annotations per decoder row).

A script runs on ``sim://?vcd=...&strict=0`` (a filter load, then an LTRJ whose control word
announces three parameters but carries two, cut short by STT: a host bug the decoder names);
sigrok-cli decodes the VCD with the package's decoder (:func:`lm629_host.sigrok.decode`), and
matplotlib draws both.  Nothing is drawn from the host's own knowledge: the annotations are
sigrok's output, the levels the VCD's.

Run:  python3 tools/render_decode.py [--out docs/debugging-decode.png] [--vcd bus.vcd]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import lm629_host
from lm629_host.bus.opcodes import Cmd
from lm629_host.sigrok import Annotation, decode

#: the decoder's rows, top to bottom, and their colours
ROWS = (("Bus cycles", "#9ecae1"), ("Commands", "#a1d99b"), ("Words", "#fdd0a2"),
        ("Busy checks", "#dadaeb"), ("Protocol warnings", "#fc9272"))
LINES = ("cs", "ps", "rd", "wr")


def capture(vcd: Path) -> None:
    """The script: LFIL + UDF as the driver sends them, then a short LTRJ and STT."""
    with lm629_host.open(f"sim://?strict=0&vcd={vcd}") as chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        chip.raw(Cmd.LTRJ, [0x002A, 0x0000, 0x0064, 0x0002])
        chip.raw(Cmd.STT)


def read_vcd(path: Path) -> tuple[float, dict[str, list[tuple[float, int]]]]:
    """(time unit in us, {signal: [(time us, level)...]}) of a 1-bit VCD as pyvcd writes it."""
    ids: dict[str, str] = {}
    changes: dict[str, list[tuple[float, int]]] = {}
    unit_us = 1e-3
    t = 0.0
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line.startswith("$timescale"):
                n, unit = line.split()[1:3]
                unit_us = int(n) * {"ns": 1e-3, "us": 1.0, "ps": 1e-6}[unit]
            elif line.startswith("$var"):
                _, _, _, ident, name = line.split()[:5]
                ids[ident] = name
                changes[name] = []
            elif line.startswith("#"):
                t = int(line[1:]) * unit_us
            elif line[:1] in ("0", "1") and line[1:] in ids:
                changes[ids[line[1:]]].append((t, int(line[0])))
    return unit_us, changes


def level_at(steps: list[tuple[float, int]], t: float) -> int:
    v = 1
    for ts, level in steps:
        if ts > t:
            break
        v = level
    return v


def panel(ax, changes: dict[str, list[tuple[float, int]]], annotations: list[Annotation],
          t0: float, t1: float, title: str) -> None:
    """One window of the capture: the lines, D0-D7 as a bus, then the decoder's rows."""
    import matplotlib.pyplot as plt

    shown = [a for a in annotations if a.end_us >= t0 and a.start_us <= t1]
    rows = len(LINES) + 1 + len(ROWS)
    y = rows
    labels = []
    for name in LINES:  # the control lines as square waves
        y -= 1
        steps = changes[name]
        ts = [t0] + [t for t, _ in steps if t0 < t < t1] + [t1]
        vs = [level_at(steps, t) for t in ts]
        ax.step(ts, [y + 0.15 + 0.6 * v for v in vs], where="post", color="#2c7fb8", lw=1)
        labels.append((y, "/" + name.upper()))
    y -= 1  # D0-D7 as one bus with its hex value between changes
    data = sorted({t for n in (f"d{i}" for i in range(8)) for t, _ in changes[n] if t0 < t < t1})
    edges = [t0, *data, t1]
    for e0, e1 in zip(edges, edges[1:]):
        value = sum(level_at(changes[f"d{i}"], e0) << i for i in range(8))
        ax.plot([e0, e1], [y + 0.15, y + 0.15], color="#555", lw=0.8)
        ax.plot([e0, e1], [y + 0.75, y + 0.75], color="#555", lw=0.8)
        ax.plot([e1, e1], [y + 0.15, y + 0.75], color="#555", lw=0.5)
        if e1 - e0 > (t1 - t0) / 60:
            ax.text((e0 + e1) / 2, y + 0.45, f"{value:02X}", ha="center", va="center", fontsize=7)
    labels.append((y, "D0-D7"))
    for name, colour in ROWS:
        y -= 1
        for a in (x for x in shown if x.row == name):
            a0, a1 = max(a.start_us, t0), min(a.end_us, t1)
            ax.add_patch(plt.Rectangle((a0, y + 0.1), a1 - a0, 0.8, facecolor=colour,
                                       edgecolor="#444", lw=0.5))
            width = (a1 - a0) / (t1 - t0)
            room = int(width * 16 * 110 / 6)  # characters that fit at fontsize 6.5
            text = a.text if len(a.text) <= room else a.text.split(":")[0]
            if room >= 3:
                ax.text((a0 + a1) / 2, y + 0.5, text if len(text) <= room else text[:room - 1]
                        + "…", ha="center", va="center", fontsize=6.5, clip_on=True)
        labels.append((y, name))
    ax.set_yticks([v + 0.5 for v, _ in labels], [n for _, n in labels], fontsize=8)
    ax.set_xlim(t0, t1)
    ax.set_ylim(0, rows)
    ax.set_title(title, fontsize=9, loc="left")
    for side in ("top", "right", "left"):
        ax.spines[side].set_visible(False)


def draw(vcd: Path, annotations: list[Annotation], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, changes = read_vcd(vcd)
    cmds = [a for a in annotations if a.row == "Commands"]
    first = next(a for a in cmds if a.text.startswith("LFIL"))
    last = next(a for a in cmds if a.text.startswith("STT"))
    ltrj = next(a for a in cmds if a.text.startswith("LTRJ"))
    ctrl = next(a for a in annotations if a.row == "Words" and a.start_us >= ltrj.start_us)
    fig, (top, zoom) = plt.subplots(2, 1, figsize=(16, 10), dpi=110)
    panel(top, changes, annotations, first.start_us - 2, last.end_us + 4,
          "LFIL + UDF as the driver sends them, then an LTRJ whose control word 002A announces "
          "six words and gets three: STT cuts it short (sim://, 8 MHz; time in us)")
    panel(zoom, changes, annotations, ctrl.start_us - 4, ctrl.end_us + 1.5,
          "zoom: the last busy polls before LTRJ's control word, and its two bytes (high first)")
    zoom.set_xlabel("simulated time (us): the chip model's strobes on its clock, drawn by "
                    "sim://?vcd=; annotations: sigrok-cli -P lm629")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("docs/debugging-decode.png"))
    ap.add_argument("--vcd", type=Path, default=None, help="Keep the VCD here.")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        vcd = args.vcd or Path(tmp) / "bus.vcd"
        capture(vcd)
        draw(vcd, decode(vcd), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
