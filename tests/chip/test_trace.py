"""Bus trace: the callback of ``lm629_host.open(url, trace=...)`` and the DEBUG hex log."""

from __future__ import annotations

import logging

import lm629_host
from lm629_host.bus.program import Program, ProgramResult, cycles_of


def test_trace_kinds_and_values(open_chip, recorder):
    chip = open_chip("sim://")
    chip.reset()
    kinds = {c.kind for c in recorder.cycles}
    assert kinds == {"reset", "status", "command", "write"}
    recorder.clear()
    chip.read_real_position()
    assert recorder.data() == [("command", 0x0A), ("read", 0), ("read", 0)]
    assert all(0 <= c.value <= 0xFF for c in recorder.cycles if c.kind in ("status", "command"))


def test_debug_log_is_a_hex_trace(caplog):
    with caplog.at_level(logging.DEBUG, logger="lm629_host.bus"):
        with lm629_host.open("sim://") as chip:
            chip.load_filter(kp=10)
    lines = [r.getMessage() for r in caplog.records]
    assert "sim command 1E" in lines
    assert "sim write   0008" in lines and "sim write   000A" in lines


def test_cycles_of_reconstructs_a_far_side_program():
    p = Program().status().command(0x0A).read(2).command(0x1E).write(0x0008)
    r = ProgramResult(words=(0xFFFF, 0xFC18), statuses=(0xC0,))
    assert [(c.kind, c.value) for c in cycles_of(p, r)] == [
        ("status", 0xC0), ("command", 0x0A), ("read", 0xFFFF), ("read", 0xFC18),
        ("command", 0x1E), ("write", 0x0008)]
