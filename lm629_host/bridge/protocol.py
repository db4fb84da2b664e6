"""The bridge link protocol (``firmware_bridge/PROTOCOL.md``, version 1), both ends' bytes.

* the protocol's constants (frame types, result codes, capability bits, ``MAX_FRAME``), defined
  here once and written into the firmware's ``lm629_tables.h`` (``tools/gen_tables.py``);
* COBS framing and CRC-16/GENIBUS, a frame codec and a resynchronising :class:`FrameReader`;
* the payload codecs of HELLO_REPLY, RUN and RUN_REPLY, shared by the host
  (:mod:`lm629_host.transports.link`) and by the Python far end (:mod:`lm629_host.sim.bridge`),
  so that both speak exactly the same bytes.

No I/O here beyond :class:`Pipe`, what a byte stream to a bridge must offer (a serial port,
a simulated UART, the Python far end); the transport over it is :class:`~lm629_host.transports.link.LinkTransport`.
"""

from __future__ import annotations

import enum
import struct
from binascii import crc_hqx
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from lm629_host.clock import Clock
from lm629_host.bus.opcodes import UPDATE_INTERVAL_S, Cmd, Status, TrajectoryFlags
from lm629_host.bus.program import OP_ARG_BYTES, STATUS_OPS, BusOp, Op, Program

# ---------------------------------------------------------------------------------- constants
#: version of PROTOCOL.md implemented here; HELLO_REPLY must carry the same
PROTOCOL_VERSION = 1
#: the bridge firmware's version (HELLO_REPLY), generated into ``lm629_tables.h`` so that the
#: firmware and the Python far end (``lm629_host/sim/bridge/``) report the one release they
#: both implement.  1.1: several chips (Op.SELECT, four chip selects); 1.2: the compact RUN,
#: programs kept by code, SET_BAUD; 1.3: RECORD (rows on the bridge's timer); 1.4: the link
#: failsafe (FAILSAFE), PROFILE (a shaped move's pieces on the bridge's timer)
FIRMWARE_VERSION = (1, 4, 0)
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
#: bytes of a RUN_SHORT around the program: type, seq, CRC (2)
RUN_SHORT_OVERHEAD = 4
#: bytes of a RUN_SHORT_REPLY around the bytes read: type, seq, the last-status/HI byte, CRC (2)
RUN_SHORT_REPLY_OVERHEAD = 5
#: largest PING payload
MAX_PING = 32
#: programs a bridge with PROGRAM_CODES keeps (codes 0..CODE_SLOTS-1), and their largest size:
#: a poll (RDRP: 4 bytes, a snapshot: 12) is sent again as a 1-byte code
CODE_SLOTS = 8
CODE_BYTES = 12
#: after SET_BAUD the bridge waits this long for a good frame at the new rate, then goes back
BAUD_WINDOW_MS = 250
#: the rate a host asks a bridge with BAUD_SWITCH for: an Uno's or Nano's USB serial chip
#: (16U2, CH340, FT232R) and the ATmega328P at 16 MHz make it exactly (divisor 2 with U2X)
FAST_BAUD = 1_000_000
#: RECORD: the sample program's limits (bytes of program, bytes read per row), the shortest
#: period, and the bridge's clock tick (its Timer1 at clk/64: periods and stamps are multiples)
RECORD_MAX_PROGRAM = 32
RECORD_MAX_BYTES = 40
RECORD_MIN_PERIOD_US = 200
RECORD_TICK_US = 4
#: bytes of a RECORD_ROW around the bytes read: type, seq, row (2), t_us (4), CRC (2)
RECORD_ROW_OVERHEAD = 10
#: the chip's data-reporting commands (RDDV 07h .. RDSUM 0Dh): the only commands a sample
#: program may send, so that a recording never changes the chip (and may be repeated)
RECORD_CMD_FIRST, RECORD_CMD_LAST = 0x07, 0x0D
#: FAILSAFE: the range of the bridge's link timer (a host slower than 10 s is not alive)
FAILSAFE_MIN_MS = 50
FAILSAFE_MAX_MS = 10_000
#: PROFILE: the pieces of a shaped move (AN-706 4.5.3) the bridge issues on its own timer: at
#: least 10 ms apart (AN-706 4.6.2, the host's UPDATE_INTERVAL_S), as many as a frame carries
PROFILE_MIN_SPACING_US = round(UPDATE_INTERVAL_S * 1e6)
#: PROFILE's flags: a new schedule (its clock starts when the frame arrives; pending pieces of
#: an older one are dropped), else the pieces are appended (none: a query of the schedule)
PROFILE_NEW = 0x01
#: bytes of a piece: its time from the schedule's start (us), its velocity word
PROFILE_PIECE = struct.Struct(">II")
#: PROFILE's payload header: flags, chip select
PROFILE_HEADER = struct.Struct(">BB")
#: the most pieces one PROFILE frame carries (type, seq and CRC around the payload)
PROFILE_MAX_PIECES = (MAX_FRAME - 4 - PROFILE_HEADER.size) // PROFILE_PIECE.size
#: the most pieces a schedule holds (the firmware's table)
PROFILE_MAX_SCHEDULE = 64
_STATUS_BUSY = int(Status.BUSY)


