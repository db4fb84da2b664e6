"""An in-process serial line to a :class:`~.link.BridgeEmulator`, in the model's simulated
time (the wire's byte time at a chosen rate), and the host end's clock that runs the far end
while the host sleeps."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

from lm629_host.sim.bridge.link import BridgeEmulator
from lm629_host.sim.clock import SimClock


#: the far end runs on the chip model's simulated clock (the one ``sim://`` uses)
ModelClock = SimClock


class _PipeClock(SimClock):
    """The model's clock seen from the host end of an :class:`EmuPipe`: ``sleep`` also runs
    what the bridge does on its own timer meanwhile (the pieces of a shaped move, rows, the
    bytes on the wire), as a real bridge goes on while the host sleeps."""

    def __init__(self, pipe: EmuPipe) -> None:
        super().__init__(pipe.emulator.model)
        self._pipe = pipe

    def sleep(self, seconds: float) -> None:
        self._pipe.run_far(self.now() + max(0.0, seconds))


def _last_due(queue: Sequence[tuple[Any, ...]], deadline: float) -> float:
    """Arrival time of the last byte of ``queue`` (time-ordered) due by ``deadline``; the first
    byte must be due."""
    last = queue[0][0]
    for item in queue:
        t = item[0]
        if t > deadline:
            break
        last = t
    return last


class EmuPipe:
    """An in-process serial line to a :class:`BridgeEmulator`, in the model's simulated time.

    Each byte takes ``10 / baud`` seconds on the wire in each direction (``baud=None``: no
    wire time); the far end sees a frame when its last byte has arrived, runs it (advancing the
    model) and its reply is on the wire from then on.  ``read`` advances the simulated clock up
    to the next byte or the timeout.
    """

    def __init__(self, emulator: BridgeEmulator, *, baud: int | None = 115200,
                 max_baud: int | None = None) -> None:
        self.emulator = emulator
        self.clock = _PipeClock(self)
        self.byte_s = 10.0 / baud if baud else 0.0
        self._timed = bool(baud)
        #: the host side's rate; a byte sent at another rate than the receiver's is lost (as
        #: garbage would be), and so is one above ``max_baud`` (a line or USB serial adapter
        #: that cannot carry it)
        self.rate = baud or 0
        self.max_baud = max_baud
        emulator.rate = self.rate
        self._to_far: deque[tuple[float, bytes, int]] = deque()  # (arrival time, byte, rate)
        self._to_host: deque[tuple[float, int, int]] = deque()
        self._tx_free = 0.0  # when the host->bridge wire is free again
        self._rx_free = 0.0  # when the bridge->host wire is free again
        self.closed = False

    def set_baud(self, baud: int) -> None:
        """The host side's rate (the far end's changes on SET_BAUD)."""
        self.rate = baud
        if self._timed:
            self.byte_s = 10.0 / baud

    def _carried(self, rate: int, receiver: int) -> bool:
        return rate == receiver and (self.max_baud is None or rate <= self.max_baud)

    def write(self, data: bytes) -> None:
        t = max(self.clock.now(), self._tx_free)
        bs = self.byte_s
        if bs == 0.0:
            self._to_far.append((t, bytes(data), self.rate))
        else:
            for b in data:
                t += bs
                self._to_far.append((t, bytes((b,)), self.rate))
        self._tx_free = t

    def _deliver_far(self, until: float) -> None:
        """Hand the far end every byte that has arrived by ``until`` and queue its replies."""
        chunk = bytearray()
        q = self._to_far
        emu = self.emulator
        while q and q[0][0] <= until:
            t, b, rate = q.popleft()
            emu.expire(t)
            if self._carried(rate, emu.rate):
                chunk += b
        if not chunk:
            return
        self._queue_replies(emu.receive(bytes(chunk)))

    def _queue_replies(self, replies: list[bytes]) -> None:
        emu = self.emulator
        for reply in replies:
            t = max(self.clock.now(), self._rx_free)
            bs = self.byte_s
            for byte in reply:
                t += bs
                self._to_host.append((t, byte, emu.rate))
            self._rx_free = t
            emu.switch_after_reply(t)

    def run_far(self, until: float) -> None:
        """Run the far end up to ``until`` without reading: the bytes that arrive there, what
        falls due on its timer; the replies wait for the host's next read."""
        clock = self.clock
        emu = self.emulator
        while True:
            q = self._to_far
            due = emu.far_due
            arrive = q[0][0] if q else None
            if due is not None and due <= until and (arrive is None or due < arrive):
                if due > clock.now():
                    clock.advance_to(due)
                self._queue_replies(emu.far_step())
                continue
            if arrive is not None and arrive <= until:
                t = _last_due(q, until if due is None else min(until, due))
                if t > clock.now():
                    clock.advance_to(t)
                self._deliver_far(max(t, clock.now()))
                continue
            if until > clock.now():
                clock.advance_to(until)
            return

    def read(self, timeout_s: float) -> bytes:
        clock = self.clock
        deadline = clock.now() + max(0.0, timeout_s)
        emu = self.emulator
        while True:
            now = clock.now()
            h = self._to_host
            q = self._to_far
            due = emu.far_due
            # a row of a recording, a piece or the failsafe's expiry falls due before the next
            # byte moves: at its time
            if due is not None and due <= deadline and (not q or due < q[0][0]) \
                    and (not h or due < h[0][0]):
                if due > now:
                    clock.advance_to(due)
                self._queue_replies(emu.far_step())
                continue
            limit = deadline if due is None else min(deadline, due)
            if h and h[0][0] <= limit:
                # the reply is on its way: wait for the burst that is on the wire (up to the
                # deadline), as a serial read with a short inter-byte timeout would
                last = _last_due(h, limit)
                if last > now:
                    clock.advance_to(last)
                out = bytearray()
                while h and h[0][0] <= last:
                    _, b, rate = h.popleft()
                    if self._carried(rate, self.rate):
                        out.append(b)
                self._deliver_far(max(last, clock.now()))
                return bytes(out)
            if q and q[0][0] <= limit:
                t = _last_due(q, limit)
                if t > now:
                    clock.advance_to(t)
                self._deliver_far(max(t, clock.now()))
                continue
            if due is not None and due <= deadline:
                continue  # the row comes first (the loop's head)
            if deadline > now:
                clock.advance_to(deadline)
            return b""

    def close(self) -> None:
        self.closed = True


__all__ = ["EmuPipe", "ModelClock"]
