"""The link's framing (``firmware_bridge/PROTOCOL.md``): CRC-16/GENIBUS, COBS, the frame codec
and a resynchronising :class:`FrameReader`, the same bytes at both ends."""

from __future__ import annotations

from binascii import crc_hqx
from collections.abc import Iterator
from dataclasses import dataclass

from lm629_host.bridge.protocol.constants import MAX_FRAME, MAX_WIRE_FRAME


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


def wire_size(decoded: int) -> int:
    """Bytes on the wire for a decoded frame of ``decoded`` bytes (COBS overhead, delimiter).
    An upper bound: COBS adds one byte per started 254-byte block, plus the code byte."""
    return decoded + 1 + decoded // 254 + 1
