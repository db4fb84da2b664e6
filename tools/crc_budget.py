#!/usr/bin/env python3
"""Error-detection budget of the bridge link (PROTOCOL.md "Error detection"): what the
16-bit CRC lets through for the frames the link really sends, under the fault model of the
soak (``sim.faults.FaultPipe``: each byte dropped, corrupted or duplicated at ``--rate`` each).

A stream of real frames (RUN requests and RUN_REPLYs of SBPA and RDRP, and the largest frame,
250 bytes) goes through the fault model into the host's own FrameReader.  Every frame that
comes out damaged is classified:

* stopped before the CRC (COBS framing, length, frame too short/long): CRC not needed;
* a same-length frame whose damage is one burst of at most 16 bits: CRC-16 detects every such
  error (a property of any 16-bit CRC), and for poly 0x1021 also every 1-3 bit error (Hamming
  distance 4 up to 32751 bits: Koopman's tables);
* the rest reached the CRC with damage it is not guaranteed to see: it passes with probability
  about 2^-16 each (a CRC is a uniform hash over the remaining error patterns).  A RUN_REPLY
  whose length is not the one its program asks for is rejected by the host whatever its CRC
  (``LinkTransport._run``), so for replies only the same-length rest counts ("rest, =len").

That count x 2^-16, per damaged frame, is the expected rate of undetected frames.  The model is checked by
the same run with the CRC cut to its low 8 bits: the damaged frames that then pass are counted,
and they should be about "the rest" x 2^-8.

Run:  python3 tools/crc_budget.py [--rate 0.01] [--frames 200000] [--seed 1]
"""

from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lm629_host.bridge.protocol import (
    FrameType,
    MAX_FRAME,
    RunReply,
    cobs_decode,
    crc16,
    encode_frame,
    encode_program,
    run_payload,
    short_reply_payload,
)
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import BusOp, Op


def frames() -> list[tuple[str, bytes]]:
    sbpa_ops = [BusOp(Op.COMMAND, int(Cmd.SBPA)), BusOp(Op.WRITE, 0x0001), BusOp(Op.WRITE, 0x2345)]
    rdrp_ops = [BusOp(Op.COMMAND, int(Cmd.RDRP)), BusOp(Op.READ), BusOp(Op.READ)]
    sbpa = run_payload(sbpa_ops, 5000)
    rdrp = run_payload(rdrp_ops, 5000)
    big = run_payload([BusOp(Op.WRITE, 0x1234 + i) for i in range(81)], 5000)
    return [
        ("SBPA request", encode_frame(FrameType.RUN, 0x41, sbpa)),
        ("RDRP request", encode_frame(FrameType.RUN, 0x42, rdrp)),
        ("SBPA reply", encode_frame(FrameType.RUN_REPLY, 0x41, RunReply(last_status=0x80).encode())),
        ("RDRP reply", encode_frame(FrameType.RUN_REPLY, 0x42,
                                    RunReply(last_status=0x80, words=(0, 1234)).encode())),
        (f"largest ({MAX_FRAME} bytes)", encode_frame(FrameType.RUN, 0x43, big)),
        # the compact frames (RUN_SHORT, programs kept under codes): what a poll sends now
        ("SBPA RUN_SHORT", encode_frame(FrameType.RUN_SHORT, 0x44, encode_program(sbpa_ops))),
        ("RDRP RUN_CODE", encode_frame(FrameType.RUN_CODE, 0x45, bytes((3,)))),
        ("RDRP short reply", encode_frame(FrameType.RUN_SHORT_REPLY, 0x45, short_reply_payload(
            rdrp_ops, RunReply(last_status=0x80, words=(0, 1234))))),
    ]


def mangle(data: bytes, rate: float, rng: random.Random) -> bytes:
    out = bytearray()
    for b in data:
        x = rng.random()
        if x < rate:
            continue  # dropped
        if x < 2 * rate:
            out.append(b ^ rng.randrange(1, 256))
        elif x < 3 * rate:
            out += bytes((b, b))
        else:
            out.append(b)
    return bytes(out)


def single_burst(a: bytes, b: bytes) -> bool:
    """Same length and all differing bits within 16 consecutive bit positions."""
    if len(a) != len(b):
        return False
    x = int.from_bytes(a, "big") ^ int.from_bytes(b, "big")
    if x == 0:
        return True
    low = (x & -x).bit_length() - 1
    return x.bit_length() - low <= 16 or bin(x).count("1") <= 3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate", type=float, default=0.01, help="per-byte rate of each fault")
    ap.add_argument("--frames", type=int, default=200_000, help="frames of each kind sent")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    print(f"rate {args.rate} per byte for each of drop, corrupt, duplicate "
          f"({300 * args.rate:g} % of bytes changed); {args.frames} frames of each kind")
    print(f"{'frame':22} {'wire':>4} {'damaged':>8} {'stopped':>8} {'burst<=16':>9} "
          f"{'rest':>7} {'rest, =len':>10} {'P(undetected)/damaged':>22} "
          f"{'8-bit: seen/predicted':>22}")
    for name, wire in frames():
        body = cobs_decode(wire[:-1])
        damaged = stopped = burst = rest = rest_same = weak_pass = 0
        reply = wire in (w for n, w in frames() if "reply" in n)
        for _ in range(args.frames // 2):
            # two copies back to back, so that a lost delimiter runs one frame into the next
            # (COBS then decodes both as one frame with a zero between: it reaches the CRC)
            got = mangle(wire + wire, args.rate, rng)
            pieces = got.split(b"\x00")
            pieces = pieces[:-1]  # the bytes after the last delimiter wait for the next frame
            for p in pieces:
                if not p:
                    continue  # an empty piece: a spare delimiter, ignored by the reader
                try:
                    dec = cobs_decode(p)
                except ValueError:
                    damaged += 1
                    stopped += 1
                    continue
                if dec == body:
                    continue
                damaged += 1
                if not 4 <= len(dec) <= MAX_FRAME:
                    stopped += 1
                elif single_burst(dec, body):
                    burst += 1
                else:
                    rest += 1
                    rest_same += len(dec) == len(body)
                    # the same frame with an 8-bit check (the CRC's low byte) to test the model
                    if crc16(dec[:-2]) & 0xFF == dec[-1]:
                        weak_pass += 1
        counted = rest_same if reply else rest
        p_pass = counted / damaged * 2 ** -16 if damaged else 0.0
        print(f"{name:22} {len(wire):4} {damaged:8} {stopped:8} {burst:9} {rest:7} "
              f"{rest_same:10} {p_pass:22.2e} {weak_pass:10} / {rest / 256:9.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
