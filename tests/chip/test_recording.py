"""Recording on the far side: ``LM629.record`` -> ``Trace``.

The figures: the chip samples every 2048 clocks (256 us at 8 MHz), so 1 ms holds 3.906 samples:
a move at 4 counts/sample advances the desired position by 3 or 4 samples' worth, 12 or 16
counts, between two rows 1 ms apart.  The bridge's clock ticks every 4 us (Timer1 at clk/64),
its due times are exact multiples of the period: rows 1000 us apart, give or take a tick.
"""

from __future__ import annotations

import math

import pytest

import lm629_host
from lm629_host import LM629
from lm629_host.errors import ArgumentError, TransportError
from lm629_host.bridge.protocol import Capability, FrameType, HelloInfo, Result, decode_frame
from lm629_host.bus.opcodes import Cmd, s32
from lm629_host.sim.bridge import MULTI_AXIS_INFO
from lm629_host.sim.faults import FaultPipe
from lm629_host.transports.session import FEED_SEQ
from lm629_host.errors import LinkError
from lm629_host.transports.simemu import open_emulated

#: 4 counts per sample (16.16)
FULL_SPEED = 4 * 65536


def _moving(url: str) -> LM629:
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20, kd=200)
    chip.update_filter()
    chip.move_to(100_000, velocity=FULL_SPEED, acceleration=6553)  # full speed after ~10 ms
    chip.clock.sleep(0.05)
    return chip


def _check_done_when(tr) -> None:
    assert 495 <= len(tr) <= 505
    spacing = [b - a for a, b in zip(tr.t, tr.t[1:])]
    on_time = sum(1 for d in spacing if abs(d - 1e-3) <= 20e-6)
    assert on_time >= 0.99 * len(spacing), sorted(spacing)[:3] + sorted(spacing)[-3:]
    assert max(spacing) <= 2.5e-3
    steps = [b - a for a, b in zip(tr.desired, tr.desired[1:])]
    # at full speed (15.6 counts a row): never back, 12-20 counts a row
    assert set(steps) <= set(range(12, 21)), sorted(set(steps))
    assert tr.t[0] == 0.0 and not tr.missing


@pytest.mark.parametrize("url", ["sim://", "sim+emu://?fast_baud=1000000"])
def test_record_during_a_move(url):
    chip = _moving(url)
    with chip:
        before = chip.transport.stats.round_trips
        tr = chip.record(1e-3, 0.5)
        _check_done_when(tr)
        assert tr.far_side
        if url.startswith("sim+emu"):
            assert chip.transport.stats.round_trips - before == 1  # one exchange, rows streamed
            assert chip.transport.emulator.stats.rows == 500


def test_record_during_a_move_on_the_firmware(firmware_built):
    chip = _moving("sim+avr://?fast_baud=1000000")
    with chip:
        before = chip.transport.stats.round_trips
        tr = chip.record(1e-3, 0.5)
        _check_done_when(tr)
        assert chip.transport.stats.round_trips - before == 1
        assert chip.transport.info.firmware >= (1, 3, 0)
        # the line is quiet after it: the next command is answered at once, no retry
        assert chip.read_desired_position() >= tr.desired[-1]
        assert chip.transport.stats.retries == 0


def test_full_rows_hold_a_snapshot():
    """At full speed (4 counts/sample, the 16.16 word 262144) rows 2 ms apart are 7.8125
    samples apart: the desired position advances 7 or 8 samples' worth, 28 or 32 counts; ki is
    0, so the integration sum stays 0; the motor follows behind, the following error positive.
    A row's snapshot holds each of the row's registers in its own field."""
    chip = _moving("sim+emu://?fast_baud=1000000")
    with chip:
        tr = chip.record(2e-3, 0.02, full=True)
        assert len(tr) == 10
        assert {b - a for a, b in zip(tr.desired, tr.desired[1:])} <= {28, 32}
        for r in tr:
            assert r.real_velocity in (3, 4, 5) and r.desired_velocity == FULL_SPEED
            assert r.integration_sum == 0 and r.signals is not None
            s = r.snapshot(t0=10.0)
            assert (s.status, s.signals, s.desired_position, s.real_position,
                    s.desired_velocity, s.real_velocity, s.integration_sum) == (
                r.status, r.signals, r.desired, r.real, FULL_SPEED, r.real_velocity, 0)
            assert s.time == pytest.approx(10.0 + r.t)
            assert s.following_error == r.desired - r.real > 0