class FrameType(enum.IntEnum):
    HELLO = 0x01
    RUN = 0x02
    PING = 0x03
    RUN_SHORT = 0x04  #: RUN without cs and busy timeout (0 and the default); COMPACT_RUN only
    RUN_STORE = 0x05  #: slot, program: a RUN_SHORT whose program is kept under that code
    RUN_CODE = 0x06  #: slot: run the program kept under that code (PROGRAM_CODES only)
    SET_BAUD = 0x07  #: baud (4): switch the line's rate after the reply (BAUD_SWITCH only)
    #: period_us (4), rows (2; 0: until stopped), a sample program: the bridge runs it on its
    #: own timer and streams one RECORD_ROW per run, then RECORD_END (RECORD only)
    RECORD = 0x08
    #: empty: report the failsafe's state (FAILSAFE_REPLY); or a FailsafeCmd and its
    #: arguments (FAILSAFE only).  Every good frame feeds the failsafe; during a recording
    #: the exact bytes of :data:`FAILSAFE_FEED` feed it without ending the recording
    FAILSAFE = 0x09
    #: flags (1), cs (1), pieces (t_us (4), velocity (4)): the bridge issues each piece (LTRJ
    #: velocity + STT on cs) at its time on its own timer between requests (PROFILE only)
    PROFILE = 0x0A
    HELLO_REPLY = 0x81
    RUN_REPLY = 0x82
    PONG = 0x83
    RUN_SHORT_REPLY = 0x84  #: a RUN_SHORT that ran to its end (otherwise: RUN_REPLY)
    BAUD_REPLY = 0x87  #: result (1), the rate the bridge switches to (4)
    RECORD_ROW = 0x88  #: row (2), t_us (4), the bytes the sample program read, in order
    RECORD_END = 0x89  #: result (1), index (1), rows sent (2): the recording is over
    FAILSAFE_REPLY = 0x8A  #: result (1) then the failsafe's state (:class:`FailsafeState`)
    #: result (1), pieces issued (2), pieces pending (2), largest lateness of a piece (4, us)
    PROFILE_REPLY = 0x8B
    ERROR_REPLY = 0xFF


#: request type -> the reply type it expects
REPLY_TO = {FrameType.HELLO: FrameType.HELLO_REPLY, FrameType.RUN: FrameType.RUN_REPLY,
            FrameType.PING: FrameType.PONG, FrameType.RUN_SHORT: FrameType.RUN_SHORT_REPLY,
            FrameType.RUN_STORE: FrameType.RUN_SHORT_REPLY,
            FrameType.RUN_CODE: FrameType.RUN_SHORT_REPLY, FrameType.SET_BAUD: FrameType.BAUD_REPLY,
            FrameType.RECORD: FrameType.RECORD_ROW, FrameType.FAILSAFE: FrameType.FAILSAFE_REPLY,
            FrameType.PROFILE: FrameType.PROFILE_REPLY}
