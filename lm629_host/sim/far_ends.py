"""The far ends ``lm629 sim serve`` serves (:mod:`.serve`): a simulated bridge as bytes in,
reply bytes out and a simulated clock the server keeps level with the wall clock.

The Python bridge (:class:`~lm629_host.sim.bridge.BridgeEmulator`) is driven straight
(:class:`EmuFarEnd`); the compiled firmware in simavr (:func:`firmware_far_end`), or either one
behind a USB adapter's latency (``usb=uno|ftdi|cdc``, :mod:`.usb`), sits behind a simulated
:class:`~lm629_host.bridge.protocol.Pipe` (:class:`PipeFarEnd`), whose replies are waited for
on the pipe's clock so that a client gets whole replies.
"""

from __future__ import annotations

import abc
import math
from collections import deque

from lm629_host.urls import PortURL
from lm629_host.bridge.protocol.constants import MAX_WIRE_FRAME, FrameType
from lm629_host.bridge.protocol.framing import Frame, FrameReader
from lm629_host.bridge.protocol.run import BadProgram, decode_program
from lm629_host.bus.program import Op
from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
from lm629_host.sim.build import SERVED_OPTIONS, build_bus, sim_options
from lm629_host.sim.wiring import Miswiring, wiring_of
from lm629_host.sim.model import ChipBus, ChipModel
from lm629_host.sim.usb import UsbPipe, adapter_of, wrap_usb


class FarEnd(abc.ABC):
    """What the server needs from a far end: bytes in, reply bytes out, a simulated clock that
    the server keeps level with the wall clock, and the chip model."""

    model: ChipModel | ChipBus

    @abc.abstractmethod
    def receive(self, data: bytes) -> list[bytes]: ...

    @abc.abstractmethod
    def now(self) -> float: ...

    @abc.abstractmethod
    def advance_to(self, t: float) -> bytes:
        """Run the far end up to simulated time ``t``; returns bytes it sent meanwhile."""

    @abc.abstractmethod
    def describe(self) -> str: ...

    def close(self) -> None:  # noqa: B027 - optional: a far end may hold nothing
        pass

    @property
    def owes_reply(self) -> bool:
        """A request is still running on the far end (its reply comes later, with time)."""
        return False


class EmuFarEnd(FarEnd):
    """The Python bridge over the model, driven straight."""

    def __init__(self, model: ChipModel | ChipBus, wiring: Miswiring | None = None) -> None:
        self.model = model  # one chip, or a ChipBus (``--url 'sim://?axes=2'``)
        self.emulator = BridgeEmulator(model, wiring=wiring)

    def receive(self, data: bytes) -> list[bytes]:
        return self.emulator.receive(data)

    def now(self) -> float:
        return self.model.now()

    def advance_to(self, t: float) -> bytes:
        """Up to ``t``, with the rows of a recording (RECORD), the pieces of a shaped move
        (PROFILE) and the failsafe's expiry that fall due on the way, each run at its time:
        rows go out together, stamped with the bridge's clock."""
        emu, out = self.emulator, bytearray()
        while (due := emu.far_due) is not None and due <= t:
            self.model.advance_to(max(self.model.tick, math.ceil(due * self.model.clock_hz - 1e-6)))
            out += b"".join(emu.far_step())
        self.model.advance_to(max(self.model.tick, int(t * self.model.clock_hz)))
        return bytes(out)

    def describe(self) -> str:
        return f"Python bridge emulator (firmware {self.emulator.info.firmware_version})"