def test_a_rate_the_line_cannot_carry_names_the_highest(firmware_built):
    """At 115200 baud a basic row (9 bytes read + 10 of frame + COBS code and delimiter: 21
    bytes, at 11 bits a byte 2005 us) plus its bus time (2 commands x 25 us + 5 reads x 4 us)
    with 10 % to spare: 0.9 / 2075 us = 433 rows/s."""
    for url in ("sim+emu://?baud=115200", "sim+avr://?baud=115200"):
        with lm629_host.open(url) as chip:
            stats = chip.transport.stats
            before = stats.round_trips, stats.bytes_out
            with pytest.raises(ValueError, match=r"highest rate is 433 rows/s"):
                chip.record(1e-3, 0.5)
            assert (stats.round_trips, stats.bytes_out) == before  # nothing sent
            tr = chip.record(1 / 433, 0.1)
            assert len(tr) == 43 and not tr.missing
            spacing = [b - a for a, b in zip(tr.t, tr.t[1:])]
            assert all(abs(d - 1 / 433) <= 4e-6 for d in spacing)  # one 4 us tick


def test_a_sample_program_that_writes_is_refused_before_any_traffic():
    with lm629_host.open("sim+emu://") as chip:
        t = chip.transport
        before = t.stats.bytes_out
        for p in (chip.program().command(Cmd.STT), chip.program().command(Cmd.RDRP).read(2).wait(5)):
            with pytest.raises(ValueError, match="not a sample program"):
                list(t.record_rows(p, 1e-3, 3))
        assert t.stats.bytes_out == before


@pytest.mark.parametrize("period,duration,argument,lo,hi", [
    (0, 1, "period_s", None, None), (-1e-3, 1, "period_s", None, None),
    (math.inf, 1, "period_s", None, None), (math.nan, 1, "period_s", None, None),
    (True, 1, "period_s", None, None),
    # duration_s from one period to 65535 of them (RECORD counts rows in 16 bits): at 1 ms,
    # 0.001..65.535 s
    (1e-3, 5e-4, "duration_s", 1e-3, 65.535), (1e-3, math.nan, "duration_s", 1e-3, 65.535),
    (1e-3, math.inf, "duration_s", 1e-3, 65.535), (1e-3, -1.0, "duration_s", 1e-3, 65.535),
    (1e-3, 100.0, "duration_s", 1e-3, 65.535)])
def test_bad_arguments_are_argument_errors_naming_the_range(period, duration, argument, lo, hi):
    with lm629_host.open("sim+emu://") as chip:
        with pytest.raises(ArgumentError) as e:
            chip.record(period, duration)
        assert chip.transport.stats.round_trips == 0  # before any bus cycle
    assert e.value.argument == argument
    assert e.value.value is (duration if argument == "duration_s" else period)
    message = str(e.value)
    assert message.startswith(f"{argument}=") and "finite number of seconds" in message
    if argument == "period_s":
        assert "above 0" in message
    else:
        assert e.value.lo == pytest.approx(lo) and e.value.hi == pytest.approx(hi)
        assert "in 0.001..65.535" in message


