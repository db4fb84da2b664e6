"""The USB adapter between the host and a simulated bridge, on the simulated clock.

Every simulated serial link is otherwise instant between the host and the bridge's UART; a
real bench has a USB chip in between that holds the bridge's replies back.  :class:`UsbPipe`
sits between the host side of an emulated serial line (:class:`~.bridge.EmuPipe`,
:class:`~.avr.AvrPipe`, or a fault wrapper around one) and the link transport, and delays the
bytes each way as the chosen adapter would (``usb=`` on ``sim+emu://``, ``sim+avr://`` and
``lm629 sim serve``; docs/usb.md has the sources of every figure):

``uno``
    the ATmega16U2 of an Arduino Uno R3 running Arduino-usbserial (LUFA).  Bytes from the
    bridge's UART wait in a 128-byte ring buffer; the main loop moves them to the USB IN
    endpoint only when its free-running Timer0 has overflowed (clk/256 from 16 MHz, 8 bits:
    every 4.096 ms) or when more than 96 bytes wait.  The timer's phase is drawn from
    ``usb_seed`` (deterministic for a seed): it is unrelated to the host's requests.
``ftdi``
    an FT232R / FT231X: bytes wait until a 64-byte packet is full (2 modem-status bytes + 62
    data) or the latency timer (``latency_ms``, 16 by default, 1 with the driver's low-latency
    mode) expires; every packet sent (the status-only ones the chip sends each time the timer
    expires with nothing to say included) starts the timer again.
``cdc``
    a native full-speed device (ATmega32U4, RP2040): the firmware writes the IN endpoint
    itself, so a byte leaves as soon as it is written.

For all three, full-speed USB moves data in 1 ms frames: a host write goes out at the next
frame start (at once when written exactly at one), and bytes the device has released reach
the reading program at the first frame start after their release (the host controller reports
completed transfers at frame boundaries).  ``none`` (the default) is no adapter: the pipe is
not wrapped at all.

Time is the inner pipe's clock; the wrapper only ever advances it through the inner pipe's
``read`` (which runs the far end), so nothing here sleeps on the wall clock, and the
transport's ``clock.sleep`` runs the USB events too (:class:`UsbClock`).
"""

from __future__ import annotations

import abc
import math
import random
from collections import deque
from typing import Any

from lm629_host.clock import Clock
from lm629_host.urls import Option, PortURL, query_params

#: full-speed USB frame (USB 2.0, 8.4.3: a SOF every 1.000 ms)
FRAME_S = 1e-3
#: the 16U2's flush timer: Timer0 at clk/256 from 16 MHz, overflowing every 256 counts
UNO_FLUSH_S = 256 * 256 / 16e6
#: Arduino-usbserial's UART -> USB ring buffer, and the count above which it flushes at once
UNO_BUFFER_BYTES = 128
UNO_NEARLY_FULL = 96
#: data bytes in one FT232R/FT231X bulk IN packet (64 bytes less 2 modem-status bytes)
FTDI_PACKET_DATA = 62
#: the FTDI latency timer when nobody set it (AN232B-04)
FTDI_DEFAULT_LATENCY_MS = 16

MODELS = ("none", "uno", "ftdi", "cdc")
#: the URL options of the USB model (``usb=uno&usb_seed=3``, ``usb=ftdi&latency_ms=1``)
OPTIONS = (Option("usb", "str", "none", choices=MODELS),
           Option("usb_seed", "int", 0, 0, 2**31 - 1),
           Option("latency_ms", "int", FTDI_DEFAULT_LATENCY_MS, 1, 255, "ms"))

#: slack when comparing simulated times: the inner clocks round to whole cycles (62.5 ns on the
#: AVR), so a time within 1 us of a frame start or a timer event counts as at it
_EPS = 1e-6


def next_frame(t: float) -> float:
    """The first full-speed frame start at or after ``t`` (frames start at 0, 1 ms, ...)."""
    return math.ceil((t - _EPS) / FRAME_S) * FRAME_S


def _grid_after(origin: float, period: float, t: float) -> float:
    """The first ``origin + k * period`` (k an integer) at or after ``t``."""
    return origin + math.ceil((t - _EPS - origin) / period) * period