#: other reply types a request may get: a compact RUN that failed is answered as a RUN
ALSO_REPLY_TO = {FrameType.RUN_SHORT: FrameType.RUN_REPLY, FrameType.RUN_STORE: FrameType.RUN_REPLY,
                 FrameType.RUN_CODE: FrameType.RUN_REPLY, FrameType.RECORD: FrameType.RECORD_END}
#: the compact requests that run a program (a give-up says it may or may not have run)
RUN_TYPES = frozenset({FrameType.RUN, FrameType.RUN_SHORT, FrameType.RUN_STORE, FrameType.RUN_CODE})


class Result(enum.IntEnum):
    OK = 0
    BUSY_TIMEOUT = 1
    BAD_PROGRAM = 2
    PROGRAM_TOO_LONG = 3
    BAD_CHIP_SELECT = 4
    BAD_REQUEST = 5
    UNKNOWN_CODE = 6  #: RUN_CODE for a code the bridge keeps no program under (nothing ran)
    BAD_BAUD = 7  #: SET_BAUD to a rate the bridge cannot make within 2 % (it stays as it is)
    BAD_RATE = 8  #: RECORD with a period below RECORD_MIN_PERIOD_US (nothing recorded)
    #: a program with STT while a failsafe trip is latched and not acknowledged (nothing ran)
    FAILSAFE_TRIPPED = 9
    #: FAILSAFE with a timeout outside FAILSAFE_MIN_MS..FAILSAFE_MAX_MS, an unknown action or
    #: command (nothing changed)
    BAD_FAILSAFE = 10
    #: PROFILE with pieces out of order, closer than PROFILE_MIN_SPACING_US, a velocity above
    #: 3FFFFFFF, more than PROFILE_MAX_SCHEDULE or a chip select it has not (nothing scheduled)
    BAD_PROFILE = 11
    #: the schedule was dropped before its last piece: a program that loads a trajectory
    #: (LTRJ: a stop) or pulses /RST ended it, or a failsafe trip stopped the chips, so that
    #: nothing restarts a stopped motor
    PROFILE_CANCELLED = 12


class Capability(enum.IntFlag):
    RESET_LINE = 0x01  #: the bridge drives /RST
    HI_LINE = 0x02  #: the bridge reads HI
    BUSY_ON_BRIDGE = 0x04  #: busy is polled on the bridge (always, in protocol 1)
    WAIT_STATUS = 0x08  #: the bridge runs Op.WAIT_STATUS (older bridges: the host polls)
    #: the bridge runs Op.SELECT: a program may switch chip select (a multi-axis bridge; an
    #: older bridge gets one RUN per chip, its ``cs`` field naming the chip)
    SELECT = 0x10
    #: the bridge takes RUN_SHORT (older bridges: every program is a RUN)
    COMPACT_RUN = 0x20
    #: the bridge keeps CODE_SLOTS programs of up to CODE_BYTES bytes (RUN_STORE, RUN_CODE)
    PROGRAM_CODES = 0x40
    #: the bridge switches its line's rate on SET_BAUD, and goes back to the rate it had when
    #: no good frame comes at the new rate within BAUD_WINDOW_MS
    BAUD_SWITCH = 0x80
    #: the bridge records on its own timer (RECORD): rows stamped with its clock, streamed
    RECORD = 0x100
    #: the bridge keeps a link failsafe (FAILSAFE): silent host -> every chip stopped, latched
    FAILSAFE = 0x200
    #: the bridge issues a shaped move's pieces on its own timer (PROFILE)
    PROFILE = 0x400


class FailsafeCmd(enum.IntEnum):
    """The first payload byte of a FAILSAFE request (an empty payload only reports)."""

    DISARM = 0
    ARM = 1  #: timeout_ms (2), action (1)
    ACKNOWLEDGE = 2  #: forget the latched trip: trajectory commands are taken again