def test_a_lost_row_is_a_gap_never_a_value():
    """Rows dropped and damaged on the way to the host: every row the trace holds is exactly the
    row the bridge sent under its index, every other index is in ``missing``."""
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    chip.move_to(100_000, velocity=FULL_SPEED, acceleration=6553)
    sent: dict[int, bytes] = {}  # row number -> the RECORD_ROW payload the bridge sent
    emu = t.emulator
    step = emu.record_step

    def spy():
        out = step()
        f = decode_frame(out[0])
        if f.type == FrameType.RECORD_ROW:
            sent[int.from_bytes(f.payload[:2], "big")] = f.payload
        return out
    emu.record_step = spy  # type: ignore[method-assign]  # a spy on what the bridge sends
    t.pipe = FaultPipe(t.pipe, drop=0.003, corrupt=0.003, seed=7, to_bridge=False)
    tr = chip.record(1e-3, 0.5)
    assert tr.missing, "no row met a fault: raise the rates"
    assert len(tr) + len(tr.missing) == 500
    first = tr.rows[0].index
    for r in tr:
        p = sent[r.index]
        assert p[6] == r.status
        assert (s32(int.from_bytes(p[7:11], "big")), s32(int.from_bytes(p[11:15], "big"))) == \
            (r.desired, r.real)
        assert r.t == pytest.approx((r.index - first) * 1e-3, abs=4e-6)
    assert sum(n for _, n in tr.gaps) == len(tr.missing)


def test_rows_lost_at_the_end_are_missing_up_to_the_rows_asked():
    """The line towards the host breaks after row 399 of a 500-row recording (every byte from
    the bridge lost from then on; the bridge records on): the trace ends with row 399 when the
    recording's time is up, and rows 400..499 -- asked for, never received -- are missing, one
    gap of 100."""
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    fp = FaultPipe(t.pipe, seed=1, to_bridge=False)  # a line towards the host, healthy so far
    t.pipe = fp
    try:
        with chip.record_stream(1e-3, 0.5) as stream:
            for row in stream:
                if row.index == 399:
                    fp.into.rates.drop = 1.0  # the cable breaks
    finally:  # closed here, not left to the interpreter's exit (which says it cannot stop it)
        t.close()
    tr = stream.trace()
    assert tr.asked == 500
    assert [r.index for r in tr] == list(range(400))
    assert tr.missing == list(range(400, 500)) and tr.gaps == [(400, 100)]


def test_rows_lost_anywhere_are_missing_counted_from_row_0():
    """A noisy line towards the host (1 % of the bytes lost, ten seeds): whatever a seed's
    losses hit, the trace's missing rows are exactly the indices 0..19 it does not hold --
    counted from row 0, the first rows included when they are lost -- and ``t`` counts from
    the first row held."""
    for seed in range(10):
        t = open_emulated("sim://", baud=1_000_000)
        chip = LM629(t)
        chip.reset()
        t.pipe = FaultPipe(t.pipe, drop=0.01, seed=seed, to_bridge=False)
        try:
            tr = chip.record(1e-3, 0.02)
        except TransportError as exc:  # the losses took the end of the recording too: the
            tr = exc.trace  # rows that came ride on the error
        got = [r.index for r in tr]
        assert tr.missing == [k for k in range(20) if k not in got], seed
        assert all(r.t == pytest.approx((r.index - got[0]) * 1e-3, abs=4e-6) for r in tr)


def test_gaps_on_the_firmware(firmware_built):
    t = lm629_host.open("sim+avr://?fast_baud=1000000").transport
    chip = LM629(t)
    with chip:
        chip.reset()
        chip.move_to(100_000, velocity=FULL_SPEED, acceleration=6553)
        chip.clock.sleep(0.05)
        t.pipe = FaultPipe(t.pipe, drop=0.003, corrupt=0.003, seed=3, to_bridge=False)
        tr = chip.record(1e-3, 0.3)
        assert tr.missing and len(tr) + len(tr.missing) == 300
        first = tr.rows[0]
        for r in tr:
            assert r.t == pytest.approx((r.index - first.index) * 1e-3, abs=4e-6)
            # no value made up: the desired position moves 12..16 counts a period, gaps included
            n = r.index - first.index
            assert 12 * n <= r.desired - first.desired <= 16 * n + 4


