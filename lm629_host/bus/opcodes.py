"""The LM628/LM629 facts that every layer shares: command opcodes, word counts and bit masks.

This module is the one place where these numbers are written down.  The typed command layer,
the chip model, the bridge firmware (through the generated ``firmware_bridge/lm629_tables.h``, see
``tools/gen_tables.py``) and the tests all take them from here.  Sources: the datasheet command
table and AN-706 section 3 (condensed in ``shared/spec/lm628-lm629-reference.md``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Cmd(enum.IntEnum):
    """User command opcodes (the byte written with /PS low)."""

    RESET = 0x00
    STT = 0x01
    DFH = 0x02
    SIP = 0x03
    UDF = 0x04
    PORT8 = 0x05
    PORT12 = 0x06
    RDDV = 0x07
    RDDP = 0x08
    RDIP = 0x09
    RDRP = 0x0A
    RDRV = 0x0B
    RDSIGS = 0x0C
    RDSUM = 0x0D
    LPES = 0x1A
    LPEI = 0x1B
    MSKI = 0x1C
    RSTI = 0x1D
    LFIL = 0x1E
    LTRJ = 0x1F
    SBPA = 0x20
    SBPR = 0x21


class Direction(enum.Enum):
    NONE = "none"
    WRITE = "write"
    READ = "read"


@dataclass(frozen=True)
class CommandInfo:
    """How many data words follow a command and in which direction.

    For LFIL and LTRJ ``words`` is the minimum (the control word); the rest depends on the
    flags in that control word (see :func:`lfil_word_count`, :func:`ltrj_word_count`).
    """

    direction: Direction
    words: int
    variable: bool = False


COMMANDS: dict[Cmd, CommandInfo] = {
    Cmd.RESET: CommandInfo(Direction.NONE, 0),
    Cmd.STT: CommandInfo(Direction.NONE, 0),
    Cmd.DFH: CommandInfo(Direction.NONE, 0),
    Cmd.SIP: CommandInfo(Direction.NONE, 0),
    Cmd.UDF: CommandInfo(Direction.NONE, 0),
    Cmd.PORT8: CommandInfo(Direction.NONE, 0),
    Cmd.PORT12: CommandInfo(Direction.NONE, 0),
    Cmd.RDDV: CommandInfo(Direction.READ, 2),
    Cmd.RDDP: CommandInfo(Direction.READ, 2),
    Cmd.RDIP: CommandInfo(Direction.READ, 2),
    Cmd.RDRP: CommandInfo(Direction.READ, 2),
    Cmd.RDRV: CommandInfo(Direction.READ, 1),
    Cmd.RDSIGS: CommandInfo(Direction.READ, 1),
    Cmd.RDSUM: CommandInfo(Direction.READ, 1),
    Cmd.LPES: CommandInfo(Direction.WRITE, 1),
    Cmd.LPEI: CommandInfo(Direction.WRITE, 1),
    Cmd.MSKI: CommandInfo(Direction.WRITE, 1),
    Cmd.RSTI: CommandInfo(Direction.WRITE, 1),
    Cmd.LFIL: CommandInfo(Direction.WRITE, 1, variable=True),
    Cmd.LTRJ: CommandInfo(Direction.WRITE, 1, variable=True),
    Cmd.SBPA: CommandInfo(Direction.WRITE, 2),
    Cmd.SBPR: CommandInfo(Direction.WRITE, 2),
}


class Status(enum.IntFlag):
    """The status byte (RDSTAT), bits 0..7."""

    BUSY = 0x01
    COMMAND_ERROR = 0x02
    TRAJECTORY_COMPLETE = 0x04
    INDEX_PULSE = 0x08
    WRAPAROUND = 0x10
    POSITION_ERROR = 0x20
    BREAKPOINT = 0x40
    MOTOR_OFF = 0x80


#: The six interrupt conditions (status bits 1..6): what MSKI enables and RSTI clears.
INTERRUPTS = (
    Status.COMMAND_ERROR
    | Status.TRAJECTORY_COMPLETE
    | Status.INDEX_PULSE
    | Status.WRAPAROUND
    | Status.POSITION_ERROR
    | Status.BREAKPOINT
)


class Signals(enum.IntFlag):
    """The signals register (RDSIGS), 16 bits.  Bits 7..1 repeat the status byte."""

    ACQUIRE_INDEX = 0x0001
    COMMAND_ERROR = 0x0002
    TRAJECTORY_COMPLETE = 0x0004
    INDEX_PULSE = 0x0008
    WRAPAROUND = 0x0010
    POSITION_ERROR = 0x0020
    BREAKPOINT = 0x0040
    MOTOR_OFF = 0x0080
    EIGHT_BIT_OUTPUT = 0x0100
    STOP_ON_ERROR = 0x0200
    ON_TARGET = 0x0400
    VELOCITY_MODE = 0x0800
    FORWARD = 0x1000
    FILTER_UPDATED = 0x2000
    ACCELERATION_LOADED = 0x4000
    HOST_INTERRUPT = 0x8000


class FilterFlags(enum.IntFlag):
    """Low byte of the LFIL control word: which coefficients follow, in this order."""

    KP = 0x08
    KI = 0x04
    KD = 0x02
    IL = 0x01


#: LFIL coefficients in the order their words follow the control word.
FILTER_ORDER = (FilterFlags.KP, FilterFlags.KI, FilterFlags.KD, FilterFlags.IL)

#: :attr:`Status.BUSY` as a plain int, for the busy-poll loops (IntFlag arithmetic costs
#: microseconds there)
BUSY_BIT = int(Status.BUSY)


def s16(value: int) -> int:
    """A 16-bit word as the chip's two's complement (signed words: velocities, errors)."""
    value &= 0xFFFF
    return value - (1 << 16) if value & 0x8000 else value


def wrap_counts(value: int) -> int:
    """A whole-count position, or a difference of two, folded into the position register's
    range [-2^30, 2^30) (C0000000..3FFFFFFF): the circle the register runs round, taken the
    short way (AN-706 6.5.2).  The chip model's registers and the host's extended positions
    both fold here."""
    return ((value + (1 << 30)) & 0x7FFFFFFF) - (1 << 30)


def s32(value: int) -> int:
    """A 32-bit pattern as the chip's two's complement (positions, 16.16 velocities)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value & 0x80000000 else value


