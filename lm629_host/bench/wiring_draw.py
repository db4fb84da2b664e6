"""The wiring drawn: the adapter, the LM629's 28-pin DIP (top view) and every wire, labelled
on both ends, with the 10 kOhm pull-ups; plain SVG written by hand (no dependency).

``lm629 wiring --svg FILE`` writes it (``--png FILE`` through rsvg-convert or cairosvg when
one is installed); docs/bridge.md and docs/ftdi.md show the ones ``tools/gen_wiring.py``
writes into docs/.  Every position comes from :mod:`lm629_host.wiring.connections` and
:mod:`lm629_host.bus.pinout`: nothing here knows which pin is which.

Layout: the adapter's pins on the left, one row per wire; the DIP on the right with pins 1-14
down its left side and 15-28 up its right side, as seen from above.  The rows: the lines to
the DIP's left side in pin order, each a straight line level with its pin, except the data
bus, which keeps the adapter's bit order (D0 at the top, as the adapter's port runs) in the
band of the data pins, so that its wires cross over in a band of their own between the
adapter and the chip (the DIP numbers its data pins the other way); then the lines to its
right side in pin order, each passing under the chip and up to its pin; then the lines of the
other chips, as labelled stubs.  A pulled-up line has a dot and a 10 kOhm resistor to a +5 V
flag in its own row.
"""

from __future__ import annotations

import shutil
import subprocess
from html import escape
from pathlib import Path

from lm629_host.wiring.connections import Connection, adapter_name, connections
from lm629_host.bus.pinout import DIP, pin_of

ROW = 30  #: vertical pitch of the adapter's rows and of the DIP's pins
TOP = 150  #: y of the first row and of pin 1
ADAPTER_X, ADAPTER_W = 40, 230
CHIP_X, CHIP_W = 690, 130
#: where data wires that change rows cross over (first slant's start, each slant's width, the
#: step between rows): clear of the labels at both ends, the line's name after the adapter and
#: the adapter's pin before the chip
CROSS_X0, CROSS_W, CROSS_STEP = ADAPTER_X + ADAPTER_W + 100, 160, 6

COLORS = {"data": "#1f5fbf", "strobe": "#c0392b", "cs": "#d35400", "rst": "#8e44ad",
          "hi": "#1e8449", "gnd": "#222222"}


def _is_data(c: Connection) -> bool:
    """A data bus line (D0-D7)."""
    return c.chip_line[:1] == "D" and c.chip_line[1:].isdigit()


def _color(c: Connection) -> str:
    if _is_data(c):
        return COLORS["data"]
    if c.chip_line == "/CS":
        return COLORS["cs"]
    if c.chip_line == "/RST":
        return COLORS["rst"]
    if c.chip_line == "HI":
        return COLORS["hi"]
    if c.chip_line == "GND":
        return COLORS["gnd"]
    return COLORS["strobe"]


def _pin_xy(n: int) -> tuple[float, float, int]:
    """Where pin ``n``'s stub ends (x, y) and which way it points (-1: left, +1: right)."""
    if n <= 14:
        return CHIP_X - 20, TOP + (n - 1) * ROW, -1
    return CHIP_X + CHIP_W + 20, TOP + (28 - n) * ROW, 1


def _text(x: float, y: float, s: str, *, size: int = 13, anchor: str = "start",
          color: str = "#000", weight: str = "normal") -> str:
    return (f'<text x="{x:.0f}" y="{y:.0f}" font-size="{size}" text-anchor="{anchor}" '
            f'fill="{color}" font-weight="{weight}">{escape(s)}</text>')


def _line(points: list[tuple[float, float]], color: str, width: float = 2.2) -> str:
    d = " ".join(f"{x:.0f},{y:.0f}" for x, y in points)
    return (f'<polyline points="{d}" fill="none" stroke="{color}" stroke-width="{width}" '
            'stroke-linejoin="round"/>')


def _dot(x: float, y: float, color: str) -> str:
    return f'<circle cx="{x:.0f}" cy="{y:.0f}" r="4" fill="{color}"/>'