def test_a_lost_request_is_sent_again():
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    fp = FaultPipe(t.pipe, seed=1, to_host=False)
    t.pipe = fp
    fp.out.rates.drop = 1.0  # the first RECORD never arrives
    original = t.pipe.write

    def write_then_heal(data):
        original(data)
        fp.out.rates.drop = 0.0
    t.pipe.write = write_then_heal  # type: ignore[method-assign]  # heal the line after one write
    tr = chip.record(1e-3, 0.01)
    assert len(tr) == 10 and t.stats.retries == 1 and t.emulator.stats.recordings == 1


def test_a_damaged_first_row_sends_the_record_again_with_a_new_seq():
    """The first row of a RECORD arrives damaged: like any request whose reply was bad, it is
    sent again at once, with a new seq (RECORD is never answered from the cache); the new
    frame's first byte stops the first recording, whose rows (the old seq) are ignored.  The
    trace is the second recording's, whole."""
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    emu = t.emulator
    step = emu.record_step
    seqs: list[int] = []  # the seq of every row the bridge sent, in order
    sent: dict[int, bytes] = {}  # row number -> the last RECORD_ROW payload sent under it

    def damage_the_first_row():
        out = step()
        f = decode_frame(out[0])
        if f.type == FrameType.RECORD_ROW:
            seqs.append(f.seq)
            sent[int.from_bytes(f.payload[:2], "big")] = f.payload
            if len(seqs) == 1:
                frame = bytearray(out[0])
                k = len(frame) // 2
                frame[k] ^= 0x40 if frame[k] != 0x40 else 0x20  # a COBS byte, never 0
                out[0] = bytes(frame)
        return out
    emu.record_step = damage_the_first_row  # type: ignore[method-assign]  # the line's damage
    bad = t.bad_frames
    tr = chip.record(1e-3, 0.01)
    assert [r.index for r in tr] == list(range(10)) and not tr.missing
    assert t.stats.retries == 1 and emu.stats.recordings == 2 and t.bad_frames == bad + 1
    second = seqs[-1]
    # one new seq for the one retry: the next after the first's, past the failsafe feed's
    # (the session starts at a random seq: from 255 the next is 1, as CI once drew)
    expected = (seqs[0] + 1) & 0xFF
    assert second == (expected + 1 if expected == FEED_SEQ else expected), (seqs[0], second)
    assert seqs.count(second) == 10  # every row kept is the second recording's
    for r in tr:
        assert s32(int.from_bytes(sent[r.index][7:11], "big")) == r.desired


def test_an_unanswered_record_gives_up_then_resynchronises():
    """RECORD lost every time: one LinkError after ``retries + 1`` attempts, each a new seq,
    saying the line is the suspect; the next call first resynchronises (HELLO), then runs."""
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    fp = FaultPipe(t.pipe, seed=1, to_host=False)
    t.pipe = fp
    fp.out.rates.drop = 1.0
    t._seq = seq0 = 0x10  # clear of seq 0, which the host skips (the failsafe feed's)
    with pytest.raises(LinkError) as e:
        chip.record(1e-3, 0.01)
    assert e.value.may_have_run
    assert f"no answer to RECORD after {t.retries + 1} attempt(s)" in str(e.value)
    assert f"{t.retries + 1} of the last" in str(e.value) and "Check the USB cable" in str(e.value)
    assert t.stats.retries == t.retries and (t._seq - seq0) & 0xFF == t.retries + 1
    emu = t.emulator
    assert emu.stats.recordings == 0
    fp.out.rates.drop = 0.0
    frames, runs = emu.stats.frames, emu.stats.runs
    assert chip.read_desired_position() == 0
    assert (emu.stats.frames - frames, emu.stats.runs - runs) == (2, 1)  # HELLO, then the RUN


