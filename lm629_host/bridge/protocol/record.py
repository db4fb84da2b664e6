"""RECORD's payloads: a sample program the bridge runs on its own timer, the rows it streams."""

from __future__ import annotations

import struct
from collections.abc import Sequence

from lm629_host.bridge.protocol.constants import (
    RECORD_CMD_FIRST,
    RECORD_CMD_LAST,
    RECORD_MAX_BYTES,
    RECORD_MAX_PROGRAM,
    RECORD_ROW_OVERHEAD,
)
from lm629_host.bridge.protocol.run import BadProgram, encode_program
from lm629_host.bus.program import STATUS_OPS, BusOp, Op

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
