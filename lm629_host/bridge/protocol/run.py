"""The payloads of RUN, RUN_SHORT and their replies: a bus program's bytes and what it read,
shared by the host (:mod:`lm629_host.transports.link`) and the Python far end
(:mod:`lm629_host.sim.bridge`), so that both speak exactly the same bytes."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from lm629_host.bridge.protocol.constants import NONE_BYTE, RUN_REPLY_OVERHEAD, Result
from lm629_host.bridge.protocol.framing import FrameError
from lm629_host.bus.program import OP_ARG_BYTES, STATUS_OPS, BusOp, Op, Program
# the status byte's busy bit: RUN_SHORT_REPLY carries HI in it (see short_reply_payload)
from lm629_host.bus.bits import STATUS_BUSY as _STATUS_BUSY


def encode_program(ops: Sequence[BusOp]) -> bytes:
    """Program bytes of a RUN request: each op code followed by its big-endian argument."""
    out = bytearray()
    for o in ops:
        out.append(int(o.op))
        n = OP_ARG_BYTES[o.op]
        if n:
            out += int(o.arg).to_bytes(n, "big")
    return bytes(out)


class BadProgram(ValueError):
    """Program bytes that do not decode (the far end answers BAD_PROGRAM at ``index``)."""

    def __init__(self, index: int, why: str) -> None:
        self.index = index
        super().__init__(f"operation {index}: {why}")


def decode_program(data: bytes) -> list[BusOp]:
    """Inverse of :func:`encode_program` (the far end's parser); raises :class:`BadProgram`."""
    ops: list[BusOp] = []
    i = 0
    while i < len(data):
        try:
            op = Op(data[i])
        except ValueError:
            raise BadProgram(len(ops), f"unknown op code {data[i]:02X}") from None
        n = OP_ARG_BYTES[op]
        if i + 1 + n > len(data):
            raise BadProgram(len(ops), f"{op.name} lacks {i + 1 + n - len(data)} argument byte(s)")
        ops.append(BusOp(op, int.from_bytes(data[i + 1:i + 1 + n], "big") if n else 0))
        i += 1 + n
    return ops


def busy_timeout_us(program: Program) -> int:
    """The RUN field for ``program.busy_timeout_s`` (ValueError when it cannot be carried)."""
    us = round(program.busy_timeout_s * 1e6)
    if not 1 <= us <= 0xFFFF:
        raise ValueError(f"busy_timeout_s={program.busy_timeout_s!r} is outside what the bridge "
                         "can carry (1 us .. 65.535 ms)")
    return us


#: the RUN payload's header: chip select, busy_timeout_us
RUN_HEADER = struct.Struct(">BH")


def run_payload(ops: Sequence[BusOp], timeout_us: int, cs: int = 0) -> bytes:
    return RUN_HEADER.pack(cs, timeout_us) + encode_program(ops)


@dataclass(frozen=True)
class RunReply:
    """The payload of RUN_REPLY."""

    result: int = Result.OK
    index: int = NONE_BYTE
    last_status: int = NONE_BYTE
    hi: int = 0
    statuses: tuple[int, ...] = ()
    words: tuple[int, ...] = ()

    #: result, index, last_status, hi, number of status bytes; then the status bytes and the
    #: words (big-endian)
    HEADER = struct.Struct(">5B")

    def encode(self) -> bytes:
        return (self.HEADER.pack(self.result, self.index, self.last_status, self.hi,
                                 len(self.statuses))
                + bytes(self.statuses) + struct.pack(f">{len(self.words)}H", *self.words))

    @classmethod
    def decode(cls, payload: bytes) -> RunReply:
        if len(payload) < 5:
            raise FrameError(f"RUN_REPLY of {len(payload)} bytes is shorter than its 5-byte header")
        n = payload[4]
        rest = payload[5 + n:]
        if len(payload) < 5 + n or len(rest) % 2:
            raise FrameError(f"RUN_REPLY of {len(payload)} bytes does not hold {n} status bytes "
                             "and whole words")
        words = struct.unpack(f">{len(rest) // 2}H", rest)
        return cls(payload[0], payload[1], payload[2], payload[3], tuple(payload[5:5 + n]), words)


#: operations checked for busy before they run
_BUSY_CHECKED = (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC)


def short_reply_payload(ops: Sequence[BusOp], reply: RunReply) -> bytes:
    """RUN_SHORT_REPLY's payload for ``ops`` that ran to their end with ``reply``'s results:
    the bytes read in program order (a status byte for each STATUS, SYNC and WAIT_STATUS, two
    for each READ), then the last status seen with its busy bit replaced by HI.

    The busy bit is free because the last status the host cannot find among the bytes read is
    that of a passed busy check (busy clear); :func:`decode_short_reply` says which it is."""
    statuses, words = iter(reply.statuses), iter(reply.words)
    out = bytearray()
    for o in ops:
        if o.op is Op.READ:
            out += next(words).to_bytes(2, "big")
        elif o.op in STATUS_OPS:
            out.append(next(statuses))
    last = reply.last_status if reply.last_status != NONE_BYTE else NONE_BYTE
    out.append((last & ~_STATUS_BUSY & 0xFF) | (1 if reply.hi else 0))
    return bytes(out)


def decode_short_reply(payload: bytes, ops: Sequence[BusOp]) -> RunReply:
    """Inverse of :func:`short_reply_payload`; :class:`FrameError` when the payload does not
    hold exactly what ``ops`` read (line damage the CRC missed)."""
    n_status = sum(1 for o in ops if o.op in STATUS_OPS)
    n_words = sum(1 for o in ops if o.op is Op.READ)
    if len(payload) != n_status + 2 * n_words + 1:
        raise FrameError(f"RUN_SHORT_REPLY of {len(payload)} bytes, expected "
                         f"{n_status + 2 * n_words + 1} for {n_status} status byte(s) and "
                         f"{n_words} word(s)")
    statuses: list[int] = []
    words: list[int] = []
    i = 0
    last = NONE_BYTE
    hdr = payload[-1]
    for o in ops:
        if o.op is Op.READ:
            words.append(int.from_bytes(payload[i:i + 2], "big"))
            i += 2
            last = hdr & ~_STATUS_BUSY & 0xFF
        elif o.op in STATUS_OPS:
            statuses.append(payload[i])
            last = payload[i]
            i += 1
        elif o.op in _BUSY_CHECKED:
            last = hdr & ~_STATUS_BUSY & 0xFF
    return RunReply(Result.OK, NONE_BYTE, last, hdr & 1, tuple(statuses), tuple(words))


def reply_size(ops: Sequence[BusOp]) -> int:
    """Decoded size of the RUN_REPLY to ``ops`` when it succeeds."""
    n_status = sum(1 for o in ops if o.op in STATUS_OPS)
    n_words = sum(1 for o in ops if o.op is Op.READ)
    return RUN_REPLY_OVERHEAD + n_status + 2 * n_words
