"""Golden frame vectors (``firmware_bridge/golden_frames.txt``), shared with the firmware's C
tests: the Python codec must encode and decode every line exactly, and the file must be what
``tools/gen_golden_frames.py`` makes (so the two never drift apart)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from lm629_host.bridge.protocol import (
    MAX_FRAME,
    FrameError,
    FrameType,
    HelloInfo,
    Result,
    RunReply,
    cobs_decode,
    cobs_encode,
    crc16,
    decode_frame,
    decode_program,
    decode_short_reply,
    encode_frame,
)
from lm629_host.bridge.protocol.framing import _CRC_TABLE
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import BusOp, Op, Program

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "firmware_bridge" / "golden_frames.txt"


def golden() -> dict[str, tuple[bytes, bytes]]:
    out = {}
    for line in GOLDEN.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        name, dec, enc = line.split("\t")
        out[name] = (bytes.fromhex(dec), bytes.fromhex(enc))
    return out


def test_file_is_what_the_generator_makes():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_golden_frames.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("name", sorted(golden()))
def test_codec_round_trip(name):
    dec, enc = golden()[name]
    assert enc[-1] == 0 and 0 not in enc[:-1]
    assert cobs_encode(dec) + b"\x00" == enc
    assert cobs_decode(enc[:-1]) == dec
    f = decode_frame(enc)
    assert encode_frame(f.type, f.seq, f.payload) == enc
    assert crc16(dec[:-2]) == int.from_bytes(dec[-2:], "big") == f.crc


def test_crc_check_value():
    # the catalogue check value of CRC-16/GENIBUS
    assert crc16(b"123456789") == 0xD64E


def _crc16_bitwise(data: bytes) -> int:
    """CRC-16/GENIBUS bit by bit, as the catalogue defines it (poly 0x1021, init 0xFFFF, no
    reflection, xorout 0xFFFF): the reference the stdlib-based crc16 is held against."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc ^ 0xFFFF


def _crc16_table(data: bytes) -> int:
    """The firmware's way: the byte table that tools/gen_tables.py writes into lm629_tables.h."""
    crc = 0xFFFF
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[(crc >> 8) ^ b]
    return crc ^ 0xFFFF


def test_crc_equals_the_bitwise_definition_and_the_firmware_table():
    import random
    rng = random.Random(13)
    samples = [b"", b"\x00", b"\xff" * 3, bytes(range(256))]
    samples += [bytes(rng.randrange(256) for _ in range(rng.randrange(1, MAX_FRAME)))
                for _ in range(300)]
    for data in samples:
        assert crc16(data) == _crc16_bitwise(data) == _crc16_table(data), data.hex()


def test_a_delimiter_turned_into_01_fails_the_crc():
    """COBS decodes "frame, 0x01, 0x00" as the frame plus one 0x00 byte; with no final xor
    the CRC would accept it (the CRC of a message followed by its CRC is constant)."""
    wire = encode_frame(FrameType.RUN, 0x2A, b"\x00\x13\x88\x02\x0a\x04\x04")
    damaged = wire[:-1] + b"\x01\x00"
    assert cobs_decode(damaged[:-1]) == cobs_decode(wire[:-1]) + b"\x00"
    with pytest.raises(FrameError, match="CRC"):
        decode_frame(damaged)
    with pytest.raises(FrameError, match="CRC"):
        decode_frame(wire[:-1] + b"\x01\x01\x00")


def test_an693_filter_module_bytes():
    """AN-693 table 4: LFIL, 0008 (kp only), 000A (kp = 10), UDF, busy-checked each, as a RUN
    with seq 0x2A, cs 0 and a 5000 us busy timeout, byte for byte."""
    dec, _ = golden()["run_an693_filter"]
    assert dec[:2] == bytes((FrameType.RUN, 0x2A))
    assert dec[2:5] == bytes((0, 0x13, 0x88))  # cs 0, 5000 us big-endian
    assert dec[5:-2] == bytes((Op.COMMAND, Cmd.LFIL, Op.WRITE, 0x00, 0x08, Op.WRITE, 0x00, 0x0A,
                               Op.COMMAND, Cmd.UDF))
    assert decode_program(dec[5:-2]) == [BusOp(Op.COMMAND, 0x1E), BusOp(Op.WRITE, 8),
                                         BusOp(Op.WRITE, 10), BusOp(Op.COMMAND, 0x04)]