class FailsafeAction(enum.IntEnum):
    """What the bridge does to every chip when the failsafe expires: LTRJ with this stop bit,
    then STT, each with the busy discipline."""

    ABRUPT = 0  #: the PID brakes at full torque and holds: a loaded axis does not fall
    SMOOTH = 1  #: decelerates at the loaded acceleration
    OFF = 2  #: motor off (the drive output goes to zero: a loaded axis may fall)


#: LTRJ's stop bit for each failsafe action
FAILSAFE_STOP_BITS = {FailsafeAction.ABRUPT: int(TrajectoryFlags.STOP_ABRUPT),
                      FailsafeAction.SMOOTH: int(TrajectoryFlags.STOP_SMOOTH),
                      FailsafeAction.OFF: int(TrajectoryFlags.MOTOR_OFF)}


#: "index of the failing operation" and "last status byte" when there is none
NONE_BYTE = 0xFF


def c_defines() -> list[tuple[str, int, str]]:
    """The protocol's constants as (C name, value, comment), for ``tools/gen_tables.py`` to
    write into ``firmware_bridge/lm629_tables.h``: the firmware never keeps its own copy."""
    out: list[tuple[str, int, str]] = [
        ("LINK_PROTOCOL_VERSION", PROTOCOL_VERSION, "HELLO_REPLY protocol version"),
        ("FIRMWARE_MAJOR", FIRMWARE_VERSION[0], "HELLO_REPLY firmware version"),
        ("FIRMWARE_MINOR", FIRMWARE_VERSION[1], "HELLO_REPLY firmware version"),
        ("FIRMWARE_PATCH", FIRMWARE_VERSION[2], "HELLO_REPLY firmware version"),
        ("LINK_MAX_FRAME", MAX_FRAME, "largest decoded frame, each way"),
        ("LINK_MAX_WIRE_FRAME", MAX_WIRE_FRAME, "largest encoded frame with its delimiter"),
        ("LINK_RUN_OVERHEAD", RUN_OVERHEAD, "RUN bytes around the program"),
        ("LINK_RUN_REPLY_OVERHEAD", RUN_REPLY_OVERHEAD, "RUN_REPLY bytes around statuses+words"),
        ("LINK_RUN_SHORT_OVERHEAD", RUN_SHORT_OVERHEAD, "RUN_SHORT bytes around the program"),
        ("LINK_RUN_SHORT_REPLY_OVERHEAD", RUN_SHORT_REPLY_OVERHEAD,
         "RUN_SHORT_REPLY bytes around the bytes read"),
        ("LINK_MAX_PING", MAX_PING, "largest PING payload"),
        ("LINK_CODE_SLOTS", CODE_SLOTS, "programs kept for RUN_CODE"),
        ("LINK_CODE_BYTES", CODE_BYTES, "largest program kept for RUN_CODE"),
        ("LINK_BAUD_WINDOW_MS", BAUD_WINDOW_MS, "SET_BAUD: a good frame at the new rate within"),
        ("LINK_DEFAULT_BUSY_TIMEOUT_US", FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
         "busy_timeout_us = 0 means this"),
        ("LINK_NONE_BYTE", NONE_BYTE, "no failing op / no status read yet"),
        ("LINK_RECORD_MAX_PROGRAM", RECORD_MAX_PROGRAM, "RECORD: largest sample program"),
        ("LINK_RECORD_MAX_BYTES", RECORD_MAX_BYTES, "RECORD: most bytes a row reads"),
        ("LINK_RECORD_MIN_PERIOD_US", RECORD_MIN_PERIOD_US, "RECORD: shortest period"),
        ("LINK_RECORD_TICK_US", RECORD_TICK_US, "RECORD: the bridge clock's tick"),
        ("LINK_RECORD_CMD_FIRST", RECORD_CMD_FIRST, "RECORD: first data-reporting command"),
        ("LINK_RECORD_CMD_LAST", RECORD_CMD_LAST, "RECORD: last data-reporting command"),
        ("LINK_FAILSAFE_MIN_MS", FAILSAFE_MIN_MS, "FAILSAFE: shortest timeout"),
        ("LINK_FAILSAFE_MAX_MS", FAILSAFE_MAX_MS, "FAILSAFE: longest timeout"),
        ("LINK_FAILSAFE_REPLY_SIZE", FailsafeState.SIZE, "FAILSAFE_REPLY payload bytes"),
        ("LINK_PROFILE_MIN_SPACING_US", PROFILE_MIN_SPACING_US, "PROFILE: pieces this far apart"),
        ("LINK_PROFILE_NEW", PROFILE_NEW, "PROFILE flags: a new schedule"),
        ("LINK_PROFILE_MAX_PIECES", PROFILE_MAX_PIECES, "PROFILE: pieces in one frame"),
        ("LINK_PROFILE_MAX_SCHEDULE", PROFILE_MAX_SCHEDULE, "PROFILE: pieces in a schedule"),
        ("LINK_PROFILE_LTRJ_CONTROL", int(TrajectoryFlags.VELOCITY),
         "PROFILE: a piece's LTRJ control word (velocity only)"),
        ("LINK_CRC_POLY", 0x1021, "CRC-16/GENIBUS polynomial"),
        ("LINK_CRC_INIT", 0xFFFF, "CRC-16/GENIBUS initial value"),
        ("LINK_CRC_XOROUT", 0xFFFF, "CRC-16/GENIBUS final xor"),
    ]
    out += [(f"FRAME_{t.name}", int(t), "frame type") for t in FrameType]
    out += [(f"RESULT_{r.name}", int(r), "result code") for r in Result]
    out += [(f"CAP_{c.name}", int(c), "HELLO_REPLY capability bit") for c in Capability]
    out += [(f"FAILSAFE_CMD_{c.name}", int(c), "FAILSAFE command") for c in FailsafeCmd]
    out += [(f"FAILSAFE_ACTION_{a.name}", int(a), "FAILSAFE action") for a in FailsafeAction]
    out += [(f"FAILSAFE_STOP_{a.name}", FAILSAFE_STOP_BITS[a], "FAILSAFE: LTRJ word")
            for a in FailsafeAction]
    out += [("LINK_FAILSAFE_FEED_LEN", len(FAILSAFE_FEED), "FAILSAFE_FEED wire bytes")]
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