class PipeFarEnd(FarEnd):
    """Any bridge behind a simulated :class:`~lm629_host.bridge.protocol.Pipe` (the compiled firmware in
    simavr).  Bytes go in through the pipe; for each good request the server waits, on the
    pipe's simulated clock, for the reply frame (up to the per-request timeout the host would
    compute), so that a pty client gets whole replies."""

    #: added to each per-request wait, simulated seconds
    MARGIN_S = 0.05
    #: the longest a request's reply is waited for in one go, simulated seconds: a longer
    #: program (a WAIT_STATUS of seconds) goes on with the wall clock, so that the bytes a
    #: host sends meanwhile (a new client's HELLO) reach the far end at their time
    AHEAD_S = 0.1

    def __init__(self, pipe, model: ChipModel | ChipBus, name: str, *, baud: int | None = None) -> None:
        self.pipe = pipe
        self.model = model
        self.name = name
        self.baud = baud
        self._requests = FrameReader()
        self._replies = FrameReader()
        #: programs the far end keeps by code (RUN_STORE), to time a RUN_CODE's reply
        self._codes: dict[int, bytes] = {}
        #: when each request whose reply has not come out yet stops being owed (simulated
        #: seconds: a request lost on the line, at a rate the far end does not speak, is
        #: never answered)
        self._owed: deque[float] = deque()

    def _timeout(self, frame: Frame) -> float:
        t = self.MARGIN_S + (2 * MAX_WIRE_FRAME * 10 / self.baud if self.baud else 0.0)
        if isinstance(self.pipe, UsbPipe):
            t += self.pipe.adapter.worst_s
        ftype, payload = frame.type, frame.payload
        program: bytes | None = None
        if ftype == FrameType.HELLO:
            self._codes.clear()  # the far end forgets its codes too
        elif ftype == FrameType.RUN_SHORT:
            program = payload
        elif ftype == FrameType.RUN_STORE and payload:
            program = payload[1:]
            self._codes[payload[0]] = program
        elif ftype == FrameType.RUN_CODE and len(payload) == 1:
            program = self._codes.get(payload[0], b"")
        elif ftype == FrameType.RUN and len(payload) >= 3:
            program = payload[3:]
        if program is not None:
            # the compact forms run with the default busy timeout
            busy = ((int.from_bytes(payload[1:3], "big") if ftype == FrameType.RUN else 0)
                    or 5000) * 1e-6
            try:
                ops = decode_program(program)
            except BadProgram:
                return t
            for o in ops:
                if o.op is Op.WAIT:
                    t += o.arg * 1e-6
                elif o.op is Op.WAIT_STATUS:  # as LinkTransport.reply_timeout
                    t += (o.arg & 0xFFFF) * 1e-3 * 1.1 + 0.01
                elif o.op is not Op.STATUS and o.op is not Op.RESET:
                    t += busy
        return t

    def receive(self, data: bytes) -> list[bytes]:
        self.pipe.write(data)
        waits = [self._timeout(f) for f in self._requests.feed(data)
                 if isinstance(f, Frame) and not f.type & 0x80]
        now = self.pipe.clock.now()
        self._owed.extend(now + timeout for timeout in waits)
        out = bytearray()
        for timeout in waits:
            deadline = self.pipe.clock.now() + min(timeout, self.AHEAD_S)
            while self._owed:
                left = deadline - self.pipe.clock.now()
                if left <= 0:
                    break
                chunk = self.pipe.read(left)
                if not chunk:
                    break
                out += chunk
                self._count_replies(chunk)
        return [bytes(out)] if out else []

    def _count_replies(self, data: bytes) -> None:
        """Settle what is owed with the frames in ``data`` (a RECORD's answer is its first
        row; the rows after it, and a failsafe report, settle nothing that is not owed)."""
        for f in self._replies.feed(data):
            if isinstance(f, Frame):
                if self._owed:
                    self._owed.popleft()

    @property
    def owes_reply(self) -> bool:
        owed, now = self._owed, self.pipe.clock.now()
        while owed and owed[0] < now:
            owed.popleft()
        return bool(owed)

    def now(self) -> float:
        return self.pipe.clock.now()

    def advance_to(self, t: float) -> bytes:
        out = bytearray()
        while (left := t - self.pipe.clock.now()) > 0:  # all of it: a recording's rows too
            data = self.pipe.read(left)
            if not data:
                break
            out += data
        if out:
            self._count_replies(bytes(out))
        return bytes(out)

    def describe(self) -> str:
        return self.name

    def close(self) -> None:
        self.pipe.close()


class _PtyLine(EmuPipe):
    """The Python bridge's serial line when a pseudo-terminal stands for the host's port: a
    pty carries bytes at any rate (the client's SET_BAUD changes nothing on it), so no byte is
    lost to a rate mismatch, and no wire time is charged (``baud=None``)."""

    def _carried(self, rate: int, receiver: int) -> bool:
        return True


def emulator_far_end(url: str | PortURL) -> FarEnd:
    """The Python bridge over a chip model built from ``url``; with ``usb=`` behind that USB
    adapter (:mod:`.usb`)."""
    opts = sim_options(url, SERVED_OPTIONS, defaults=True)  # the one parse of the URL
    model = build_bus(url, opts)
    adapter, wiring = adapter_of(url, opts), wiring_of(url, opts)
    if adapter is None:
        return EmuFarEnd(model, wiring)
    pipe = UsbPipe(_PtyLine(BridgeEmulator(model, wiring=wiring), baud=None), adapter)
    return PipeFarEnd(pipe, model, f"Python bridge emulator behind USB {adapter.describe()}")


def firmware_far_end(url: str | PortURL) -> FarEnd:
    """The compiled bridge firmware in simavr (:mod:`.avr`, 115200 baud) as a far end, over a
    chip model built from the simulator options of ``url`` (with ``usb=``: behind that USB
    adapter).  Raises RuntimeError saying what is missing when the firmware or the harness
    cannot run."""
    from lm629_host.wiring.uno import CHIP_SELECTS
    from lm629_host.sim.avr import AvrPipe, AvrSim
    from lm629_host.sim.harness import DEFAULT_BAUD, HarnessError

    opts = sim_options(url, SERVED_OPTIONS, defaults=True)  # before the firmware is built
    adapter = adapter_of(url, opts)
    model = build_bus(url, opts, limit=len(CHIP_SELECTS))
    if isinstance(model, ChipBus):
        model.lines = len(CHIP_SELECTS)  # the firmware's four /CS, chips on the first N
    try:
        sim = AvrSim(model, wiring=wiring_of(url, opts))
    except (HarnessError, OSError) as exc:
        raise RuntimeError(f"--firmware runs the compiled firmware in simavr: {exc}. Build it "
                           "with `make -C firmware_bridge` (needs gcc-avr, avr-libc, simavr, "
                           "libsimavr-dev), or serve the Python bridge without --firmware.") from None
    name = "bridge firmware in simavr" + (f" behind USB {adapter.describe()}" if adapter else "")
    return PipeFarEnd(wrap_usb(AvrPipe(sim), adapter), model, name, baud=DEFAULT_BAUD)


__all__ = ["EmuFarEnd", "FarEnd", "PipeFarEnd", "emulator_far_end", "firmware_far_end"]