def test_replies_decode_to_their_fields():
    g = golden()
    info = HelloInfo.decode(decode_frame(g["hello_reply"][1]).payload)
    assert (info.protocol, info.firmware, info.capabilities, info.max_program, info.max_reads,
            info.chip_selects, info.cpu_hz) == (1, (1, 4, 0), 0x7FF, 243, 120, 4, 16_000_000)
    r = RunReply.decode(decode_frame(g["run_reply_busy_timeout"][1]).payload)
    assert (r.result, r.index, r.last_status, r.hi, r.statuses, r.words) == \
        (Result.BUSY_TIMEOUT, 3, 0x81, 0, (0xC4,), (0x1234,))
    rdrp = Program().command(Cmd.RDRP).read(2).ops
    f = decode_frame(g["run_short_reply_rdrp"][1])
    assert f.type == FrameType.RUN_SHORT_REPLY
    assert f.payload == bytes((0xFF, 0xFF, 0xFC, 0x18, 0xC1))  # words in order, C0 | HI
    r = decode_short_reply(f.payload, rdrp)
    assert (r.result, r.last_status, r.hi, r.statuses, r.words) == \
        (Result.OK, 0xC0, 1, (), (0xFFFF, 0xFC18))
    with pytest.raises(FrameError, match="expected 5"):
        decode_short_reply(f.payload[1:], rdrp)
    # the last status is the last STATUS read when the program ends with one, busy included
    st = Program().command(Cmd.RDRP).read(2).status().ops
    r = decode_short_reply(bytes((0, 1, 0, 2, 0x81, 0xC0)), st)
    assert (r.last_status, r.hi, r.statuses, r.words) == (0x81, 0, (0x81,), (1, 2))
    e = decode_frame(g["error_reply"][1])
    assert (e.type, e.payload) == (FrameType.ERROR_REPLY, bytes((Result.BAD_REQUEST,)))


def test_max_frame_is_max():
    dec, enc = golden()["run_max_frame"]
    assert len(dec) == MAX_FRAME
    assert len(enc) == MAX_FRAME + 2  # one COBS code byte per block here, plus the delimiter
    with pytest.raises(ValueError, match="MAX_FRAME"):
        encode_frame(FrameType.RUN, 0, dec[2:-2] + b"\x01")


def test_sync_start_bytes_and_the_python_bridge_answers_them():
    """RUN seq 0x11 starting on chip 1 (cs field), STT, SELECT 2, STT: the bytes of
    PROTOCOL.md, and the Python far end (four chip selects, SELECT) answers the golden reply,
    both STTs reaching their chips."""
    from lm629_host.sim.bridge import MULTI_AXIS_INFO, BridgeEmulator
    from lm629_host.sim.build import build_bus
    dec, wire = golden()["run_sync_start"]
    assert dec[2:5] == bytes((1, 0x13, 0x88))  # cs 1, 5000 us
    assert dec[5:-2] == bytes((Op.COMMAND, Cmd.STT, Op.SELECT, 2, Op.COMMAND, Cmd.STT))
    bus = build_bus("sim://?axes=3&record=1&strict=0")
    bus.advance(0.002)  # past power-on: status C4 with the breakpoint flag below
    for c in bus.chips:
        c.flags |= 0x40  # breakpoint level-held, as after reset + MSKI/RSTI (choice 19)
    emu = BridgeEmulator(bus, MULTI_AXIS_INFO)
    replies = emu.receive(wire)
    assert [c.history for c in bus.chips] == [[], [(0x01, ())], [(0x01, ())]]
    assert replies and decode_frame(replies[0]).payload == \
        decode_frame(golden()["run_reply_sync_start"][1]).payload



def test_record_frames_decode_to_their_fields():
    """RECORD: period 1000 us, 3 rows, status + RDDP + RDRP; a row carries its number, the
    bridge's clock in us and the bytes read in program order; the end says how many rows."""
    from lm629_host.bridge.protocol import END_PAYLOAD, RECORD_HEADER, ROW_HEADER
    g = golden()
    f = decode_frame(g["record_basic"][1])
    assert f.type == FrameType.RECORD == 0x08
    assert RECORD_HEADER.unpack_from(f.payload) == (1000, 3)
    assert decode_program(f.payload[6:]) == [
        BusOp(Op.STATUS), BusOp(Op.COMMAND, Cmd.RDDP), BusOp(Op.READ), BusOp(Op.READ),
        BusOp(Op.COMMAND, Cmd.RDRP), BusOp(Op.READ), BusOp(Op.READ)]
    row = decode_frame(g["record_row"][1])
    assert row.type == 0x88 and ROW_HEADER.unpack_from(row.payload) == (1, 1000)
    r = decode_short_reply(row.payload[6:] + b"\x00", decode_program(f.payload[6:]))
    assert r.statuses == (0xC4,) and r.words == (0x0000, 0x1234, 0xFFFF, 0xFFFE)
    end = decode_frame(g["record_end"][1])
    assert end.type == 0x89 and END_PAYLOAD.unpack(end.payload) == (Result.OK, 0xFF, 3)
