"""The host side of the bridge link protocol (``firmware_bridge/PROTOCOL.md``, version 1).

Everything a transport needs to talk to a bridge that runs whole bus programs on its far side:

* the protocol's constants (frame types, result codes, capability bits, ``MAX_FRAME``), defined
  here once and checked against the firmware's generated tables by the tests;
* COBS framing and CRC-16/GENIBUS, a frame codec and a resynchronising :class:`FrameReader`;
* the payload codecs of HELLO_REPLY, RUN and RUN_REPLY, shared by the host and by the Python far
  end (:mod:`lm629_host.bridge_emu`) so that both speak exactly the same bytes;
* :class:`Pipe`, the byte stream to a bridge with its own clock (a pyserial port, a simulated
  AVR UART, a lossy test wrapper), and :class:`LinkTransport`, the transport over any pipe:
  handshake on open, one RUN frame per program, retries with the same ``seq``, typed errors.

The bridge answers a repeated RUN (same ``seq`` and CRC) from its cache, so the retries here
never run a program twice; after the last retry the host cannot know whether the program ran
and says so.
"""

from __future__ import annotations

import enum
import struct
from binascii import crc_hqx
import logging
import random
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from .errors import BusyTimeout, TransportError
from .program import (OP_ARG_BYTES, STATUS_OPS, BusOp, Op, Program,
                      ProgramResult, TraceCallback, cycles_of)
from .transports.base import Clock, Transport

log = logging.getLogger("lm629_host.link")

# ---------------------------------------------------------------------------------- constants
#: version of PROTOCOL.md implemented here; HELLO_REPLY must carry the same
PROTOCOL_VERSION = 1
#: largest decoded frame (type, seq, payload, CRC), each way
MAX_FRAME = 250
#: largest encoded frame on the wire: COBS adds one byte per 254 and the delimiter one more
MAX_WIRE_FRAME = MAX_FRAME + (MAX_FRAME + 253) // 254 + 1
#: ``busy_timeout_us`` = 0 in a RUN request means this firmware default
FIRMWARE_DEFAULT_BUSY_TIMEOUT_US = 5000
#: bytes of a RUN request around the program: type, seq, cs, busy_timeout_us (2), CRC (2)
RUN_OVERHEAD = 7
#: bytes of a RUN_REPLY around its status bytes and words: type, seq, 5 header bytes, CRC (2)
RUN_REPLY_OVERHEAD = 9
#: largest PING payload
MAX_PING = 32
#: retries of one request (same ``seq``, same bytes) before the host gives up.  Seven: at 1 % of
#: bytes faulty (each of drop, corrupt, duplicate, delay at 0.25 %) one attempt of a small RUN
#: fails about one time in five, so 3 retries leave ~0.15 % of commands failed, 7 leave none
#: measured in 100,000 (README "The serial bridge"); a dead link costs 8 timeouts to notice
DEFAULT_RETRIES = 7
#: how many recent attempts :attr:`LinkTransport.error_rate` looks back over
ERROR_WINDOW = 200
#: an error rate above this makes a give-up message call the link too bad to use
BAD_LINK_RATE = 0.2
#: above this error rate (over a full window) the link logs one warning per window, even while
#: the retries still hide every failure: 5 % of exchanges failing is a cable to look at
WARN_LINK_RATE = 0.05


class FrameType(enum.IntEnum):
    HELLO = 0x01
    RUN = 0x02
    PING = 0x03
    HELLO_REPLY = 0x81
    RUN_REPLY = 0x82
    PONG = 0x83
    ERROR_REPLY = 0xFF


#: request type -> the reply type it expects
REPLY_TO = {FrameType.HELLO: FrameType.HELLO_REPLY, FrameType.RUN: FrameType.RUN_REPLY,
            FrameType.PING: FrameType.PONG}


class Result(enum.IntEnum):
    OK = 0
    BUSY_TIMEOUT = 1
    BAD_PROGRAM = 2
    PROGRAM_TOO_LONG = 3
    BAD_CHIP_SELECT = 4
    BAD_REQUEST = 5


class Capability(enum.IntFlag):
    RESET_LINE = 0x01  #: the bridge drives /RST
    HI_LINE = 0x02  #: the bridge reads HI
    BUSY_ON_BRIDGE = 0x04  #: busy is polled on the bridge (always, in protocol 1)
    WAIT_STATUS = 0x08  #: the bridge runs Op.WAIT_STATUS (older bridges: the host polls)