def wire_size(decoded: int) -> int:
    """Bytes on the wire for a decoded frame of ``decoded`` bytes (COBS overhead, delimiter).
    An upper bound: COBS adds one byte per started 254-byte block, plus the code byte."""
    return decoded + 1 + decoded // 254 + 1


# ---------------------------------------------------------------------------------- RECORD
#: RECORD's payload header: period_us, rows (0: until stopped); the program follows
RECORD_HEADER = struct.Struct(">IH")
#: RECORD_ROW's payload header: row number (mod 65536), the bridge's clock in us (mod 2**32)
ROW_HEADER = struct.Struct(">HI")
#: RECORD_END's payload: result, index of the failing operation (NONE_BYTE), rows sent
END_PAYLOAD = struct.Struct(">BBH")
#: the operations a sample program may hold (reads only: a recording never changes the chip)
RECORD_OPS = frozenset({Op.STATUS, Op.COMMAND, Op.READ, Op.SELECT})


def record_payload(period_us: int, rows: int, ops: Sequence[BusOp]) -> bytes:
    """RECORD's payload (the host checks the program with :func:`check_record_program`)."""
    return RECORD_HEADER.pack(period_us, rows) + encode_program(ops)


def check_record_program(ops: Sequence[BusOp], chip_selects: int = 1) -> tuple[int, int]:
    """Why the bridge would refuse ``ops`` as a sample program: :class:`BadProgram` for an
    operation that is not a status read, a data-reporting command, a READ or a SELECT of a chip
    it has; ``ValueError`` for a program or row over the limits.  Returns (program bytes, bytes
    read per row)."""
    for i, o in enumerate(ops):
        if o.op not in RECORD_OPS:
            raise BadProgram(i, f"{o.describe()} in a sample program (only status reads, "
                                "data-reporting commands RDDV..RDSUM and READs)")
        if o.op is Op.COMMAND and not RECORD_CMD_FIRST <= o.arg <= RECORD_CMD_LAST:
            raise BadProgram(i, f"{o.describe()} is not a data-reporting command")
        if o.op is Op.SELECT and o.arg >= chip_selects:
            raise BadProgram(i, f"{o.describe()}: the bridge has {chip_selects} chip select(s)")
    size = len(encode_program(ops))
    read = sum(2 if o.op is Op.READ else 1 for o in ops if o.op is Op.READ or o.op in STATUS_OPS)
    if size > RECORD_MAX_PROGRAM or read > RECORD_MAX_BYTES:
        raise ValueError(f"a sample program of {size} bytes reading {read} bytes a row is over "
                         f"the bridge's {RECORD_MAX_PROGRAM} / {RECORD_MAX_BYTES}")
    return size, read