class Adapter(abc.ABC):
    """The device side of one USB serial adapter: when the bytes that came in on its UART are
    released to the bus.  Subclasses hold the bytes; :class:`UsbPipe` does the frames."""

    name = ""

    def __init__(self) -> None:
        self.held = bytearray()
        self.held_since = 0.0  #: when the oldest held byte arrived

    #: the longest a byte can be held plus the frames each way: what a reply timeout adds
    @property
    @abc.abstractmethod
    def worst_s(self) -> float: ...

    def receive(self, t: float, data: bytes) -> list[tuple[float, bytes]]:
        """Bytes in from the UART at ``t``; returns what is released at once (release time,
        bytes)."""
        if not self.held:
            self.held_since = t
        self.held += data
        return []

    def next_timer(self, now: float) -> float | None:
        """When held bytes will be released by a timer (None: nothing held or no timer)."""
        return None

    def expire(self, now: float) -> list[tuple[float, bytes]]:
        """The releases whose timer has run out by ``now``."""
        return []

    def _release(self, n: int | None = None) -> bytes:
        n = len(self.held) if n is None else n
        out = bytes(self.held[:n])
        del self.held[:n]
        return out

    def describe(self) -> str:
        return self.name


class Uno(Adapter):
    """Arduino Uno R3: the 16U2 running Arduino-usbserial (flush tick or more than 96 bytes)."""

    name = "uno"

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        #: the first Timer0 overflow after time 0 (the timer ran before the host looked)
        self.phase = random.Random(seed).random() * UNO_FLUSH_S
        self.ticks = 0  #: flushes on the timer that carried bytes
        self.full_flushes = 0  #: flushes because more than 96 bytes waited

    @property
    def worst_s(self) -> float:
        return UNO_FLUSH_S + 2 * FRAME_S

    def overflow_after(self, t: float) -> float:
        """The first Timer0 overflow at or after ``t``."""
        return _grid_after(self.phase, UNO_FLUSH_S, t)

    def receive(self, t: float, data: bytes) -> list[tuple[float, bytes]]:
        out: list[tuple[float, bytes]] = []
        for i in range(len(data)):  # byte by byte: the main loop sees the count grow
            super().receive(t, data[i:i + 1])
            if len(self.held) > UNO_NEARLY_FULL:
                self.full_flushes += 1
                out.append((t, self._release()))
        return out

    def next_timer(self, now: float) -> float | None:
        return self.overflow_after(self.held_since) if self.held else None

    def expire(self, now: float) -> list[tuple[float, bytes]]:
        at = self.next_timer(now)
        if at is None or at > now + _EPS:
            return []
        self.ticks += 1
        return [(at, self._release())]

    def describe(self) -> str:
        return f"uno (16U2 flush tick {UNO_FLUSH_S * 1e3:.3f} ms, phase {self.phase * 1e3:.3f} ms)"


class Ftdi(Adapter):
    """FT232R / FT231X: a full packet (62 data bytes) or the latency timer."""

    name = "ftdi"

    def __init__(self, latency_ms: int = FTDI_DEFAULT_LATENCY_MS, seed: int = 0) -> None:
        super().__init__()
        self.latency_s = latency_ms * 1e-3
        #: when the timer last started (a packet went out): its phase, drawn from the seed
        self.started = -random.Random(seed).random() * self.latency_s

    @property
    def worst_s(self) -> float:
        return self.latency_s + 2 * FRAME_S

    def receive(self, t: float, data: bytes) -> list[tuple[float, bytes]]:
        if not self.held:  # the status-only packets restarted the timer on its grid meanwhile
            self.started = _grid_after(self.started, self.latency_s, t) - self.latency_s
        super().receive(t, data)
        out: list[tuple[float, bytes]] = []
        while len(self.held) >= FTDI_PACKET_DATA:  # a full packet goes out without waiting
            out.append((t, self._release(FTDI_PACKET_DATA)))
            self.started = t
            self.held_since = t
        return out

    def next_timer(self, now: float) -> float | None:
        if not self.held:
            return None
        return _grid_after(self.started, self.latency_s, self.held_since + 2 * _EPS)

    def expire(self, now: float) -> list[tuple[float, bytes]]:
        at = self.next_timer(now)
        if at is None or at > now + _EPS:
            return []
        self.started = at
        return [(at, self._release())]

    def describe(self) -> str:
        return f"ftdi (latency timer {self.latency_s * 1e3:g} ms)"


class Cdc(Adapter):
    """A native full-speed device: bytes leave as they are written."""

    name = "cdc"

    @property
    def worst_s(self) -> float:
        return 2 * FRAME_S

    def receive(self, t: float, data: bytes) -> list[tuple[float, bytes]]:
        return [(t, bytes(data))]

    def describe(self) -> str:
        return "cdc (native full-speed device)"