def test_a_record_refused_with_an_error_reply_says_so():
    """A bridge that answers RECORD with ERROR_REPLY (host and firmware disagree): one
    TransportError naming RECORD and the code, no retry."""
    t = open_emulated("sim://", baud=1_000_000)
    chip = LM629(t)
    chip.reset()
    emu = t.emulator

    def refuse(frame):
        return emu._error(frame.seq, Result.BAD_REQUEST)
    emu._start_recording = refuse  # type: ignore[method-assign]  # a bridge that refuses RECORD
    with pytest.raises(TransportError, match=rf"refused RECORD \(ERROR_REPLY, code {int(Result.BAD_REQUEST)}\)"):
        chip.record(1e-3, 0.01)
    assert t.stats.retries == 0


def test_a_stream_closed_early_stops_the_bridge():
    chip = _moving("sim+emu://?fast_baud=1000000")
    with chip:
        emu = chip.transport.emulator
        with chip.record_stream(1e-3) as rows:
            got = [r for r, _ in zip(rows, range(20))]
        assert [r.index for r in got] == list(range(20))
        sent = emu.stats.rows
        assert 20 <= sent <= 22 and emu.record_due is None
        assert chip.read_desired_position() >= got[-1].desired
        assert chip.transport.stats.retries == 0
        chip.clock.sleep(0.1)
        assert emu.stats.rows == sent  # stopped: nothing more comes


def test_an_old_bridge_is_polled_by_the_host_and_says_so():
    """A bridge without RECORD (firmware 1.2): the host polls, one exchange a row, stamped with
    the host's clock; at 115200 baud an exchange takes ~1.9 ms, so slots it misses are gaps."""
    info = HelloInfo(firmware=(1, 2, 0), chip_selects=4,
                     capabilities=MULTI_AXIS_INFO.capabilities & ~Capability.RECORD)
    t = open_emulated("sim://", baud=115200)
    t.emulator.info = info
    t.hello()
    chip = LM629(t)
    assert not t.records_on_far_side and "host" in t.record_note()
    tr = chip.record(1e-3, 0.05)
    assert not tr.far_side
    assert tr.missing and len(tr) + len(tr.missing) == 50
    assert t.emulator.stats.recordings == 0


def test_watch_and_step_record_on_the_far_side(tmp_path):
    """``lm629 watch`` and ``lm629 step`` on a bridge with RECORD: the rows are the bridge's,
    exactly a period apart on its clock (a host-polled row at 1 Mbaud would be ~0.4 ms late)."""
    import csv

    from click.testing import CliRunner

    from lm629_host.cli import main
    url = "sim+emu://?fast_baud=1000000"
    out = tmp_path / "w.csv"
    r = CliRunner().invoke(main, ["--port", url, "watch", "--rate", "500", "--count", "5",
                                  "--csv", str(out)])
    assert r.exit_code == 0, r.output
    t = [float(x["t_s"]) for x in csv.DictReader(out.open())]
    assert [round(b - a, 6) for a, b in zip(t, t[1:])] == [0.002] * 4
    out = tmp_path / "s.csv"
    r = CliRunner().invoke(main, ["--port", url, "step", "300", "--kp", "20", "--kd", "100",
                                  "--csv", str(out), "--no-png", "--time", "0.05"])
    assert r.exit_code == 0, r.output
    t = [float(x["t_s"]) for x in csv.DictReader(out.open())]
    assert len(t) == 51  # the snapshot before the move, then 50 rows 1 ms apart
    assert [round(b - a, 6) for a, b in zip(t[1:], t[2:])] == [0.001] * 49


