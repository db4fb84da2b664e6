#!/usr/bin/env python3
"""Write ``firmware_bridge/golden_frames.txt``: link frames both codecs must agree on.

One line per frame: ``name<TAB>decoded-hex<TAB>encoded-hex`` (decoded = type, seq, payload,
CRC; encoded = COBS of it plus the 0x00 delimiter).  The Python tests
(``tests/transports/test_link_golden.py``) and the firmware's C tests read the same file; this script
makes it from the Python codec, and the Python test fails when file and codec drift apart.

    python3 tools/gen_golden_frames.py          # rewrite the file
    python3 tools/gen_golden_frames.py --check  # exit 1 when the file is stale
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lm629_host.bridge.protocol import (
    END_PAYLOAD,
    PROFILE_REPLY_PAYLOAD,
    ROW_HEADER,
    FrameType,
    HelloInfo,
    Result,
    RunReply,
    cobs_encode,
    encode_program,
    frame_body,
    FailsafeAction,
    FailsafeCmd,
    FailsafeState,
    profile_payload,
    record_payload,
    run_payload,
    short_reply_payload,
)
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import Program
from generated import write_or_check

OUT = Path(__file__).resolve().parent.parent / "firmware_bridge" / "golden_frames.txt"


def frames() -> list[tuple[str, bytes]]:
    """(name, decoded frame) pairs."""
    # AN-693 table 4, the filter programming module: LFIL, 0008 (kp only), 000A (kp=10), UDF
    an693 = Program().command(Cmd.LFIL).write(0x0008).write(0x000A).command(Cmd.UDF)
    # words with zero bytes inside, and a WAIT of 0x0100 us: COBS must stuff them all
    zeros = Program().command(Cmd.LPEI).write(0x0000).wait(0x0100).command(Cmd.RDSIGS).read(1)
    rdrp = Program().command(Cmd.RDRP).read(2)  # read_real_position(): -1000
    sample = Program().status().command(Cmd.RDDP).read(2).command(Cmd.RDRP).read(2)
    # the largest RUN: 81 WRITEs of 3 bytes = 243 program bytes -> 250-byte frame
    biggest = Program()
    for i in range(81):
        biggest.write((i * 0x0101) & 0xFF00)  # 0000, 0100, 0200...: zeros in every op
    info = HelloInfo(firmware=(1, 4, 0), capabilities=0x07FF, max_program=243, max_reads=120,
                     chip_selects=4, cpu_hz=16_000_000)
    return [
        ("hello", frame_body(FrameType.HELLO, 0x01)),
        ("hello_reply", frame_body(FrameType.HELLO_REPLY, 0x01, info.encode())),
        ("ping", frame_body(FrameType.PING, 0x02, b"\x00\x01\xfe\xff")),
        # FAILSAFE (capability FAILSAFE): arm 500 ms, abrupt; its reply (armed, no trip); the
        # feed a recording takes without ending (seq 0, no payload)
        ("failsafe_arm", frame_body(FrameType.FAILSAFE, 0x07, bytes((FailsafeCmd.ARM,))
                                    + (500).to_bytes(2, "big") + bytes((FailsafeAction.ABRUPT,)))),
        ("failsafe_reply_armed", frame_body(FrameType.FAILSAFE_REPLY, 0x07,
                                            FailsafeState(timeout_ms=500).encode())),
        ("failsafe_feed", frame_body(FrameType.FAILSAFE, 0x00)),
        ("pong", frame_body(FrameType.PONG, 0x02, b"\x00\x01\xfe\xff")),
        ("run_an693_filter", frame_body(FrameType.RUN, 0x2A, run_payload(an693.ops, 5000))),
        ("run_reply_an693_filter", frame_body(
            FrameType.RUN_REPLY, 0x2A, RunReply(Result.OK, 0xFF, 0xC0, 0, (), ()).encode())),
        ("run_zero_bytes", frame_body(FrameType.RUN, 0x00, run_payload(zeros.ops, 0))),
        ("run_reply_zero_bytes", frame_body(
            FrameType.RUN_REPLY, 0x00, RunReply(Result.OK, 0xFF, 0x00, 1, (), (0x0000,)).encode())),
        ("run_reply_busy_timeout", frame_body(
            FrameType.RUN_REPLY, 0x7F,
            RunReply(Result.BUSY_TIMEOUT, 3, 0x81, 0, (0xC4,), (0x1234,)).encode())),
        ("run_max_frame", frame_body(FrameType.RUN, 0xFE, run_payload(biggest.ops, 65535))),
        ("error_reply", frame_body(FrameType.ERROR_REPLY, 0x33, bytes((Result.BAD_REQUEST,)))),
        # a synchronized start on chips 1 and 2: the RUN starts on chip 1 (cs), SELECT 2
        ("run_sync_start", frame_body(FrameType.RUN, 0x11, run_payload(
            Program().command(Cmd.STT).select(2).command(Cmd.STT).ops, 5000, cs=1))),
        ("run_reply_sync_start", frame_body(
            FrameType.RUN_REPLY, 0x11, RunReply(Result.OK, 0xFF, 0xC4, 1, (), ()).encode())),
        # the compact form (capability COMPACT_RUN): the same AN-693 module; RDRP polling, its
        # reply in program order with the last status / HI byte (C0 with busy clear, HI 1 -> C1)
        ("run_short_an693_filter", frame_body(FrameType.RUN_SHORT, 0x2A, encode_program(an693.ops))),
        ("run_short_reply_an693_filter", frame_body(
            FrameType.RUN_SHORT_REPLY, 0x2A,
            short_reply_payload(an693.ops, RunReply(Result.OK, 0xFF, 0xC0, 0, (), ())))),
        ("run_short_rdrp", frame_body(FrameType.RUN_SHORT, 0x10, encode_program(rdrp.ops))),
        ("run_short_reply_rdrp", frame_body(
            FrameType.RUN_SHORT_REPLY, 0x10,
            short_reply_payload(rdrp.ops, RunReply(Result.OK, 0xFF, 0xC0, 1, (), (0xFFFF, 0xFC18))))),
        # programs kept under a code (capability PROGRAM_CODES): RDRP stored as code 3, then
        # run by its code; both answered as run_short_reply_rdrp (with their own seq)
        ("run_store_rdrp", frame_body(FrameType.RUN_STORE, 0x11,
                                      bytes((3,)) + encode_program(rdrp.ops))),
        ("run_code_rdrp", frame_body(FrameType.RUN_CODE, 0x12, bytes((3,)))),
        ("run_code_reply_rdrp", frame_body(
            FrameType.RUN_SHORT_REPLY, 0x12,
            short_reply_payload(rdrp.ops, RunReply(Result.OK, 0xFF, 0xC0, 1, (), (0xFFFF, 0xFC18))))),
        # SET_BAUD 1000000 (capability BAUD_SWITCH): made exactly, with divisor 2 and U2X
        ("set_baud_1m", frame_body(FrameType.SET_BAUD, 0x20, (1_000_000).to_bytes(4, "big"))),
        ("baud_reply_1m", frame_body(FrameType.BAUD_REPLY, 0x20,
                                     bytes((Result.OK,)) + (1_000_000).to_bytes(4, "big"))),
        ("run_reply_unknown_code", frame_body(
            FrameType.RUN_REPLY, 0x12, RunReply(Result.UNKNOWN_CODE, 0xFF, 0xFF, 0, (), ()).encode())),
        # RECORD (capability RECORD): status, RDDP, RDRP every 1000 us, 3 rows; a row (row 1,
        # 1000 us on the bridge's clock: C4, desired 1234h, real -2) and the end (3 rows sent)
        ("record_basic", frame_body(FrameType.RECORD, 0x30, record_payload(1000, 3, sample.ops))),
        ("record_row", frame_body(FrameType.RECORD_ROW, 0x30, ROW_HEADER.pack(1, 1000) + bytes(
            (0xC4, 0x00, 0x00, 0x12, 0x34, 0xFF, 0xFF, 0xFF, 0xFE)))),
        ("record_end", frame_body(FrameType.RECORD_END, 0x30,
                                  END_PAYLOAD.pack(Result.OK, 0xFF, 3))),
        ("record_end_bad_program", frame_body(FrameType.RECORD_END, 0x31,
                                              END_PAYLOAD.pack(Result.BAD_PROGRAM, 1, 0))),
        # PROFILE (capability PROFILE): a new schedule on chip 0, two pieces 20 ms apart
        # (1.25 and 0.64 counts/sample); its reply: nothing issued yet, two pending
        ("profile_two", frame_body(FrameType.PROFILE, 0x40, profile_payload(
            True, 0, [(20000, 0x00014000), (40000, 0x0000A3D7)]))),
        ("profile_reply_two", frame_body(FrameType.PROFILE_REPLY, 0x40,
                                         PROFILE_REPLY_PAYLOAD.pack(Result.OK, 0, 2, 0))),
    ]


def render() -> str:
    lines = ["# name<TAB>decoded-hex<TAB>encoded-hex  (made by tools/gen_golden_frames.py; "
             "read by tests/transports/test_link_golden.py and the firmware's C tests)"]
    for name, body in frames():
        lines.append(f"{name}\t{body.hex()}\t{(cobs_encode(body) + bytes(1)).hex()}")
    return "\n".join(lines) + "\n"


def main() -> int:
    return write_or_check(OUT, render(), sys.argv[1:], "tools/gen_golden_frames.py")


if __name__ == "__main__":
    sys.exit(main())
