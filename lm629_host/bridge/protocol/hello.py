"""HELLO_REPLY's payload: what a bridge is and what it can take."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from lm629_host.bridge.protocol.constants import MAX_FRAME, PROTOCOL_VERSION, RUN_OVERHEAD, RUN_REPLY_OVERHEAD, Capability
from lm629_host.bridge.protocol.framing import FrameError


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
