"""The link protocol's constants (``firmware_bridge/PROTOCOL.md``, version 1): versions, sizes,
frame types, result codes, capability bits and the failsafe's vocabulary.

Defined here once: :func:`~lm629_host.bridge.protocol.tables.c_defines` writes them into the
firmware's ``lm629_tables.h`` (``tools/gen_tables.py``), so the firmware keeps no copy.
"""

from __future__ import annotations

import enum
import struct

from lm629_host.bus.opcodes import UPDATE_INTERVAL_S, TrajectoryFlags

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
