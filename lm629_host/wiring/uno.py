"""THE pin map of the serial bridge: Arduino Uno/Nano pin -> ATmega328P port bit -> LM629 pin.

This is the one definition.  ``tools/gen_tables.py`` writes it into
``firmware_bridge/lm629_tables.h`` for the firmware, the simavr harness
(:mod:`lm629_host.sim.avr`) wires the simulated chip to the same port bits, and docs/bridge.md's
wiring table and drawing are generated from it (:mod:`lm629_host.wiring.connections`,
``tools/gen_wiring.py``; a test checks they are current).

Why this layout:

* PD0/PD1 are the UART (the USB serial link) and PB6/PB7 hold the crystal, so no 8-bit port is
  free: the data bus D0-D5 sits on PD2-PD7 (Uno D2-D7) and D6-D7 on PB0-PB1 (Uno D8-D9).  A byte
  goes out as ``PORTD = byte << 2`` plus ``PORTB = byte >> 6`` (two masked writes) and comes in
  as ``PIND >> 2 | PINB << 6``;
* every control line sits on port C (Uno A0-A5), so each strobe edge is one port write that
  touches nothing else; /CS and /PS change before the strobe falls (their setup time);
* HI is an input on PC5 (A5), read once after each program.

Several chips (a multi-axis board): they share D0-D7, /PS, /RD, /WR and /RST; each has its own
/CS.  The pins left over are PB2-PB5 (Uno D10-D13), so chip 0 keeps /CS on A0 (a one-chip
board is wired the same either way) and chips 1-3 take /CS on D10, D11, D12 (``/CS1``..``/CS3`` in the
table: the /CS pin of that chip); D13 takes HI of chip 1.  Chips 2 and 3 have no HI line (the
host reads their status instead).  Four chip selects on an Uno/Nano.  D11-D13 are also the
ISP header's MOSI/MISO/SCK: disconnect the chips (or hold them in reset) while flashing over
ISP; the USB bootloader does not use them.  On a Nano D13 carries the LED and its resistor to
ground, a load on HI1 that a TTL output drives without trouble.

A chip select on port B is held low by the firmware for the stretch of a program that
addresses that chip (the chip ignores /CS without a strobe; D6-D7 share port B, written masked),
so its setup time before every strobe is long met.

Put 10 kOhm pull-ups on /CS, /RD, /WR and /RST: while the AVR is in reset (the Uno resets when
the port opens) its pins float, and the pull-ups keep the chip deselected and out of reset.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PinWire:
    """One wire between the Arduino and the LM629."""

    board_pin: str  #: label on the Uno / Nano header
    port: str  #: ATmega328P port letter
    bit: int  #: bit in that port
    chip_pin: str  #: LM628/LM629 pin name
    direction: str  #: "out" (driven by the AVR), "in" (read by the AVR), "io" (data bus)


#: D0-D7 of the chip, in bit order
DATA: tuple[PinWire, ...] = (
    PinWire("D2", "D", 2, "D0", "io"),
    PinWire("D3", "D", 3, "D1", "io"),
    PinWire("D4", "D", 4, "D2", "io"),
    PinWire("D5", "D", 5, "D3", "io"),
    PinWire("D6", "D", 6, "D4", "io"),
    PinWire("D7", "D", 7, "D5", "io"),
    PinWire("D8", "B", 0, "D6", "io"),
    PinWire("D9", "B", 1, "D7", "io"),
)
CS = PinWire("A0", "C", 0, "/CS", "out")
PS = PinWire("A1", "C", 1, "/PS", "out")
RD = PinWire("A2", "C", 2, "/RD", "out")
WR = PinWire("A3", "C", 3, "/WR", "out")
RST = PinWire("A4", "C", 4, "/RST", "out")
HI = PinWire("A5", "C", 5, "HI", "in")

CONTROL: tuple[PinWire, ...] = (CS, PS, RD, WR, RST, HI)
CS1 = PinWire("D10", "B", 2, "/CS1", "out")
CS2 = PinWire("D11", "B", 3, "/CS2", "out")
CS3 = PinWire("D12", "B", 4, "/CS3", "out")
HI1 = PinWire("D13", "B", 5, "HI1", "in")
#: /CS of chip 0, 1, 2, 3 (the RUN's ``cs`` and ``Op.SELECT`` index this)
CHIP_SELECTS: tuple[PinWire, ...] = (CS, CS1, CS2, CS3)
#: HI of each chip, where it has a pin (None: read the status instead)
HI_LINES: tuple[PinWire | None, ...] = (HI, HI1, None, None)
#: the wires of chips 1-3
AXES: tuple[PinWire, ...] = (CS1, CS2, CS3, HI1)
#: every wire, data bus first (docs/bridge.md's wiring table lists these, plus GND)
WIRING: tuple[PinWire, ...] = DATA + CONTROL + AXES

#: data bus bits 0..5 sit on port D from bit DATA_LOW_SHIFT up; bits 6..7 on port B bits 0..1
DATA_LOW_PORT, DATA_LOW_SHIFT, DATA_LOW_MASK = "D", 2, 0xFC
DATA_HIGH_PORT, DATA_HIGH_SHIFT, DATA_HIGH_MASK = "B", 6, 0x03
CONTROL_PORT = "C"


def _check() -> None:
    """The shifts above must describe :data:`DATA` (one fact, two spellings, checked here)."""
    for i, w in enumerate(DATA):
        if i < 6:
            assert w.port == DATA_LOW_PORT and w.bit == i + DATA_LOW_SHIFT, w
        else:
            assert w.port == DATA_HIGH_PORT and w.bit == i - DATA_HIGH_SHIFT, w
    for w in CONTROL:
        assert w.port == CONTROL_PORT, w
    for w in CHIP_SELECTS + tuple(h for h in HI_LINES if h):
        assert w.port in (CONTROL_PORT, DATA_HIGH_PORT), w  # the firmware's two masks
    assert len(HI_LINES) == len(CHIP_SELECTS)
    used = {(w.port, w.bit) for w in WIRING}
    assert len(used) == len(WIRING), "two wires on one port bit"
    assert not used & {("D", 0), ("D", 1), ("B", 6), ("B", 7)}, "UART or crystal pin used"


_check()


def mask(*wires: PinWire) -> int:
    """Port bit mask of ``wires`` (all on one port)."""
    return sum(1 << w.bit for w in wires)


def split_byte(value: int) -> tuple[int, int]:
    """A data byte as (port D bits, port B bits), as the firmware writes it."""
    return ((value << DATA_LOW_SHIFT) & DATA_LOW_MASK, (value >> DATA_HIGH_SHIFT) & DATA_HIGH_MASK)


def join_byte(port_low: int, port_high: int) -> int:
    """The data byte seen on (port D, port B)."""
    return (((port_low & DATA_LOW_MASK) >> DATA_LOW_SHIFT)
            | ((port_high & DATA_HIGH_MASK) << DATA_HIGH_SHIFT))


def port_masks(wires: tuple[PinWire | None, ...], port: str) -> list[int]:
    """For each wire (one per chip), its bit mask on ``port`` (0: elsewhere or no wire)."""
    return [(1 << w.bit) if w is not None and w.port == port else 0 for w in wires]


__all__ = ["PinWire", "DATA", "CONTROL", "WIRING", "CS", "PS", "RD", "WR", "RST", "HI", "mask",
           "CS1", "CS2", "CS3", "HI1", "CHIP_SELECTS", "HI_LINES", "AXES", "port_masks",
           "split_byte", "join_byte"]
