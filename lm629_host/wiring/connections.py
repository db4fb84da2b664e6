"""The wires between an adapter and the LM629(s), as rows with the physical pin at both ends.

Generated from the pin maps (:mod:`lm629_host.wiring.uno` for the Uno/Nano bridge,
:mod:`lm629_host.wiring.ft232h` for the FT232H) and the DIP pinout (:mod:`lm629_host.bus.pinout`):
``lm629 wiring`` prints them, ``lm629 wiring --svg`` draws them, docs/bridge.md and
docs/ftdi.md hold the Markdown made by :func:`markdown` (``tools/gen_wiring.py`` writes it, a
test checks it is current), and the wiring check names the adapter's pin of a suspect line with
:func:`adapter_pin`.
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.wiring import ft232h as ftdi_pins
from lm629_host.wiring import uno as bridge_pins
from lm629_host.bus.pinout import pin_of

#: the adapters there is a pin map for (the Nano has the Uno's header labels and ATmega328P)
ADAPTERS = ("uno", "nano", "ft232h")
#: the most chips each adapter wires (its chip selects)
MAX_AXES = {"uno": len(bridge_pins.CHIP_SELECTS), "nano": len(bridge_pins.CHIP_SELECTS),
            "ft232h": len(ftdi_pins.CHIP_SELECTS)}
#: the lines that get a 10 kOhm pull-up to +5 V (both pin maps' docstrings say why)
PULLED_UP = frozenset({"/CS", "/RD", "/WR", "/RST"})


@dataclass(frozen=True)
class Connection:
    """One wire: the adapter's pin (header label and what it is inside the adapter) to a pin of
    one LM629 (``chip``: 0 for chip 0 and for the lines all chips share)."""

    adapter_pin: str  #: Uno/Nano header label (``D7``) or FT232H line (``ADBUS1``)
    adapter_detail: str  #: ATmega328P port bit (``PD7``) or the FT232H breakout label (``D1``)
    chip_line: str  #: LM629 line (``D5``, ``/CS``)
    chip: int  #: which chip: 0, or the axis of a /CS or HI of its own
    shared: bool  #: the line goes to every chip (data bus, /PS, /RD, /WR, /RST)
    direction: str  #: seen from the adapter: "in/out", "out", "in"
    note: str = ""

    @property
    def chip_pin(self) -> int:
        """The LM629 DIP pin number."""
        return pin_of(self.chip_line)

    @property
    def pull_up(self) -> bool:
        return self.chip_line in PULLED_UP

    @property
    def chip_label(self) -> str:
        """``D5 (pin 6)``, ``/CS (pin 12) of chip 1``."""
        where = f" of chip {self.chip}" if self.chip else ""
        return f"{self.chip_line} (pin {self.chip_pin}){where}"


def _bridge(axes: int) -> list[Connection]:
    out: list[Connection] = []
    direction = {"io": "in/out", "out": "out", "in": "in"}
    shared = bridge_pins.DATA + (bridge_pins.PS, bridge_pins.RD, bridge_pins.WR, bridge_pins.RST)
    for w in shared:
        out.append(Connection(w.board_pin, f"P{w.port}{w.bit}", w.chip_pin, 0, True,
                              direction[w.direction]))
    for k in range(axes):
        cs = bridge_pins.CHIP_SELECTS[k]
        out.append(Connection(cs.board_pin, f"P{cs.port}{cs.bit}", "/CS", k, False, "out"))
        hi = bridge_pins.HI_LINES[k]
        if hi is not None:
            out.append(Connection(hi.board_pin, f"P{hi.port}{hi.bit}", "HI", k, False, "in"))
    return out


def _ftdi_line(mask: int) -> int:
    return mask.bit_length() - 1


def _ft232h(axes: int, busy_pin: bool = False) -> list[Connection]:
    out = [Connection(f"ACBUS{i}", f"C{i}", f"D{i}", 0, True, "in/out") for i in range(8)]
    for mask, line in ((ftdi_pins.PS, "/PS"), (ftdi_pins.RD, "/RD"), (ftdi_pins.WR, "/WR"),
                       (ftdi_pins.RST, "/RST")):
        n = _ftdi_line(mask)
        out.append(Connection(f"ADBUS{n}", f"D{n}", line, 0, True, "out"))
    for k in range(axes):
        n = _ftdi_line(ftdi_pins.CHIP_SELECTS[k])
        out.append(Connection(f"ADBUS{n}", f"D{n}", "/CS", k, False, "out"))
        hi = ftdi_pins.HI_LINES[k]
        if hi and not busy_pin:
            n = _ftdi_line(hi)
            out.append(Connection(f"ADBUS{n}", f"D{n}", "HI", k, False, "in",
                                  "GPIOL1" if n == 5 else ""))
    if busy_pin:  # D0 also to GPIOL1 (ftdi_pins.BUSY_PINS); HI has no line left
        n = _ftdi_line(ftdi_pins.BUSY_PINS["gpiol1"])
        out.append(Connection(f"ADBUS{n}", f"D{n}", "D0", 0, True, "in",
                              "GPIOL1, besides C0: busy during a held status read; "
                              "HI (pin 17) not connected"))
    return out


def connections(adapter: str, axes: int = 1, busy_pin: bool = False) -> list[Connection]:
    """Every wire from ``adapter`` to ``axes`` chips (GND and supplies apart), data bus first.
    ``busy_pin``: the FT232H wired for ``busy_pin=gpiol1`` (D0 also on ADBUS5, HI off it).
    ValueError for an unknown adapter or more axes than it has chip selects."""
    adapter = adapter.lower()
    if adapter not in ADAPTERS:
        raise ValueError(f"adapter {adapter!r}: expected one of {', '.join(ADAPTERS)}")
    if not 1 <= axes <= MAX_AXES[adapter]:
        raise ValueError(f"--axes {axes}: the {adapter} wiring has 1..{MAX_AXES[adapter]} "
                         "chip selects")
    if busy_pin and adapter != "ft232h":
        raise ValueError(f"busy_pin: only the FT232H waits on a pin, not the {adapter}")
    return _ft232h(axes, busy_pin) if adapter == "ft232h" else _bridge(axes)


def adapter_name(adapter: str) -> str:
    """``Uno``, ``Nano``, ``FT232H``: how a message names the adapter."""
    return {"uno": "Uno", "nano": "Nano", "ft232h": "FT232H"}[adapter.lower()]


def adapter_pin(adapter: str, chip_line: str, chip: int = 0) -> str:
    """The adapter's pin wired to ``chip_line`` of ``chip``: ``Uno D7``, ``FT232H ACBUS5 (C5)``."""
    for c in connections(adapter, MAX_AXES[adapter.lower()]):
        if c.chip_line == chip_line and (c.shared or c.chip == chip):
            name = adapter_name(adapter)
            if adapter.lower() == "ft232h":
                return f"{name} {c.adapter_pin} (breakout {c.adapter_detail})"
            return f"{name} {c.adapter_pin}"
    raise ValueError(f"the {adapter} wiring has no wire to {chip_line} of chip {chip}")