def render(adapter: str, axes: int = 1) -> str:
    """The drawing as SVG text."""
    wires = connections(adapter, axes)
    gnd = Connection("GND", "", "GND", 0, True, "")
    mine = [w for w in wires if w.chip == 0] + [gnd]
    # rows: the DIP's left-side pins in pin order (each wire a straight line to its pin), then
    # its right-side pins in pin order (each an L under the chip, none crossing another), then
    # the lines of the other chips
    left = sorted((w for w in mine if pin_of(w.chip_line) <= 14), key=lambda w: pin_of(w.chip_line))
    right = sorted((w for w in mine if pin_of(w.chip_line) > 14), key=lambda w: pin_of(w.chip_line))
    first = pin_of(left[0].chip_line)
    # the data bus in bit order within the rows of its pins, wherever the DIP puts each bit
    slots = [k for k, w in enumerate(left) if _is_data(w)]
    for k, w in zip(slots, sorted((left[k] for k in slots), key=lambda w: int(w.chip_line[1:]))):
        left[k] = w
    others = [w for w in wires if w.chip != 0]
    rows = left + right + others
    row_y = [TOP + (first - 1 + i) * ROW for i in range(len(rows))]
    name = adapter_name(adapter)
    ft = adapter.lower() == "ft232h"
    ax = ADAPTER_X + ADAPTER_W
    ux0 = CHIP_X + CHIP_W + 50
    height = row_y[-1] + 150
    width = ux0 + len(right) * 18 + 150
    out: list[str] = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" font-family="DejaVu Sans, Arial, sans-serif">',
        f'<rect width="{width}" height="{height}" fill="#ffffff"/>',
        _text(ADAPTER_X, 36, f"{name} to LM629 wiring" + (f" ({axes} axes)" if axes > 1 else ""),
              size=20, weight="bold"),
        _text(ADAPTER_X, 58, "generated by `lm629 wiring --svg` from lm629_host/"
              + ("ftdi_pins.py" if ft else "bridge/pins.py") + " and pinout.py; "
              "the DIP seen from above, pin 1 top left", size=12, color="#555"),
    ]
    # the adapter
    a_top, a_bottom = row_y[0] - 2 * ROW, row_y[-1] + ROW
    out.append(f'<rect x="{ADAPTER_X}" y="{a_top}" width="{ADAPTER_W}" height="{a_bottom - a_top}" '
               'rx="10" fill="#e8f1e4" stroke="#2e6b2e" stroke-width="2"/>')
    label = "FT232H breakout" if ft else f"Arduino {name}"  # the MCU on the next line: fits the box
    out.append(_text(ADAPTER_X + 12, a_top + 22, label, size=14, weight="bold", color="#2e6b2e"))
    out.append(_text(ADAPTER_X + 12, a_top + 40, "line (breakout label)" if ft
                     else "ATmega328P: header pin (port bit)", size=11, color="#2e6b2e"))
    # the DIP
    out.append(f'<rect x="{CHIP_X}" y="{TOP - 24}" width="{CHIP_W}" height="{13 * ROW + 48}" '
               'rx="6" fill="#2b2b2b"/>')
    out.append(f'<path d="M {CHIP_X + CHIP_W / 2 - 12} {TOP - 24} a 12 12 0 0 0 24 0" '
               'fill="#ffffff"/>')
    out.append(_text(CHIP_X + CHIP_W / 2, TOP + 6 * ROW, "LM629", size=18, anchor="middle",
                     color="#ffffff", weight="bold"))
    out.append(_text(CHIP_X + CHIP_W / 2, TOP + 6 * ROW + 20, "28-pin DIP", size=11,
                     anchor="middle", color="#cccccc"))
    used = {w.chip_line for w in mine}
    for n, line in DIP.items():
        x, y, side = _pin_xy(n)
        stub_in = CHIP_X if side < 0 else CHIP_X + CHIP_W
        out.append(_line([(x, y), (stub_in, y)], "#777777", 3))
        inner = stub_in + 6 if side < 0 else stub_in - 6
        out.append(_text(inner, y + 4, line, size=11, anchor="start" if side < 0 else "end",
                         color="#ffffff" if line in used else "#9a9a9a"))
        num_x = x + 2 if side < 0 else x - 2
        out.append(_text(num_x, y - 5, str(n), size=10, anchor="start" if side < 0 else "end",
                         color="#555555"))
    k_right = 0
    for w, y in zip(rows, row_y):
        color = _color(w)
        out.append(_dot(ax, y, color))
        inside = f"{w.adapter_pin}" + (f"  ({w.adapter_detail})" if w.adapter_detail else "")
        out.append(_text(ax - 10, y + 4, inside, size=13, anchor="end", weight="bold"))
        if w.chip != 0:  # a line to another chip: a labelled stub
            out.append(_line([(ax, y), (ax + 120, y)], color))
            pull = " (10k pull-up to +5 V)" if w.pull_up else ""
            out.append(_text(ax + 126, y + 4, f"to {w.chip_label}{pull}", size=12, color=color,
                             weight="bold"))
            continue
        n = pin_of(w.chip_line)
        px, py, side = _pin_xy(n)
        if side < 0 and y == py:  # level with its pin
            pts = [(ax, y), (px, py)]
        elif side < 0:  # across the band where the bus turns over, each row's slant a step
            # further right, so that the crossings spread out instead of meeting in one point
            x0 = CROSS_X0 + (y - row_y[0]) / ROW * CROSS_STEP
            pts = [(ax, y), (x0, y), (x0 + CROSS_W, py), (px, py)]
        else:
            ux = ux0 + k_right * 18
            k_right += 1
            pts = [(ax, y), (ux, y), (ux, py), (px, py)]
        out.append(_line(pts, color))
        out.append(_text(ax + 8, y - 5, f"{w.chip_line} (pin {n})", size=11, color=color,
                         weight="bold"))
        end_label = "GND" if w.chip_line == "GND" else (
            f"{w.adapter_pin} ({w.adapter_detail})" if ft else w.adapter_pin)
        if side < 0:  # just before the pin, above the wire
            out.append(_text(px - 8, py - 5, end_label, size=11, anchor="end", color=color,
                             weight="bold"))
        else:  # level with the pin, right of every wire that passes there
            out.append(_text(ux0 + len(right) * 18, py + 4, end_label, size=11, color=color,
                             weight="bold"))
        if w.pull_up:  # a local +5 V flag through a 10k resistor, in the row's own band
            jx = ax + 150
            out.append(_dot(jx, y, color))
            out.append(_line([(jx, y), (jx, y + 13), (jx + 8, y + 13)], color, 1.5))
            out.append(f'<rect x="{jx + 8}" y="{y + 8}" width="30" height="10" fill="#ffffff" '
                       f'stroke="{color}" stroke-width="1.6"/>')
            out.append(_line([(jx + 38, y + 13), (jx + 48, y + 13)], color, 1.5))
            out.append(_text(jx + 52, y + 17, "10k to +5 V", size=10, color="#c0392b",
                             weight="bold"))
    foot = height - 80
    notes = [
        "Each wire: the LM629 line and pin next to the adapter, the adapter pin next to the chip.",
        "10 kOhm pull-ups to +5 V on /CS, /RD, /WR and /RST; a dot is a connection.",
        f"Also: VDD (pin {pin_of('VDD')}) to +5 V, CLK (pin {pin_of('CLK')}) from a 6-8 MHz "
        "oscillator, the encoder on A/B/IN (pins 1-3), the amplifier on PWM (pins 18/19).",
    ]
    if ft:
        notes.append("Leave ADBUS0 (D0, TCK) unconnected: the MPSSE clock toggles it.")
    for k, text in enumerate(notes):
        out.append(_text(ADAPTER_X, foot + k * 17, text, size=12, color="#333"))
    out.append("</svg>")
    return "\n".join(out) + "\n"