#: "index of the failing operation" and "last status byte" when there is none
NONE_BYTE = 0xFF


def c_defines() -> list[tuple[str, int, str]]:
    """The protocol's constants as (C name, value, comment), for ``tools/gen_tables.py`` to
    write into ``firmware_bridge/lm629_tables.h``: the firmware never keeps its own copy."""
    out: list[tuple[str, int, str]] = [
        ("LINK_PROTOCOL_VERSION", PROTOCOL_VERSION, "HELLO_REPLY protocol version"),
        ("LINK_MAX_FRAME", MAX_FRAME, "largest decoded frame, each way"),
        ("LINK_MAX_WIRE_FRAME", MAX_WIRE_FRAME, "largest encoded frame with its delimiter"),
        ("LINK_RUN_OVERHEAD", RUN_OVERHEAD, "RUN bytes around the program"),
        ("LINK_RUN_REPLY_OVERHEAD", RUN_REPLY_OVERHEAD, "RUN_REPLY bytes around statuses+words"),
        ("LINK_MAX_PING", MAX_PING, "largest PING payload"),
        ("LINK_DEFAULT_BUSY_TIMEOUT_US", FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
         "busy_timeout_us = 0 means this"),
        ("LINK_NONE_BYTE", NONE_BYTE, "no failing op / no status read yet"),
        ("LINK_CRC_POLY", 0x1021, "CRC-16/GENIBUS polynomial"),
        ("LINK_CRC_INIT", 0xFFFF, "CRC-16/GENIBUS initial value"),
        ("LINK_CRC_XOROUT", 0xFFFF, "CRC-16/GENIBUS final xor"),
    ]
    out += [(f"FRAME_{t.name}", int(t), "frame type") for t in FrameType]
    out += [(f"RESULT_{r.name}", int(r), "result code") for r in Result]
    out += [(f"CAP_{c.name}", int(c), "HELLO_REPLY capability bit") for c in Capability]
    return out


# ---------------------------------------------------------------------------------- CRC, COBS
def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