def s32_words(hi: int, lo: int) -> int:
    """A 32-bit register read as two words, high first (RDDP, RDRP, RDIP, RDDV), as the chip's
    two's complement."""
    return s32((hi << 16) | lo)


class TrajectoryFlags(enum.IntFlag):
    """The LTRJ control word."""

    POSITION_RELATIVE = 0x0001
    POSITION = 0x0002
    VELOCITY_RELATIVE = 0x0004
    VELOCITY = 0x0008
    ACCELERATION_RELATIVE = 0x0010
    ACCELERATION = 0x0020
    MOTOR_OFF = 0x0100
    STOP_ABRUPT = 0x0200
    STOP_SMOOTH = 0x0400
    VELOCITY_MODE = 0x0800
    FORWARD = 0x1000


STOP_FLAGS = TrajectoryFlags.MOTOR_OFF | TrajectoryFlags.STOP_ABRUPT | TrajectoryFlags.STOP_SMOOTH


def lfil_control(interval: int) -> int:
    """The LFIL control word's high byte for a derivative interval of ``interval`` samples
    (1..256): the chip takes the derivative every (byte + 1) samples.  Everywhere else
    ``ds`` is the interval; this and :func:`lfil_interval` are the only crossings."""
    return (interval - 1) << 8


def lfil_interval(control: int) -> int:
    """The derivative interval, samples, an LFIL control word sets."""
    return ((control >> 8) & 0xFF) + 1


def lfil_word_count(control: int) -> int:
    """Data words after the LFIL control word: one per flagged coefficient."""
    return bin(control & 0x0F).count("1")


def ltrj_word_count(control: int) -> int:
    """Data words after the LTRJ control word: two per flagged parameter."""
    return 2 * sum(
        1
        for f in (TrajectoryFlags.ACCELERATION, TrajectoryFlags.VELOCITY, TrajectoryFlags.POSITION)
        if control & f
    )


# --- ranges (datasheet) -------------------------------------------------------------------
COEFFICIENT_MAX = 0x7FFF  #: kp, ki, kd, il and the position-error thresholds: 0..7FFF
POSITION_MIN = -0x40000000  #: C0000000 as signed
POSITION_MAX = 0x3FFFFFFF
VELOCITY_MAX = 0x3FFFFFFF  #: unsigned 16.16
ACCELERATION_MAX = 0x3FFFFFFF  #: unsigned 16.16
DERIVATIVE_INTERVAL_MAX = 256  #: samples; the LFIL word's high byte holds interval - 1
#: 1.0 in the chip's unsigned 16.16 fixed point: one count per sample (velocity words), per
#: sample^2 (acceleration words), and the 16 fraction bits below the position register
FIXED_ONE = 1 << 16

# --- timing (datasheet, AN-706) -------------------------------------------------------------
BUSY_WORST_CASE_S = 100e-6  #: the chip never holds busy longer than this after a transfer
RESET_WAIT_S = 1.5e-3  #: after /RST, status is 84/C4 within this time
SAMPLE_CLOCKS = 2048  #: one sample every 2048 chip clocks
#: AN-706 4.6.2: a new STT aborts the chip's trajectory calculation (its output stays at the
#: last sample's value), so "trajectory is not updated at a greater rate than once every 10 ms"
UPDATE_INTERVAL_S = 10e-3
#: the clock assumed where the transport cannot say (hardware): the 8 MHz parts' rate
NOMINAL_CLOCK_HZ = 8_000_000
RESET_DONE_STATUSES = (0x84, 0xC4)
RESET_CLEARED_STATUSES = (0x80, 0xC0)
