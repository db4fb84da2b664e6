"""The LM629's DIP pin map against the references it was taken from, pin by pin.

The table below is written out by hand from the sources, not computed: an edit of
``lm629_host.bus.pinout`` that disagrees with them (the data bus reversed again, say) fails here
until this table is changed too, with a source for the change.
"""

from __future__ import annotations

from lm629_host.wiring.connections import connections, extras
from lm629_host.bus.pinout import DIP, PIN, pin_of

#: pin -> line.  Sources:
#: - the LM629 symbol of a built, working two-LM629 board: slgrobotics/Misc,
#:   KiCad/LM629Driver/LM629Driver.net (libpart LM629: pins 1 IN, 2 A, 3 B, 4 D7, 5 D6, 6 D5,
#:   7 D4, 8 D3, 9 D2, 10 D1, 11 D0, 12 CS, 13 RD, 14 GND, 15 WR, 16 PS, 17 HI, 18 PWM_SIGN,
#:   19 PWM_MAG, 26 CLK, 27 RST, 28 VDD).  Its nets agree: ATmega328P pin 18 (PB4, the
#:   board's bus bit 0) goes to pin 11 of both LM629s, ATmega pin 11 (PD5, bit 7) to pin 4;
#: - the datasheet's connection diagram (DS009219 / SNVS781, 28-lead DIP), as recorded in
#:   the project's chip reference, shared/spec/lm628-lm629-reference.md ("DIP-28 pin numbers"): the same list, and
#:   pins 20-25 not connected on the LM629.
REFERENCE = {
    1: "IN", 2: "A", 3: "B",
    4: "D7", 5: "D6", 6: "D5", 7: "D4", 8: "D3", 9: "D2", 10: "D1", 11: "D0",
    12: "/CS", 13: "/RD", 14: "GND", 15: "/WR", 16: "/PS", 17: "HI",
    18: "PWM SIGN", 19: "PWM MAG",
    20: "NC", 21: "NC", 22: "NC", 23: "NC", 24: "NC", 25: "NC",
    26: "CLK", 27: "/RST", 28: "VDD",
}


def test_every_pin_matches_the_reference():
    assert len(REFERENCE) == 28
    for n, line in REFERENCE.items():
        assert DIP[n] == line, f"pin {n}: pinout.py says {DIP[n]}, the reference {line}"
        if line != "NC":
            assert PIN[line] == n and pin_of(line) == n
    assert set(DIP) == set(REFERENCE)


def test_the_data_bus_runs_down_the_dip():
    """D0 at the bottom of the data pins: bit i is pin 11 - i (the board's bit 0 on pin 11)."""
    assert [pin_of(f"D{i}") for i in range(8)] == [11, 10, 9, 8, 7, 6, 5, 4]


def test_every_adapter_wires_bit_i_to_pin_11_minus_i():
    """What a user wires from: the Uno's/Nano's D2+i and the FT232H's ACBUSi carry bit i
    (their pin maps), so each must land on pin 11 - i; the pull-ups' line is the range."""
    for adapter, pin_of_bit in (("uno", lambda i: f"D{i + 2}"), ("nano", lambda i: f"D{i + 2}"),
                                ("ft232h", lambda i: f"ACBUS{i}")):
        data = {c.adapter_pin: c.chip_pin for c in connections(adapter)
                if c.chip_line[0] == "D" and c.chip_line[1:].isdigit()}
        assert data == {pin_of_bit(i): 11 - i for i in range(8)}, adapter
        assert ("+5 V (optional)", "D0-D7 (pins 4-11)") in [r[:2] for r in extras(adapter)]
