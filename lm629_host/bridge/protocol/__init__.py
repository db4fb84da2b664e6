"""The bridge link protocol (``firmware_bridge/PROTOCOL.md``, version 1), both ends' bytes, one
module per job:

* :mod:`.constants`: versions, sizes, frame types, result codes, capability bits, defined here once
  and written into the firmware's ``lm629_tables.h`` by :mod:`.tables` (``tools/gen_tables.py``);
* :mod:`.framing`: COBS framing and CRC-16/GENIBUS, a frame codec and a resynchronising
  :class:`~.framing.FrameReader`;
* the payload codecs, shared by the host (:mod:`lm629_host.transports.link`) and the Python far
  end (:mod:`lm629_host.sim.bridge`) so that both speak exactly the same bytes: :mod:`.hello`
  (HELLO_REPLY), :mod:`.run` (RUN, RUN_SHORT and their replies), :mod:`.record`, :mod:`.failsafe`,
  :mod:`.profile`;
* :mod:`.pipe`: what a byte stream to a bridge must offer.

No I/O here.  This package offers every name of its parts, so an importer may take them from
here or from their home.
"""

from __future__ import annotations

from lm629_host.bridge.protocol.constants import (
    PROTOCOL_VERSION,
    FIRMWARE_VERSION,
    MAX_FRAME,
    MAX_WIRE_FRAME,
    FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
    RUN_OVERHEAD,
    RUN_REPLY_OVERHEAD,
    RUN_SHORT_OVERHEAD,
    RUN_SHORT_REPLY_OVERHEAD,
    MAX_PING,
    CODE_SLOTS,
    CODE_BYTES,
    BAUD_WINDOW_MS,
    FAST_BAUD,
    RECORD_MAX_PROGRAM,
    RECORD_MAX_BYTES,
    RECORD_MIN_PERIOD_US,
    RECORD_TICK_US,
    RECORD_ROW_OVERHEAD,
    RECORD_CMD_FIRST,
    RECORD_CMD_LAST,
    FAILSAFE_MIN_MS,
    FAILSAFE_MAX_MS,
    PROFILE_MIN_SPACING_US,
    PROFILE_NEW,
    PROFILE_PIECE,
    PROFILE_HEADER,
    PROFILE_MAX_PIECES,
    PROFILE_MAX_SCHEDULE,
    FrameType,
    REPLY_TO,
    ALSO_REPLY_TO,
    RUN_TYPES,
    Result,
    Capability,
    FailsafeCmd,
    FailsafeAction,
    FAILSAFE_STOP_BITS,
    NONE_BYTE,
)
from lm629_host.bridge.protocol.framing import (
    crc16,
    FrameError,
    cobs_encode,
    cobs_decode,
    Frame,
    frame_body,
    encode_frame,
    decode_body,
    decode_frame,
    FrameReader,
    wire_size,
)
from lm629_host.bridge.protocol.hello import (
    HelloInfo,
)
from lm629_host.bridge.protocol.run import (
    encode_program,
    BadProgram,
    decode_program,
    busy_timeout_us,
    RUN_HEADER,
    run_payload,
    RunReply,
    short_reply_payload,
    decode_short_reply,
    reply_size,
)
from lm629_host.bridge.protocol.record import (
    RECORD_HEADER,
    ROW_HEADER,
    END_PAYLOAD,
    RECORD_OPS,
    record_payload,
    check_record_program,
    row_wire_bytes,
)
from lm629_host.bridge.protocol.failsafe import (
    FailsafeState,
    FAILSAFE_FEED,
)
from lm629_host.bridge.protocol.profile import (
    PROFILE_REPLY_PAYLOAD,
    profile_payload,
    profile_piece_ops,
    ends_a_profile,
)
from lm629_host.bridge.protocol.pipe import (
    Pipe,
)
from lm629_host.bridge.protocol.tables import (
    c_defines,
)

__all__ = [
    "ALSO_REPLY_TO",
    "BAUD_WINDOW_MS",
    "BadProgram",
    "CODE_BYTES",
    "CODE_SLOTS",
    "Capability",
    "END_PAYLOAD",
    "FAILSAFE_FEED",
    "FAILSAFE_MAX_MS",
    "FAILSAFE_MIN_MS",
    "FAILSAFE_STOP_BITS",
    "FAST_BAUD",
    "FIRMWARE_DEFAULT_BUSY_TIMEOUT_US",
    "FIRMWARE_VERSION",
    "FailsafeAction",
    "FailsafeCmd",
    "FailsafeState",
    "Frame",
    "FrameError",
    "FrameReader",
    "FrameType",
    "HelloInfo",
    "MAX_FRAME",
    "MAX_PING",
    "MAX_WIRE_FRAME",
    "NONE_BYTE",
    "PROFILE_HEADER",
    "PROFILE_MAX_PIECES",
    "PROFILE_MAX_SCHEDULE",
    "PROFILE_MIN_SPACING_US",
    "PROFILE_NEW",
    "PROFILE_PIECE",
    "PROFILE_REPLY_PAYLOAD",
    "PROTOCOL_VERSION",
    "Pipe",
    "RECORD_CMD_FIRST",
    "RECORD_CMD_LAST",
    "RECORD_HEADER",
    "RECORD_MAX_BYTES",
    "RECORD_MAX_PROGRAM",
    "RECORD_MIN_PERIOD_US",
    "RECORD_OPS",
    "RECORD_ROW_OVERHEAD",
    "RECORD_TICK_US",
    "REPLY_TO",
    "ROW_HEADER",
    "RUN_HEADER",
    "RUN_OVERHEAD",
    "RUN_REPLY_OVERHEAD",
    "RUN_SHORT_OVERHEAD",
    "RUN_SHORT_REPLY_OVERHEAD",
    "RUN_TYPES",
    "Result",
    "RunReply",
    "busy_timeout_us",
    "c_defines",
    "check_record_program",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "decode_body",
    "decode_frame",
    "decode_program",
    "decode_short_reply",
    "encode_frame",
    "encode_program",
    "ends_a_profile",
    "frame_body",
    "profile_payload",
    "profile_piece_ops",
    "record_payload",
    "reply_size",
    "row_wire_bytes",
    "run_payload",
    "short_reply_payload",
    "wire_size",
]