@pytest.mark.parametrize("firmware", [False, True])
def test_record_over_a_pty_to_sim_serve(tmp_path, firmware, request):
    """``lm629 sim serve`` (real time, pyserial on a pty): the rows run at their times on the
    served bridge (the Python one, or the compiled firmware) and reach the host in bunches, as
    behind a USB adapter; their stamps are the bridge's, due an exact period apart."""
    from lm629_host.sim.serve import SimServer

    if firmware:
        request.getfixturevalue("firmware_built")
    srv = SimServer(tmp_path / "lm629", "sim://", firmware=firmware)
    with srv.start():
        with lm629_host.open(f"serial://{srv.link}") as chip:
            chip.reset()
            assert chip.transport.records_on_far_side
            tr = chip.record(2e-3, 0.2)
            assert len(tr) == 100 and not tr.missing
            # the due times never drift (an exact multiple of the period from the first row);
            # a row's stamp is when its sampling started: on the firmware a 4 us tick or two
            # after its due time when a UART interrupt (a feed from the host, the last row
            # going out) held its loop just then (CI saw a step off by more than one tick,
            # beside two CPU hogs)
            late_us = [round((t - tr.t[0] - k * 2e-3) * 1e6, 1) for k, t in enumerate(tr.t)]
            assert all(0 <= x <= 12 for x in late_us), late_us
            assert chip.read_real_position() == 0  # a quiet line after it


def test_the_ft232h_polls_from_the_host_and_says_so():
    """No timer beside the chip on an FT232H: the base class's host polling, stamped by the
    host, and ``record_note`` says what that costs."""
    from sim_urls import available
    if not available("sim+ftdi://"):
        pytest.skip("sim+ftdi:// not available here")
    with lm629_host.open("sim+ftdi://") as chip:
        chip.reset()
        t = chip.transport
        assert not t.records_on_far_side and t.record_max_rate(chip.program()) is None
        assert "one exchange each" in t.record_note() and "gap" in t.record_note()
        tr = chip.record(1e-3, 0.02)
        assert not tr.far_side and len(tr) + len(tr.missing) == 20


def test_a_recording_without_a_finite_duration_or_below_one_sample_is_refused():
    """record() ends by itself: None or inf is an ArgumentError (record_stream runs until
    closed).  The chip's registers change once a sample, 2048 / 8 MHz = 256 us: a period below
    it is an ArgumentError whose lower bound is that sample time."""
    with lm629_host.open("sim://") as chip:
        chip.reset()
        for duration in (None, math.inf):
            with pytest.raises(ArgumentError) as info:
                chip.record(1e-3, duration)
            assert info.value.argument == "duration_s"
        with pytest.raises(ArgumentError) as info:
            chip.record(100e-6, 0.01)
        assert info.value.argument == "period_s" and info.value.lo == pytest.approx(256e-6)
        assert "below the chip's sample time 256 us" in str(info.value)
        tr = chip.record(256e-6, 0.0256)  # exactly one sample apart: 100 rows, none missing
        assert len(tr) == 100 and tr.missing == []


def test_a_link_that_dies_during_a_recording_raises_with_the_rows_so_far(tmp_path):
    """A served bench stopped 0.3 s into a 2 s recording at 1 ms: record() raises a
    TransportError, and the rows that came (some, fewer than the 2000 asked) are its .trace."""
    import threading

    from lm629_host.errors import TransportError
    from lm629_host.sim.serve import SimServer
    srv = SimServer(tmp_path / "bench", "sim://").start()
    try:
        with lm629_host.open(srv.client_url) as chip:
            chip.reset()
            threading.Timer(0.3, srv.close).start()
            with pytest.raises(TransportError) as info:
                chip.record(1e-3, 2.0)
    finally:
        srv.close()
    rows = info.value.trace.rows
    assert 0 < len(rows) < 2000 and rows[-1].index < 1999


@pytest.mark.parametrize("url, advice", [("sim+emu://?fast_baud=115200", True),
                                         ("sim+emu://?fast_baud=1000000&usb=uno", False)])
def test_a_rate_the_line_cannot_carry_suggests_a_faster_line_only_where_there_is_one(url, advice):
    """3333 rows/s of the three columns: above 433 rows/s at 115200 baud and 2990 at 1 Mbaud
    (docs/python.md): refused either way; fast_baud=1000000 is advice only below it."""
    with lm629_host.open(url) as chip:
        chip.reset()
        with pytest.raises(ValueError) as info:
            chip.record(300e-6, 0.05)
    assert "the highest rate is" in str(info.value)
    assert ("a faster line (fast_baud=1000000)" in str(info.value)) == advice