def write_svg(path: str | Path, adapter: str, axes: int = 1) -> Path:
    p = Path(path)
    p.write_text(render(adapter, axes))
    return p


NO_RENDERER = ("no SVG renderer found for --png: install rsvg-convert (sudo apt-get install "
               "librsvg2-bin) or cairosvg (pip install cairosvg), or write --svg and open it in "
               "a browser")


def png_renderer() -> str | None:
    """What can turn the SVG into PNG here: ``rsvg-convert``, ``cairosvg``, or None."""
    if shutil.which("rsvg-convert"):
        return "rsvg-convert"
    try:
        import cairosvg  # noqa: F401 - only asked whether it is there
    except ImportError:
        return None
    return "cairosvg"


def write_png(path: str | Path, adapter: str, axes: int = 1) -> Path:
    """The drawing as PNG; RuntimeError saying what to install when nothing can render it."""
    svg = render(adapter, axes)
    tool = png_renderer()
    p = Path(path)
    if tool == "rsvg-convert":
        subprocess.run(["rsvg-convert", "-f", "png", "-o", str(p)], input=svg.encode(),
                       check=True)
    elif tool == "cairosvg":
        import cairosvg
        cairosvg.svg2png(bytestring=svg.encode(), write_to=str(p))
    else:
        raise RuntimeError(NO_RENDERER)
    return p


__all__ = ["NO_RENDERER", "png_renderer", "render", "write_png", "write_svg"]
