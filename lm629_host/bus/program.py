"""Bus programs: what the typed layer hands to a transport.

A bus program is an ordered list of bus operations on one chip.  Each COMMAND, WRITE and READ
operation carries the busy-bit check before it: the transport (or the bridge firmware on its
far side) reads the status byte until bit 0 is clear, for at most the program's busy timeout,
and only then strobes the byte(s).  The typed layer therefore cannot forget a busy check, and a
transport that can poll on its far side runs a whole program in one round trip.

The operation codes below are shared with the bridge firmware through the generated
``firmware_bridge/lm629_tables.h`` (``tools/gen_tables.py``); this is their one definition.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from lm629_host.bus.opcodes import Cmd

#: Default busy timeout: well above the chip's 100 us worst case, and above the 1.5 ms that a
#: software RESET holds busy (the model's documented choice), so that the next busy check after
#: a RESET command waits for it instead of failing.
DEFAULT_BUSY_TIMEOUT_S = 5e-3


class Op(enum.IntEnum):
    """Bus operations.  The values are the wire codes of the bridge protocol."""

    STATUS = 0x01  #: read the status byte (no busy check); the byte is reported in ``statuses``
    COMMAND = 0x02  #: busy check, then write a command byte (/PS low)
    WRITE = 0x03  #: busy check, then write a data word, high byte first (/PS high)
    READ = 0x04  #: busy check, then read a data word, high byte first (/PS high)
    RESET = 0x05  #: pulse /RST low for at least 8 chip clocks
    WAIT = 0x06  #: wait ``arg`` microseconds (0..65535)
    SYNC = 0x07  #: busy check only: read status until busy is clear; reported in ``statuses``
    #: read the status (no busy check) until any bit of a mask is set or a timeout in ms has
    #: passed; the last status read is reported in ``statuses`` (the host judges the timeout).
    #: ``arg`` = mask << 16 | timeout_ms.  Bridges that have it say so in HELLO (capability
    #: WAIT_STATUS); a waiting host then costs one round trip per wait instead of a poll a ms.
    WAIT_STATUS = 0x08
    #: switch chip select: the operations after it go to chip ``arg`` (0..chip selects - 1) on
    #: a multi-axis board.  A program starts on chip 0 (on a bridge: the RUN's ``cs``); /RST
    #: and WAIT concern every chip.  So a synchronized start on several axes is one program.
    SELECT = 0x09


#: how often the far end reads the status during WAIT_STATUS: half a chip sample at 8 MHz (the
#: interrupt bits change at most once a sample), so a bit is seen at most 125 us late; 8 a ms
WAIT_STATUS_POLL_US = 125
#: the longest WAIT_STATUS one operation can carry (16 bits of milliseconds)
WAIT_STATUS_MAX_MS = 0xFFFF


#: How many argument bytes each operation carries on the wire.
OP_ARG_BYTES = {Op.STATUS: 0, Op.COMMAND: 1, Op.WRITE: 2, Op.READ: 0, Op.RESET: 0, Op.WAIT: 2,
                Op.SYNC: 0, Op.WAIT_STATUS: 3, Op.SELECT: 1}
#: the operations that report a status byte in ``ProgramResult.statuses``
STATUS_OPS = frozenset({Op.STATUS, Op.SYNC, Op.WAIT_STATUS})


@dataclass(frozen=True)
class BusOp:
    op: Op
    arg: int = 0

    def describe(self) -> str:
        """Human-readable form used in error messages and traces."""
        if self.op is Op.COMMAND:
            try:
                name = Cmd(self.arg).name
            except ValueError:
                name = "unknown"
            return f"command {self.arg:02X} ({name})"
        if self.op is Op.WRITE:
            return f"write word {self.arg:04X}"
        if self.op is Op.READ:
            return "read word"
        if self.op is Op.STATUS:
            return "status read"
        if self.op is Op.RESET:
            return "/RST pulse"
        if self.op is Op.SYNC:
            return "wait for busy clear"
        if self.op is Op.SELECT:
            return f"select chip {self.arg}"
        if self.op is Op.WAIT_STATUS:
            return f"wait for status {self.arg >> 16:02X} ({self.arg & 0xFFFF} ms)"
        return f"wait {self.arg} us"


# The operations without a varying argument exist once (a BusOp is immutable): building a
# program is part of every command's host cost.
_READ_OP = BusOp(Op.READ)
_STATUS_OP = BusOp(Op.STATUS)
_COMMAND_OPS: dict[int, BusOp] = {}


@dataclass
class Program:
    """An ordered bus program.  Build it with the chaining helpers::

        Program().command(Cmd.LFIL).write(0x0008).write(10).command(Cmd.UDF)
    """

    ops: list[BusOp] = field(default_factory=list)
    busy_timeout_s: float = DEFAULT_BUSY_TIMEOUT_S
    #: the highest chip select the program selects (-1: none), kept as it is built, so that
    #: a transport checks the program's selects against its own in one comparison
    top_select: int = field(default=-1, compare=False, repr=False)

    def command(self, cmd: int) -> Program:
        byte = int(cmd) & 0xFF
        op = _COMMAND_OPS.get(byte)
        if op is None:
            op = _COMMAND_OPS[byte] = BusOp(Op.COMMAND, byte)
        self.ops.append(op)
        return self

    def write(self, word: int) -> Program:
        if not 0 <= word <= 0xFFFF:
            raise ValueError(f"data word {word} is not a 16-bit value (0..FFFF)")
        self.ops.append(BusOp(Op.WRITE, word))
        return self

    def write32(self, value: int) -> Program:
        """A 32-bit value as two words, most significant word first (two's complement)."""
        value &= 0xFFFFFFFF
        return self.write(value >> 16).write(value & 0xFFFF)

    def read(self, count: int = 1) -> Program:
        self.ops.extend([_READ_OP] * count)
        return self

    def status(self) -> Program:
        self.ops.append(_STATUS_OP)
        return self

    def sync(self) -> Program:
        """Wait until busy is clear and record that status byte (e.g. to see the command-error
        bit that the chip sets while it processes a command)."""
        self.ops.append(BusOp(Op.SYNC))
        return self

    def select(self, chip: int) -> Program:
        """The operations after this one go to chip ``chip`` (its /CS), on a multi-axis bus."""
        if not 0 <= chip <= 0xFF:
            raise ValueError(f"chip select {chip} is outside 0..255")
        self.ops.append(BusOp(Op.SELECT, chip))
        self.top_select = max(self.top_select, chip)
        return self

    def reset(self) -> Program:
        self.ops.append(BusOp(Op.RESET))
        return self

    def wait(self, microseconds: int) -> Program:
        if not 0 <= microseconds <= 0xFFFF:
            raise ValueError(f"wait of {microseconds} us is outside 0..65535 us")
        self.ops.append(BusOp(Op.WAIT, microseconds))
        return self

    def wait_status(self, mask: int, timeout_ms: int) -> Program:
        """Wait on the far side for any bit of ``mask`` in the status byte, for at most
        ``timeout_ms``; the last status read is reported (see :attr:`Op.WAIT_STATUS`)."""
        if not 1 <= mask <= 0xFF:
            raise ValueError(f"status mask {mask} is outside 01..FF")
        if not 0 <= timeout_ms <= WAIT_STATUS_MAX_MS:
            raise ValueError(f"wait of {timeout_ms} ms is outside 0..{WAIT_STATUS_MAX_MS} ms")
        self.ops.append(BusOp(Op.WAIT_STATUS, (mask << 16) | timeout_ms))
        return self

    def extend(self, other: Program) -> Program:
        self.ops.extend(other.ops)
        self.top_select = max(self.top_select, other.top_select)
        return self

    def __iter__(self) -> Iterator[BusOp]:
        return iter(self.ops)

    def __len__(self) -> int:
        return len(self.ops)

    @property
    def read_count(self) -> int:
        return sum(1 for o in self.ops if o.op is Op.READ)


@dataclass(frozen=True)
class ProgramResult:
    """What a transport reports after running a program.

    ``words``: the words read by READ operations, in order.  ``statuses``: the bytes read by
    explicit STATUS and SYNC operations, in order.  ``status``: the last status byte seen during the
    program (by a STATUS operation or by the busy check of the last operation), or None when
    the program read none.  ``hi``: the HI line after the program, when the transport can see it.
    """

    words: tuple[int, ...] = ()
    statuses: tuple[int, ...] = ()
    status: int | None = None
    hi: bool | None = None


@dataclass(frozen=True)
class BusCycle:
    """One bus cycle, as passed to a trace callback.

    ``kind`` is one of "reset", "status", "command", "write", "read", "select"; ``value`` is the
    byte for status and command cycles, the 16-bit word for write and read, 0 for reset and
    the chip for select (a /CS change on a multi-axis bus, no strobe).
    """

    kind: str
    value: int

    def __str__(self) -> str:
        if self.kind in ("write", "read"):
            return f"{self.kind:7s} {self.value:04X}"
        if self.kind == "reset":
            return "reset"
        return f"{self.kind:7s} {self.value:02X}"


TraceCallback = Callable[[BusCycle], None]


def cycles_of(program: Iterable[BusOp], result: ProgramResult) -> Iterator[BusCycle]:
    """Reconstruct the data cycles of a program that ran on a far side which reports only its
    results (the bridge): commands, writes and reads with their values, explicit status reads.
    Busy polls done on the far side are not visible here."""
    words = iter(result.words)
    statuses = iter(result.statuses)
    for o in program:
        if o.op is Op.COMMAND:
            yield BusCycle("command", o.arg)
        elif o.op is Op.WRITE:
            yield BusCycle("write", o.arg)
        elif o.op is Op.READ:
            w = next(words, None)
            if w is None:
                return
            yield BusCycle("read", w)
        elif o.op in STATUS_OPS:
            s = next(statuses, None)
            if s is None:
                return
            yield BusCycle("status", s)
        elif o.op is Op.RESET:
            yield BusCycle("reset", 0)
        elif o.op is Op.SELECT:
            yield BusCycle("select", o.arg)