#: the CRC's byte table, for the firmware (``tools/gen_tables.py`` writes it into
#: ``lm629_tables.h``); the host computes the same CRC with the stdlib (:func:`crc16`)
_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/GENIBUS: poly 0x1021, init 0xFFFF, no reflection, final xor 0xFFFF (check
    value: ``crc16(b"123456789") == 0xD64E``).  The final xor matters: without it a frame
    that gains trailing zero bytes (a delimiter corrupted into 0x01) would still pass.

    It is the stdlib's CRC-CCITT (``binascii.crc_hqx``, poly 0x1021, no reflection) started at
    0xFFFF, then inverted; a test holds it against a bitwise reference and the golden frames."""
    return crc_hqx(data, 0xFFFF) ^ 0xFFFF


class FrameError(ValueError):
    """A frame that cannot be decoded (bad COBS, too long, too short, CRC mismatch)."""


class LinkError(TransportError):
    """The link gave up on a request.  ``may_have_run``: True when the request may have reached
    the bridge (its program may or may not have run), False when nothing was sent to the chip
    (the resynchronising HELLO before it got no answer)."""

    def __init__(self, message: str, *, port: str, may_have_run: bool) -> None:
        super().__init__(message, port=port)
        self.may_have_run = may_have_run


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: ``data`` without any 0x00 byte, one byte longer per
    started 254-byte block (the delimiter is not added here)."""
    out = bytearray()
    block = bytearray()
    for b in data:
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out.append(255)
                out += block
                block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`FrameError` on malformed input."""
    out = bytearray()
    i, n = 0, len(data)
    if n == 0:
        raise FrameError("empty COBS block")
    while i < n:
        code = data[i]
        if code == 0:
            raise FrameError(f"0x00 inside a COBS block at offset {i}")
        end = i + code
        if end > n:
            raise FrameError(f"COBS block at offset {i} runs {end - n} byte(s) past the end")
        block = data[i + 1:end]
        if 0 in block:
            raise FrameError("0x00 inside a COBS block")
        out += block
        i = end
        if code != 255 and i < n:
            out.append(0)
    return bytes(out)


# ---------------------------------------------------------------------------------- frames
@dataclass(frozen=True)
class Frame:
    """A decoded frame.  ``crc`` is the CRC it carried (the bridge's cache key with ``seq``)."""

    type: int
    seq: int
    payload: bytes = b""
    crc: int = 0


def frame_body(ftype: int, seq: int, payload: bytes = b"") -> bytes:
    """The decoded frame: type, seq, payload, CRC (big-endian)."""
    if not 0 <= seq <= 255:
        raise ValueError(f"seq={seq} is outside 0..255")
    body = bytes((ftype & 0xFF, seq)) + bytes(payload)
    if len(body) + 2 > MAX_FRAME:
        raise ValueError(f"frame of {len(body) + 2} bytes is longer than MAX_FRAME={MAX_FRAME}")
    return body + crc16(body).to_bytes(2, "big")


def encode_frame(ftype: int, seq: int, payload: bytes = b"") -> bytes:
    """The bytes on the wire: COBS of :func:`frame_body`, then the 0x00 delimiter."""
    return cobs_encode(frame_body(ftype, seq, payload)) + b"\x00"


def decode_body(body: bytes) -> Frame:
    """Check length and CRC of a decoded frame."""
    if len(body) < 4:
        raise FrameError(f"frame of {len(body)} bytes is shorter than type+seq+CRC")
    if len(body) > MAX_FRAME:
        raise FrameError(f"frame of {len(body)} bytes is longer than MAX_FRAME={MAX_FRAME}")
    crc = int.from_bytes(body[-2:], "big")
    if crc16(body[:-2]) != crc:
        raise FrameError(f"CRC mismatch (carried {crc:04X}, computed {crc16(body[:-2]):04X})")
    return Frame(body[0], body[1], bytes(body[2:-2]), crc)


def decode_frame(wire: bytes) -> Frame:
    """Decode one encoded frame (with or without its trailing delimiter)."""
    if wire.endswith(b"\x00"):
        wire = wire[:-1]
    return decode_body(cobs_decode(wire))


class FrameReader:
    """Splits a byte stream at 0x00 delimiters and decodes frames.

    ``feed(data)`` yields a :class:`Frame` for each good frame and a :class:`FrameError` (as a
    value, not raised) for each bad one; an over-long run of bytes without a delimiter is
    dropped at once and reported when its delimiter arrives, so the reader falls back into step
    on the next frame whatever came before.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflow = False

    def feed(self, data: bytes) -> Iterator[Frame | FrameError]:
        for b in data:
            if b == 0:
                if self._overflow:
                    self._overflow = False
                    self._buf.clear()
                    yield FrameError("frame longer than MAX_FRAME (dropped)")
                    continue
                if not self._buf:
                    continue  # an empty frame: a spare delimiter, used to flush the far end
                wire = bytes(self._buf)
                self._buf.clear()
                try:
                    yield decode_body(cobs_decode(wire))
                except FrameError as exc:
                    yield exc
            elif not self._overflow:
                self._buf.append(b)
                if len(self._buf) > MAX_WIRE_FRAME:
                    self._buf.clear()
                    self._overflow = True

    def clear(self) -> None:
        self._buf.clear()
        self._overflow = False


# ---------------------------------------------------------------------------------- payloads
@dataclass(frozen=True)
class HelloInfo:
    """The payload of HELLO_REPLY: what the bridge is and what it can take."""

    protocol: int = PROTOCOL_VERSION
    firmware: tuple[int, int, int] = (0, 0, 0)
    capabilities: int = int(Capability.RESET_LINE | Capability.HI_LINE | Capability.BUSY_ON_BRIDGE)
    max_program: int = MAX_FRAME - RUN_OVERHEAD
    max_reads: int = (MAX_FRAME - RUN_REPLY_OVERHEAD) // 2
    chip_selects: int = 1
    cpu_hz: int = 16_000_000

    #: protocol, firmware major.minor.patch, capabilities, max_program, max_reads,
    #: chip_selects, cpu_hz (PROTOCOL.md, HELLO_REPLY)
    LAYOUT = struct.Struct(">BBBBHHBBI")
    SIZE = LAYOUT.size

    def encode(self) -> bytes:
        return self.LAYOUT.pack(self.protocol, *self.firmware, self.capabilities,
                                self.max_program, self.max_reads, self.chip_selects, self.cpu_hz)

    @classmethod
    def decode(cls, payload: bytes) -> HelloInfo:
        if len(payload) < 1:
            raise FrameError("HELLO_REPLY without a protocol version")
        if payload[0] != PROTOCOL_VERSION:
            # only the version byte is defined across versions: report it, decode nothing else
            return cls(protocol=payload[0])
        if len(payload) != cls.SIZE:
            raise FrameError(f"HELLO_REPLY of {len(payload)} bytes, expected {cls.SIZE}")
        version, major, minor, patch, *rest = cls.LAYOUT.unpack(payload)
        return cls(version, (major, minor, patch), *rest)

    @property
    def firmware_version(self) -> str:
        return ".".join(map(str, self.firmware))

    def describe(self) -> str:
        caps = Capability(self.capabilities)
        names = [(c.name or "").lower() for c in Capability if c in caps]
        return (f"bridge firmware {self.firmware_version}, protocol {self.protocol}, "
                f"{self.cpu_hz / 1e6:g} MHz, programs up to {self.max_program} bytes / "
                f"{self.max_reads} words, {self.chip_selects} chip select(s), "
                f"{'+'.join(names) or 'no capabilities'}")


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


def reply_size(ops: Sequence[BusOp]) -> int:
    """Decoded size of the RUN_REPLY to ``ops`` when it succeeds."""
    n_status = sum(1 for o in ops if o.op in STATUS_OPS)
    n_words = sum(1 for o in ops if o.op is Op.READ)
    return RUN_REPLY_OVERHEAD + n_status + 2 * n_words


def wire_size(decoded: int) -> int:
    """Bytes on the wire for a decoded frame of ``decoded`` bytes (COBS overhead, delimiter).
    An upper bound: COBS adds one byte per started 254-byte block, plus the code byte."""
    return decoded + 1 + decoded // 254 + 1


_BUSY_CHECKED = (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC)


# ---------------------------------------------------------------------------------- the pipe
@runtime_checkable
class Pipe(Protocol):
    """A byte stream to a bridge, with its own clock.

    ``read(timeout_s)`` waits up to ``timeout_s`` on ``clock`` for the first byte and returns
    what is available then (``b""`` on timeout).  A simulated pipe advances its simulated clock
    while it waits; a serial port waits in real time.
    """

    @property
    def clock(self) -> Clock: ...

    def write(self, data: bytes) -> None: ...

    def read(self, timeout_s: float) -> bytes: ...

    def close(self) -> None: ...


# ---------------------------------------------------------------------------------- transport
class LinkTransport(Transport):
    """A transport whose far side is a bridge speaking PROTOCOL.md over a :class:`Pipe`.

    One RUN frame per bus program (programs longer than the bridge takes are split at operation
    boundaries).  The reply timeout is computed per request (:meth:`reply_timeout`).  On a
    timeout or a bad frame the same frame is sent again, ``retries`` times at most; replies
    with another ``seq`` (late answers to earlier attempts) are ignored.
    """

    scheme = "link"
    #: added to every reply timeout: the far end's own processing time and the latency of a
    #: USB serial adapter (a simulated pipe may lower it: its latency is known)
    margin_s: float = 0.05
    #: bits on the wire per byte for the timeout estimate: start + 8 data + stop (a simulated
    #: UART with two stop bits sets 11)
    wire_bits: int = 10
    #: how long :meth:`hello` keeps asking before "no answer" (an Uno boots in ~1-2 s after the
    #: port opens; subclasses for real ports raise it)
    hello_total_s: float = 0.5
    #: the wait for one HELLO_REPLY before HELLO is sent again
    hello_interval_s: float = 0.1

    def __init__(self, pipe: Pipe, url: str, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = None, cs: int = 0,
                 handshake: bool = True) -> None:
        super().__init__(url, trace=trace)
        if retries < 0:
            raise ValueError(f"retries={retries} must be >= 0")
        if baud is not None and baud <= 0:
            raise ValueError(f"baud={baud} must be a positive number of bits per second")
        self.pipe = pipe
        self.clock = pipe.clock
        self.retries = retries
        self.baud = baud
        self.cs = cs
        self.info: HelloInfo | None = None
        self._seq = random.randrange(256)
        self._reader = FrameReader()
        self._closed = False
        self._has_hi = True
        #: bad frames and stale replies seen (for the fault tests and ``doctor``)
        self.bad_frames = 0
        self.stale_replies = 0
        self.timeouts = 0  #: attempts that got no (usable) answer in time
        #: the last ERROR_WINDOW attempts, True for each that failed (bad frame or no answer)
        self._attempts: deque[bool] = deque(maxlen=ERROR_WINDOW)
        #: a request was given up: the bridge's cache may still hold its seq, so the next
        #: request is preceded by a HELLO (which empties that cache) -- see :meth:`_resync`
        self._need_resync = False
        self._since_warning = 0  #: attempts since the last link-quality warning
        if handshake:
            try:
                self.hello()
            except BaseException:
                self.close()
                raise
            # the counters start with the first program, as on every other transport (the
            # HELLOs a booting bridge left unanswered are not the line's error rate either)
            self.stats.reset()
            self._attempts.clear()

    # ------------------------------------------------------------------ helpers
    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def _byte_s(self) -> float:
        return self.wire_bits / self.baud if self.baud else 0.0

    def reply_timeout(self, request_wire: int, reply_wire: int, ops: Sequence[BusOp] = (),
                      timeout_s: float = 0.0) -> float:
        """Wire time of request and reply at the baud rate, plus ``timeout_s`` for every
        busy-checked operation, plus the program's WAITs, plus :attr:`margin_s`."""
        t = (request_wire + reply_wire) * self._byte_s() + self.margin_s
        for o in ops:
            if o.op in _BUSY_CHECKED:
                t += timeout_s
            elif o.op is Op.WAIT:
                t += o.arg * 1e-6
            elif o.op is Op.WAIT_STATUS:  # the wait, each poll period a little late, + 10 ms
                t += (o.arg & 0xFFFF) * 1e-3 * 1.1 + 0.01
        return t

    def _no_answer(self, what: str, attempts: int) -> TransportError:
        return TransportError(
            f"no answer to {what} after {attempts} attempt(s). Check that the bridge firmware "
            f"is flashed (lm629 bridge flash --port {self.url}), that the baud rate matches the "
            "firmware's, and that nothing else holds the port.", port=self.url)

    # ------------------------------------------------------------------ link quality
    @property
    def error_rate(self) -> float:
        """Fraction of the last :data:`ERROR_WINDOW` attempts that failed (a bad frame, or no
        usable answer in time): the line's health as the host sees it."""
        a = self._attempts
        return sum(a) / len(a) if a else 0.0

    def _attempt(self, failed: bool) -> None:
        """Count one attempt; warn (once per window) when the line is bad, before it costs a
        command."""
        self._attempts.append(failed)
        self._since_warning += 1
        if (self._since_warning >= ERROR_WINDOW and len(self._attempts) == ERROR_WINDOW
                and self.error_rate >= WARN_LINK_RATE):
            self._since_warning = 0
            log.warning("%s: %s", self.url, self._quality())

    def _quality(self) -> str:
        """One sentence on the measured link quality and what to check."""
        a = self._attempts
        failed, n = sum(a), len(a)
        rate = failed / n if n else 0.0
        verdict = ("the link is too noisy to use: " if rate >= BAD_LINK_RATE
                   else "link quality: ")
        return (f"{verdict}{failed} of the last {n} exchanges failed ({100 * rate:.0f} %; "
                f"{self.bad_frames} bad frame(s), {self.timeouts} timeout(s) since open). "
                "Check the USB cable (short, shielded, away from motor and amplifier wiring), "
                "the ground between the bridge and the LM629 board, and that the baud rate "
                f"matches the firmware's ({self.baud or '?'} here)")

    # ------------------------------------------------------------------ exchanges
    def _exchange(self, ftype: FrameType, payload: bytes, timeout_s: float, what: str,
                  retries: int, check: Callable[[Frame], object] | None = None) -> Frame:
        """Send one request and return its reply, retrying with the same frame.

        ``check(frame)`` may raise :class:`FrameError` for a reply that passed its CRC but
        cannot be the answer (wrong length for the program): that is line damage the CRC
        missed, and the request is sent again (the bridge answers from its cache)."""
        seq = self._next_seq()
        wire = encode_frame(ftype, seq, payload)
        want = REPLY_TO[ftype]
        stats = self.stats
        clock = self.clock
        attempts = 0
        bad_before = self.bad_frames
        for attempt in range(retries + 1):
            if attempt:
                stats.retries += 1
                log.info("%s: retry %d of %s seq %d", self.url, attempt, what, seq)
            attempts += 1
            # before a retry, a lone delimiter ends whatever half frame the far end holds
            out = b"\x00" + wire if attempt or ftype is FrameType.HELLO else wire
            self.pipe.write(out)
            stats.bytes_out += len(out)
            stats.round_trips += 1
            deadline = clock.now() + timeout_s
            frame = self._await(seq, deadline)
            if frame is None:
                self._attempt(True)
                continue
            if frame.type == FrameType.ERROR_REPLY:
                code = frame.payload[0] if frame.payload else -1
                raise TransportError(
                    f"the bridge refused {what} (ERROR_REPLY, code {code}): the host and the "
                    "firmware disagree on the protocol. Reflash the firmware that matches this "
                    "host (lm629 bridge flash).", port=self.url)
            if frame.type != want:
                raise TransportError(
                    f"the bridge answered {what} with frame type {frame.type:02X}, expected "
                    f"{int(want):02X}: reflash the firmware that matches this host "
                    "(lm629 bridge flash).", port=self.url)
            if check is not None:
                try:
                    check(frame)
                except FrameError as exc:
                    self.bad_frames += 1
                    self._attempt(True)
                    log.debug("%s: reply to %s passed its CRC but is malformed: %s", self.url,
                              what, exc)
                    continue
            self._attempt(False)
            return frame
        if ftype is FrameType.HELLO:
            raise self._no_answer(what, attempts)
        self._need_resync = True  # the bridge may hold this seq in its cache
        if ftype is not FrameType.RUN:
            raise self._no_answer(what, attempts)
        raise LinkError(
            f"no valid answer to {what} after {attempts} attempt(s) "
            f"({self.bad_frames - bad_before} bad frame(s)): the program may or may not "
            f"have run on the chip; {self._quality()}; then reset the chip (LM629.reset) "
            "before going on.", port=self.url, may_have_run=True)

    def _await(self, seq: int, deadline: float) -> Frame | None:
        """The reply with ``seq``, or None on timeout or on a bad frame (which calls for a
        retry at once: the far end does not answer frames it could not read)."""
        clock = self.clock
        while True:
            left = deadline - clock.now()
            if left <= 0:
                self.timeouts += 1
                return None
            data = self.pipe.read(left)
            if not data:
                self.timeouts += 1
                return None
            self.stats.bytes_in += len(data)
            found: Frame | None = None
            bad = False
            for item in self._reader.feed(data):
                if isinstance(item, FrameError):
                    self.bad_frames += 1
                    log.debug("%s: bad frame: %s", self.url, item)
                    bad = True
                elif item.seq != seq or item.type & 0x80 == 0:
                    self.stale_replies += 1
                    log.debug("%s: ignored frame type %02X seq %d (waiting for %d)",
                              self.url, item.type, item.seq, seq)
                elif found is None:
                    found = item
            if found is not None:
                return found
            if bad:
                return None

    def _resync(self) -> None:
        """After a request was given up, HELLO before the next one.

        The bridge answers a RUN whose seq and CRC equal its cached ones from the cache.  The
        seq wraps at 256, so after a give-up (the bridge may hold that request's reply) a
        later request with the same bytes could come round to the same seq while nothing in
        between reached the bridge (a cable out for 256 calls of a polling loop): it would be
        answered from the cache and never run.  HELLO empties the cache; until a HELLO is
        answered, no request is sent at all (so those failures are certain: nothing ran)."""
        if not self._need_resync:
            return
        timeout = max(self.hello_interval_s,
                      self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)))
        try:
            self._exchange(FrameType.HELLO, b"", timeout, "HELLO (resynchronising after a "
                           "failed exchange)", self.retries)
        except TransportError:
            raise LinkError(
                "no answer from the bridge since the last failed exchange (HELLO unanswered "
                f"{self.retries + 1} times): nothing was sent to the chip; {self._quality()}.",
                port=self.url, may_have_run=False) from None
        self._need_resync = False

    # ------------------------------------------------------------------ protocol requests
    def hello(self) -> HelloInfo:
        """HELLO until answered (for :attr:`hello_total_s`); check the protocol version."""
        timeout = max(self.hello_interval_s,
                      self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)))
        retries = max(0, round(self.hello_total_s / timeout) - 1)
        frame = self._exchange(FrameType.HELLO, b"", timeout, "HELLO (handshake)", retries)
        try:
            info = HelloInfo.decode(frame.payload)
        except FrameError as exc:
            raise TransportError(f"malformed HELLO_REPLY ({exc}): reflash the bridge firmware "
                                 "(lm629 bridge flash)", port=self.url) from None
        if info.protocol != PROTOCOL_VERSION:
            raise TransportError(
                f"the bridge speaks link protocol version {info.protocol}, this host speaks "
                f"version {PROTOCOL_VERSION}. Reflash the bridge with the firmware of this "
                f"host's release: lm629 bridge flash --port {self.url} (or upgrade lm629-host "
                "to match the firmware).", port=self.url)
        if not info.capabilities & Capability.BUSY_ON_BRIDGE:
            raise TransportError("the bridge does not poll busy itself, which protocol 1 "
                                 "requires: reflash the firmware (lm629 bridge flash)",
                                 port=self.url)
        if self.cs >= info.chip_selects:
            raise ValueError(f"cs={self.cs} is outside the bridge's chip selects "
                             f"0..{info.chip_selects - 1}")
        self.info = info
        self.has_reset_line = bool(info.capabilities & Capability.RESET_LINE)
        self._has_hi = bool(info.capabilities & Capability.HI_LINE)
        self.has_wait_status = bool(info.capabilities & Capability.WAIT_STATUS)
        return info

    def ping(self, data: bytes = b"") -> float:
        """PING with ``data`` echoed; returns the round-trip time on the pipe's clock."""
        if len(data) > MAX_PING:
            raise ValueError(f"ping payload of {len(data)} bytes is longer than {MAX_PING}")
        self._resync()
        t0 = self.clock.now()
        n = 4 + len(data)
        frame = self._exchange(FrameType.PING, data,
                               self.reply_timeout(wire_size(n), wire_size(n)), "PING",
                               self.retries)
        if frame.payload != data:
            raise TransportError("PONG does not echo the PING payload: the link corrupts data "
                                 "that passes its CRC; check the baud rate", port=self.url)
        return self.clock.now() - t0

    # ------------------------------------------------------------------ programs
    def _chunks(self, program: Program) -> Iterator[list[BusOp]]:
        """Split ``program`` at operation boundaries into runs that fit the bridge's limits
        (HELLO_REPLY's largest program and reads, and MAX_FRAME for the reply): usually one."""
        info = self.info or HelloInfo()
        max_program = min(info.max_program, MAX_FRAME - RUN_OVERHEAD)
        chunk: list[BusOp] = []
        size = reads = n_status = 0
        for o in program.ops:
            n = 1 + OP_ARG_BYTES[o.op]
            r = 1 if o.op is Op.READ else 0
            s = 1 if o.op in STATUS_OPS else 0
            if chunk and (size + n > max_program or reads + r > info.max_reads
                          or RUN_REPLY_OVERHEAD + n_status + s + 2 * (reads + r) > MAX_FRAME):
                yield chunk
                chunk, size, reads, n_status = [], 0, 0, 0
            chunk.append(o)
            size, reads, n_status = size + n, reads + r, n_status + s
        yield chunk

    def execute(self, program: Program) -> ProgramResult:
        if self._closed:
            raise TransportError("the port is closed", port=self.url)
        timeout_us = busy_timeout_us(program)
        self._resync()
        self.stats.programs += 1
        words: list[int] = []
        statuses: list[int] = []
        status: int | None = None
        hi: bool | None = None
        base = 0
        for ops in self._chunks(program):
            reply = self._run(ops, timeout_us, program.busy_timeout_s)
            ok = reply.result == Result.OK
            busy = reply.result == Result.BUSY_TIMEOUT
            # operations that touched the bus: all, those before the failing one and its busy
            # check after a busy timeout, none when the bridge refused the program
            ran = ops if ok else ops[:reply.index + 1] if busy else []
            self._account(ran, reply)
            self._emit_cycles(ops if ok else ops[:reply.index] if busy else [], reply.words,
                              reply.statuses)
            words += reply.words
            statuses += reply.statuses
            if reply.last_status != NONE_BYTE or any(o.op not in (Op.WAIT, Op.RESET) for o in ran):
                status = reply.last_status
            hi = bool(reply.hi) if self._has_hi else None
            if not ok:
                self._raise_result(reply, ops, base, program, words)
            base += len(ops)
        return ProgramResult(tuple(words), tuple(statuses), status, hi)

    def _run(self, ops: list[BusOp], timeout_us: int, timeout_s: float) -> RunReply:
        payload = run_payload(ops, timeout_us, self.cs)
        req = wire_size(len(payload) + 4)
        rep = wire_size(reply_size(ops))
        timeout = self.reply_timeout(req, rep, ops, timeout_s)
        decoded: list[RunReply] = []

        def check(frame: Frame) -> None:
            reply = RunReply.decode(frame.payload)  # FrameError: retried
            if reply.result in (Result.OK, Result.BUSY_TIMEOUT):
                done = len(ops) if reply.result == Result.OK else min(reply.index, len(ops))
                want_words = sum(1 for o in ops[:done] if o.op is Op.READ)
                want_status = sum(1 for o in ops[:done] if o.op in STATUS_OPS)
                if len(reply.words) != want_words or len(reply.statuses) != want_status:
                    raise FrameError(
                        f"RUN_REPLY carries {len(reply.statuses)} status byte(s) and "
                        f"{len(reply.words)} word(s), expected {want_status} and {want_words}")
            decoded.append(reply)

        self._exchange(FrameType.RUN, payload, timeout, f"RUN of {len(ops)} operation(s)",
                       self.retries, check)
        # a refused program (BAD_PROGRAM...) is raised by the caller, whatever it carries
        return decoded[-1]

    def _account(self, ops: Sequence[BusOp], reply: RunReply) -> None:
        """Bus cycles and busy polls as far as the reply lets us reconstruct them: each busy
        check costs at least one status read (polls beyond the first are not reported)."""
        stats = self.stats
        for o in ops:
            op = o.op
            if op in _BUSY_CHECKED:
                stats.busy_polls += 1
                stats.bus_cycles += 1
            if op is Op.WRITE or op is Op.READ:
                stats.bus_cycles += 2
            elif op is Op.COMMAND or op is Op.STATUS or op is Op.RESET or op is Op.WAIT_STATUS:
                stats.bus_cycles += 1

    def _emit_cycles(self, ops: Sequence[BusOp], words: Sequence[int],
                     statuses: Sequence[int]) -> None:
        if self.trace is None and not logging.getLogger("lm629_host.bus").isEnabledFor(logging.DEBUG):
            return
        for cycle in cycles_of(ops, ProgramResult(tuple(words), tuple(statuses))):
            self._emit(cycle)

    def _raise_result(self, reply: RunReply, ops: list[BusOp], base: int, program: Program,
                      words: list[int]) -> None:
        index = reply.index
        op = ops[index].describe() if index < len(ops) else f"operation {index}"
        where = f" at operation {base + index} ({op})" if index < len(ops) else ""
        if reply.result == Result.BUSY_TIMEOUT:
            status = None if reply.last_status == NONE_BYTE else reply.last_status
            raise BusyTimeout(op, program.busy_timeout_s, status, base + index, words)
        try:
            name = Result(reply.result).name
        except ValueError:
            name = f"unknown result {reply.result}"
        raise TransportError(
            f"the bridge refused the program{where}: {name}; nothing of it ran. "
            "Host and firmware disagree on the program format or limits; reflash the firmware "
            "that matches this host (lm629 bridge flash).", port=self.url)

    # ------------------------------------------------------------------ misc
    def describe(self) -> str:
        if self.info is None:
            return self.url
        return f"{self.url} ({self.info.describe()})"

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.pipe.close()


__all__ = [
    "BadProgram", "Capability", "DEFAULT_RETRIES", "Frame", "FrameError", "FrameReader",
    "FrameType", "HelloInfo", "LinkError", "LinkTransport", "MAX_FRAME", "MAX_WIRE_FRAME", "PROTOCOL_VERSION", "Pipe", "Result",
    "RunReply", "busy_timeout_us", "c_defines", "cobs_decode", "cobs_encode", "crc16", "decode_body",
    "decode_frame", "decode_program", "encode_frame", "encode_program", "frame_body",
    "reply_size", "run_payload", "wire_size",
]
