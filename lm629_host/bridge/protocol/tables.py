"""The protocol's constants as the firmware sees them: what ``tools/gen_tables.py`` writes
into ``firmware_bridge/lm629_tables.h``, so that the firmware never keeps its own copy."""

from __future__ import annotations

from lm629_host.bridge.protocol.constants import (
    BAUD_WINDOW_MS,
    CODE_BYTES,
    CODE_SLOTS,
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FAILSAFE_STOP_BITS,
    FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
    FIRMWARE_VERSION,
    MAX_FRAME,
    MAX_PING,
    MAX_WIRE_FRAME,
    NONE_BYTE,
    PROFILE_MAX_PIECES,
    PROFILE_MAX_SCHEDULE,
    PROFILE_MIN_SPACING_US,
    PROFILE_NEW,
    PROTOCOL_VERSION,
    RECORD_CMD_FIRST,
    RECORD_CMD_LAST,
    RECORD_MAX_BYTES,
    RECORD_MAX_PROGRAM,
    RECORD_MIN_PERIOD_US,
    RECORD_TICK_US,
    RUN_OVERHEAD,
    RUN_REPLY_OVERHEAD,
    RUN_SHORT_OVERHEAD,
    RUN_SHORT_REPLY_OVERHEAD,
    Capability,
    FailsafeAction,
    FailsafeCmd,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.failsafe import FAILSAFE_FEED, FailsafeState
from lm629_host.bus.opcodes import TrajectoryFlags


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