def adapter_of(url: str | PortURL, opts: dict[str, Any]) -> Adapter | None:
    """The adapter that ``url``'s ``usb=`` names (None for ``usb=none``), from ``opts``: the
    URL as its transport parsed it, once, against a table with these :data:`OPTIONS` (with
    their defaults); ``url`` only says which of them it gave, and names itself in a message."""
    kind = opts["usb"]
    if "latency_ms" in query_params(url) and kind != "ftdi":
        raise ValueError(f"{url}: latency_ms= is the FTDI latency timer: it needs usb=ftdi")
    if kind == "uno":
        return Uno(opts["usb_seed"])
    if kind == "ftdi":
        return Ftdi(opts["latency_ms"], opts["usb_seed"])
    if kind == "cdc":
        return Cdc()
    return None


class UsbClock(Clock):
    """The inner pipe's clock, whose ``sleep`` also runs the USB events (a write that goes out
    at the next frame, a flush tick) while the host waits."""

    def __init__(self, pipe: UsbPipe) -> None:
        self._pipe = pipe
        self._inner = pipe.inner.clock

    def now(self) -> float:
        return self._inner.now()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._pipe.run(self._inner.now() + seconds, stop_on_data=False)


class UsbPipe:
    """``UsbPipe(inner, adapter)``: a :class:`~lm629_host.bridge.protocol.Pipe` that passes
    ``inner``'s bytes through ``adapter`` and 1 ms frames each way."""

    def __init__(self, inner: Any, adapter: Adapter) -> None:
        self.inner = inner
        self.adapter = adapter
        self.clock = UsbClock(self)
        self._now = inner.clock.now
        self._out: deque[tuple[float, bytes]] = deque()  # (frame it goes out in, bytes)
        self._in: deque[tuple[float, bytes]] = deque()  # (frame the host sees it in, bytes)
        self._host = bytearray()  # arrived, not yet read
        self.closed = False

    def __getattr__(self, name: str) -> Any:
        # the inner line's own attributes (an EmuPipe's rate, an AvrPipe's sim) stay reachable
        return getattr(self.inner, name)

    def write(self, data: bytes) -> None:
        at = next_frame(self._now())
        if self._out and self._out[-1][0] == at:
            self._out[-1] = (at, self._out[-1][1] + bytes(data))
        else:
            self._out.append((at, bytes(data)))

    def read(self, timeout_s: float) -> bytes:
        if not self._host:
            self.run(self._now() + max(0.0, timeout_s), stop_on_data=True)
        out = bytes(self._host)
        self._host.clear()
        return out

    def _released(self, releases: list[tuple[float, bytes]]) -> None:
        for at, data in releases:
            if data:
                self._in.append((next_frame(at), data))

    def run(self, until: float, *, stop_on_data: bool) -> None:
        """Run the line and the adapter up to ``until`` (or, with ``stop_on_data``, to the
        first frame that brings the host bytes)."""
        inner, adapter, out, inn = self.inner, self.adapter, self._out, self._in
        while True:
            now = self._now()
            while out and out[0][0] <= now + _EPS:
                inner.write(out.popleft()[1])
            self._released(adapter.expire(now))
            while inn and inn[0][0] <= now + _EPS:
                self._host += inn.popleft()[1]
            if (stop_on_data and self._host) or now >= until - _EPS:
                return
            nxt = until
            if out:
                nxt = min(nxt, out[0][0])
            if inn:
                nxt = min(nxt, inn[0][0])
            timer = adapter.next_timer(now)
            if timer is not None:
                nxt = min(nxt, timer)
            data = inner.read(max(0.0, nxt - now))
            if data:
                self._released(adapter.receive(self._now(), data))

    def set_baud(self, baud: int) -> None:
        """The host's line coding: the adapter's UART runs at ``baud`` from now on."""
        self.inner.set_baud(baud)

    def reset_input(self) -> None:
        self._host.clear()
        self._in.clear()

    def close(self) -> None:
        self.closed = True
        self.inner.close()


def wrap_usb(pipe: Any, adapter: Adapter | None) -> Any:
    """``pipe`` behind ``adapter`` (:func:`adapter_of`; ``pipe`` itself for None: ``usb=none``)."""
    return pipe if adapter is None else UsbPipe(pipe, adapter)


__all__ = ["Adapter", "Cdc", "FRAME_S", "Ftdi", "MODELS", "OPTIONS",
           "UNO_FLUSH_S", "UNO_NEARLY_FULL", "Uno", "UsbClock", "UsbPipe", "adapter_of",
           "next_frame", "wrap_usb"]