def row_wire_bytes(read: int) -> int:
    """Bytes on the wire of one RECORD_ROW that carries ``read`` bytes (COBS and delimiter:
    a row is shorter than 254 bytes)."""
    return RECORD_ROW_OVERHEAD + read + 2


# ---------------------------------------------------------------------------------- FAILSAFE
@dataclass(frozen=True)
class FailsafeState:
    """FAILSAFE_REPLY's payload: the request's result, the timer as armed (``timeout_ms`` 0:
    disarmed) and its action, and the latched trip: whether there is one, which chip selects
    it stopped (bit k: chip select k), how long the host had been silent and the bridge's
    clock at the trip (ms since the bridge started)."""

    result: int = Result.OK
    timeout_ms: int = 0
    action: int = FailsafeAction.ABRUPT
    tripped: bool = False
    chips: int = 0
    silent_ms: int = 0
    at_ms: int = 0

    LAYOUT = struct.Struct(">BHBBBII")
    SIZE = LAYOUT.size

    def encode(self) -> bytes:
        return self.LAYOUT.pack(self.result, self.timeout_ms, self.action, int(self.tripped),
                                self.chips, self.silent_ms & 0xFFFFFFFF, self.at_ms & 0xFFFFFFFF)

    @classmethod
    def decode(cls, payload: bytes) -> FailsafeState:
        if len(payload) != cls.SIZE:
            raise FrameError(f"FAILSAFE_REPLY of {len(payload)} bytes, expected {cls.SIZE}")
        result, ms, action, tripped, chips, silent, at = cls.LAYOUT.unpack(payload)
        return cls(result, ms, action, bool(tripped), chips, silent, at)

    @property
    def stopped(self) -> list[int]:
        """The chip selects the trip stopped."""
        return [k for k in range(8) if self.chips >> k & 1]

    def describe(self, names: dict[int, str] | None = None) -> str:
        """One sentence on the latched trip (``names``: axis names by chip select)."""
        if not self.tripped:
            return "no failsafe trip latched"
        names = names or {}
        who = ", ".join(f"axis {names[k]} (cs {k})" if k in names else f"cs {k}"
                        for k in self.stopped) or "no chip (none answered)"
        try:
            how = FailsafeAction(self.action).name.lower()
        except ValueError:
            how = f"action {self.action}"
        return (f"the bridge stopped {who} ({how} stop) after the host was silent for "
                f"{self.silent_ms / 1e3:.2f} s (at bridge time {self.at_ms / 1e3:.1f} s)")


#: the one FAILSAFE frame a recording takes without ending: seq 0, empty payload, always the
#: same bytes, so that the bridge matches it byte by byte while it samples
FAILSAFE_FEED = encode_frame(FrameType.FAILSAFE, 0)


