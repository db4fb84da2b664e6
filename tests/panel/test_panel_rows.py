"""The panel's rows as velocities: what the velocity plot shows while an axis cruises.

The numbers (spec: a sample is 2048 clocks; RDDV is 16.16 counts/sample; RDRV is the integer
counts the encoder moved in the last sample): the page's default velocity word 65536 is
V = 1 count/sample, on the 8 MHz chip S = 256 us, V/S = 3906.25 counts/s.  Rows come 50 a
second (:data:`~lm629_host.panel.bench.SAMPLE_HZ`), about 78 samples apart.

At kp = 20 the 8-bit drive steps between two output codes (e = 51: 1020 >> 8 = 3, e = 52: 4),
so the shaft's speed ripples between about 3833 and 3958 counts/s and the encoder moves 0 or
2 counts in the odd sample: a row's RDRV read 0 about 0.38 s into every cruise, plotted as a
drop to 0 counts/s of an axis that never slowed (docs/panel-move.png before this test).  A
row's actual velocity is the counts the shaft covered since the previous row: the desired
position's counts (V a sample, to the one count its integer part drops), less what the
following error grew.  Settled, that is V/S within two counts a row interval (100 counts/s).
"""

from __future__ import annotations

import lm629_host
from lm629_host.bench.scope import feed
from lm629_host.bus.opcodes import Signals, Status
from lm629_host.bus.snapshot import Snapshot
from lm629_host.panel.bench import MAX_VELOCITY_SPAN_ROWS, SAMPLE_HZ, Rows
from panel_helpers import command, events, panel

S = 2048 / 8e6  # s a sample, 8 MHz
WORD = 65536  # the page's default velocity word: 1 count/sample
V_CPS = WORD / 65536 / S  # 3906.25 counts/s
#: settled: this long after the desired velocity reached V (the catch-up after the ramp is over)
SETTLE_S = 0.3


def _cruise(rows: list[list], axis: int = 0) -> tuple[list[tuple[list, list]], list[tuple[list, list]]]:
    """Pairs of consecutive rows both at the cruise's desired velocity: all of them, and the
    settled ones (SETTLE_S after the first row at V)."""
    o = 1 + 6 * axis
    at_v = round(V_CPS, 1)
    pairs = [(a, b) for a, b in zip(rows, rows[1:]) if a[o + 2] == b[o + 2] == at_v]
    assert pairs, "no row at the cruise's velocity"
    start = pairs[0][0][0]
    return pairs, [(a, b) for a, b in pairs if a[0] >= start + SETTLE_S]


def _check_cruise(rows: list[list], axis: int = 0) -> int:
    o = 1 + 6 * axis
    pairs, settled = _cruise(rows, axis)
    for a, b in pairs:
        dt = b[0] - a[0]
        grew = (b[o] - b[o + 1]) - (a[o] - a[o + 1])  # following error, counts
        # the shaft covered what the desired position did, less what the error grew
        assert abs(b[o + 3] * dt - V_CPS * dt) <= 1 + abs(grew) + 0.05 * dt, (a, b)
    for a, b in settled:
        dt = b[0] - a[0]
        assert abs(b[o + 3] - V_CPS) <= 2 / dt, (a, b)
    return len(settled)


def test_a_cruise_plots_its_speed_in_every_row():
    """The panel's rows of a recorded trapezoid on sim:// (far-side recording, the chip
    model's own registers), at the page's default velocity word: no row plots a speed the
    shaft did not have."""
    board = lm629_host.open_board("sim://")
    try:
        board.reset()
        axis = board.axes[0]
        axis.load_filter(kp=20)
        axis.update_filter()
        axis.sync()
        axis.load_trajectory(acceleration=655, velocity=WORD, position=8000, start=True)
        maker = Rows(S, SAMPLE_HZ)
        stream = feed(board, [0], SAMPLE_HZ, duration_s=2.0)
        rows = [maker.row(snaps) for snaps in stream]
    finally:
        board.close()
    assert rows[0][4] is None  # the first row has nothing to measure from
    assert _check_cruise(rows) >= 60  # 1.5 s and more of settled cruise, every row checked


def test_the_page_gets_the_cruise_speed_in_every_row():
    """The same through `lm629 --port sim:// panel`: the page's move, the rows its event
    stream sends (the worker's recording, restarted after the command)."""
    with panel("sim://") as p:
        token = p.page_token()
        with events(p, token) as stream:
            hello = next(stream)
            status, answer = command(p, token, {"cmd": "move", "target": "8000",
                                                "client": hello["client"]})
            assert answer["ok"], answer
            rows: list = []
            for m in stream:
                if m["type"] == "rows":
                    rows += m["rows"]
                    if rows[-1][1] == 8000:  # the desired position arrived: the cruise is over
                        break
    assert _check_cruise(rows) >= 60


def _snap(t: float, real: int) -> list[Snapshot]:
    return [Snapshot(Status(0), Signals(0), real, real, WORD, 1, 0, t)]


def test_a_row_across_the_registers_wrap_and_rows_too_far_apart():
    """The real position register runs round C0000000..3FFFFFFF (spec): 96 counts forward
    across its top in one 20 ms row are 4800 counts/s, not -2^31/0.02; a row more than
    MAX_VELOCITY_SPAN_ROWS periods after the previous one, or the first after a command
    (which may redefine positions: DFH), has no velocity (None: the page spans it)."""
    rows = Rows(S, SAMPLE_HZ)
    assert rows.row(_snap(1.0, 0x3FFFFFD0))[4] is None
    assert rows.row(_snap(1.02, -(1 << 30) + 0x30))[4] == 4800.0
    assert rows.row(_snap(1.04, -(1 << 30) + 0x30))[4] == 0.0
    late = 1.04 + (MAX_VELOCITY_SPAN_ROWS + 0.5) / SAMPLE_HZ
    assert rows.row(_snap(late, -(1 << 30) + 0x40))[4] is None
    assert rows.row(_snap(late + 0.02, -(1 << 30) + 0x41))[4] == 50.0
    rows.restart()
    assert rows.row(_snap(late + 0.04, 0))[4] is None
