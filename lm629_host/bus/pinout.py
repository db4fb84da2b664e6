"""The LM628/LM629's 28-pin DIP: which pin is which line (the one place for the pin numbers;
the wiring table, the drawing and the wiring check's messages take them from here).

From the datasheet's connection diagram (DS009219 / SNVS781, the N and M packages share it);
AN-706 names pins 17 (HI), 18/19 (PWM sign and magnitude) and 27 (/RST) in its text.  On the
LM628 pins 18-25 are the DAC output port instead of the PWM outputs and unused pins.

The data bus runs downwards: D7 is pin 4 and D0 pin 11.  A built, working two-LM629 board
(slgrobotics/Misc, ``KiCad/LM629Driver/LM629Driver.net``) confirms it: its netlist names the
LM629's pins 4..11 D7..D0 and wires the ATmega's bus bit 0 to pin 11, and its logged run reads
the datasheet's status bytes bit for bit.  ``tests/wiring/test_pinout.py`` holds the reference table.
"""

from __future__ import annotations

#: pin number -> line name (LM629)
DIP: dict[int, str] = {
    1: "IN", 2: "A", 3: "B",
    **{4 + i: f"D{7 - i}" for i in range(8)},  # D7 on pin 4 down to D0 on pin 11
    12: "/CS", 13: "/RD", 14: "GND", 15: "/WR", 16: "/PS", 17: "HI",
    18: "PWM SIGN", 19: "PWM MAG",
    **{n: "NC" for n in range(20, 26)},
    26: "CLK", 27: "/RST", 28: "VDD",
}
#: line name -> pin number (the NC pins left out)
PIN: dict[str, int] = {name: n for n, name in DIP.items() if name != "NC"}


def pin_of(line: str) -> int:
    """The DIP pin of an LM629 line (``"D5"`` -> 6, ``"/RST"`` -> 27)."""
    return PIN[line]


__all__ = ["DIP", "PIN", "pin_of"]