# ---------------------------------------------------------------------------------- PROFILE
#: PROFILE_REPLY's payload: result, pieces issued, pieces pending, largest lateness (us)
PROFILE_REPLY_PAYLOAD = struct.Struct(">BHHI")


def profile_payload(new: bool, cs: int, pieces: Sequence[tuple[int, int]]) -> bytes:
    """PROFILE's payload: ``pieces`` as (us from the schedule's start, velocity word)."""
    if len(pieces) > PROFILE_MAX_PIECES:
        raise ValueError(f"{len(pieces)} pieces: a PROFILE frame carries {PROFILE_MAX_PIECES}")
    return PROFILE_HEADER.pack(PROFILE_NEW if new else 0, cs) + b"".join(
        PROFILE_PIECE.pack(t, v) for t, v in pieces)


def profile_piece_ops(velocity: int) -> list[BusOp]:
    """The bus program of one piece: LTRJ with a new maximum velocity only, then STT (a
    velocity may change on the fly, AN-706 4.6.1)."""
    return [BusOp(Op.COMMAND, int(Cmd.LTRJ)), BusOp(Op.WRITE, int(TrajectoryFlags.VELOCITY)),
            BusOp(Op.WRITE, velocity >> 16), BusOp(Op.WRITE, velocity & 0xFFFF),
            BusOp(Op.COMMAND, int(Cmd.STT))]


def ends_a_profile(ops: Sequence[BusOp]) -> bool:
    """A program the bridge drops a schedule for: one that loads a trajectory (a stop, a new
    move) or pulses /RST: no later piece may restart what it stopped."""
    return any((o.op is Op.COMMAND and o.arg == Cmd.LTRJ) or o.op is Op.RESET for o in ops)


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


__all__ = [
    "PROFILE_HEADER",
    "PROFILE_MAX_PIECES",
    "PROFILE_MAX_SCHEDULE",
    "PROFILE_MIN_SPACING_US",
    "PROFILE_NEW",
    "PROFILE_PIECE",
    "PROFILE_REPLY_PAYLOAD",
    "ends_a_profile",
    "profile_payload",
    "profile_piece_ops",
    "ALSO_REPLY_TO",
    "FAILSAFE_FEED",
    "FAILSAFE_MAX_MS",
    "FAILSAFE_MIN_MS",
    "FAILSAFE_STOP_BITS",
    "FailsafeAction",
    "FailsafeCmd",
    "FailsafeState",
    "END_PAYLOAD",
    "RECORD_CMD_FIRST",
    "RECORD_CMD_LAST",
    "RECORD_HEADER",
    "RECORD_MAX_BYTES",
    "RECORD_MAX_PROGRAM",
    "RECORD_MIN_PERIOD_US",
    "RECORD_OPS",
    "RECORD_ROW_OVERHEAD",
    "RECORD_TICK_US",
    "ROW_HEADER",
    "check_record_program",
    "record_payload",
    "row_wire_bytes",
    "BAUD_WINDOW_MS",
    "CODE_BYTES",
    "CODE_SLOTS",
    "FAST_BAUD",
    "RUN_SHORT_OVERHEAD",
    "RUN_SHORT_REPLY_OVERHEAD",
    "RUN_TYPES",
    "decode_short_reply",
    "short_reply_payload",
    "Pipe",
    "BadProgram",
    "Capability",
    "Frame",
    "FrameError",
    "FrameReader",
    "FrameType",
    "HelloInfo",
    "MAX_FRAME",
    "MAX_WIRE_FRAME",
    "PROTOCOL_VERSION",
    "FIRMWARE_VERSION",
    "Result",
    "RunReply",
    "busy_timeout_us",
    "c_defines",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "decode_body",
    "decode_frame",
    "decode_program",
    "encode_frame",
    "encode_program",
    "frame_body",
    "reply_size",
    "run_payload",
    "wire_size",
]