def extras(adapter: str) -> list[tuple[str, str, str]]:
    """The wires that are not signals: (adapter side, LM629 side, note)."""
    rows = [("GND", f"GND (pin {pin_of('GND')})", "common ground")]
    if adapter.lower() == "ft232h":
        rows.append(("ADBUS0 (D0)", "-", "TCK: toggled by the delays, leave unconnected"))
    rows.append(("+5 V", "/CS, /RD, /WR, /RST of every chip", "10 kOhm pull-up each"))
    data = sorted(pin_of(f"D{i}") for i in range(8))  # a range of pins: D7 is the lowest
    rows.append(("+5 V (optional)", f"D0-D7 (pins {data[0]}-{data[-1]})",
                 "10 kOhm pull-ups: an open data wire then reads 1, which the wiring check finds"))
    return rows


def table_rows(adapter: str, axes: int = 1,
               busy_pin: bool = False) -> list[tuple[str, str, str, str, str]]:
    """(adapter pin, port bit or breakout label, LM629 pin, direction, note) for every wire."""
    rows = []
    for c in connections(adapter, axes, busy_pin):
        notes = [n for n in (c.note, "10k pull-up" if c.pull_up else "",
                             "all chips" if c.shared and axes > 1 else "") if n]
        rows.append((c.adapter_pin, c.adapter_detail, c.chip_label, c.direction, "; ".join(notes)))
    return rows


def headers(adapter: str) -> tuple[str, str, str, str, str]:
    if adapter.lower() == "ft232h":
        return ("FT232H line", "breakout label", "LM629 pin", "direction", "note")
    return (f"{adapter_name(adapter)} pin", "ATmega328P port bit", "LM629 pin",
            "direction (AVR side)", "note")


def markdown(adapter: str, axes: int | None = None, busy_pin: bool = False) -> str:
    """The wiring table as Markdown (every chip select the adapter has, unless ``axes``)."""
    n = MAX_AXES[adapter.lower()] if axes is None else axes
    lines = ["| " + " | ".join(headers(adapter)) + " |", "|---|---|---|---|---|"]
    for row in table_rows(adapter, n, busy_pin):
        lines.append("| " + " | ".join(row) + " |")
    for a, b, note in extras(adapter):
        lines.append(f"| {a} |  | {b} |  | {note} |")
    return "\n".join(lines) + "\n"


def text_table(adapter: str, axes: int = 1) -> str:
    """The wiring table as aligned plain text, for the terminal."""
    rows = [headers(adapter), *table_rows(adapter, axes)]
    rows += [(a, "", b, "", note) for a, b, note in extras(adapter)]
    widths = [max(len(r[i]) for r in rows) for i in range(5)]
    out = []
    for k, r in enumerate(rows):
        out.append("  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip())
        if k == 0:
            out.append("  ".join("-" * w for w in widths))
    return "\n".join(out) + "\n"


__all__ = ["ADAPTERS", "Connection", "MAX_AXES", "PULLED_UP", "adapter_name", "adapter_pin",
           "connections", "extras", "headers", "markdown", "table_rows", "text_table"]
