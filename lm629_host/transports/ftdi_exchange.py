"""One MPSSE stream through the FT232H: written whole, its answer read whole, counted; and the
busy wait each chip is still owed when it ends (:mod:`.ftdi` has the busy discipline).

Apart from the transport because three parts of it exchange streams: the programs
(:mod:`.ftdi`), the busy-time measure before the first program (:mod:`.ftdi_busy`), and the
status polls and the recovery after a stall (:mod:`.ftdi_resync`).  Each stream starts with
whatever is left of the wait the previous one owed its chips, so that wait and the time the
last answer came back live here, with the exchange that ends them, not in any one of those
parts.
"""

from __future__ import annotations

from typing import Any

from lm629_host.clock import Clock
from lm629_host.errors import TransportError
from lm629_host.transports.reports import Stats
from lm629_host.transports.mpsse import Stream


class Stalled(Exception):
    """The answer of a stream that waits on the busy pin came back short: the engine is
    still waiting (``answer``: what it sent before)."""

    def __init__(self, answer: bytes) -> None:
        super().__init__(f"{len(answer)} answer bytes")
        self.answer = answer


class StreamExchange:
    """Streams to the opened pyftdi ``Ftdi`` and their answers back, on ``clock`` (only its
    ``now()`` is read: a wrapper the transport puts around it later keeps its time base)."""

    def __init__(self, ftdi: Any, url: str, clock: Clock, stats: Stats, latency_ms: int) -> None:
        self.ftdi = ftdi  #: the opened pyftdi ``Ftdi`` (None once closed)
        self.url = url
        self.clock = clock
        self.stats = stats  #: the transport's: every exchange is counted there
        self.latency_ms = latency_ms
        self.last_end = -1.0  #: clock time at which the last stream's answer came back
        self.owed: dict[int, float] = {}  #: busy wait owed after each chip's last transfer

    def run(self, stream: Stream, wait_s: float = 0.0) -> bytes:
        """Write ``stream``, read its answer.  ``wait_s``: how long its waits on the busy pin
        may take in all (they have no timeout of their own: the read gives up after that)."""
        ftdi = self.ftdi
        if ftdi is None:
            raise TransportError("the port is closed", port=self.url)
        need = len(stream.slots)
        # on hardware the answer can only come once the stream's delays have run: let pyftdi
        # wait that many latency periods for it, and a few more
        attempts = 3 + int((stream.delay_s + (wait_s if stream.waits else 0.0)) * 1000
                           / max(1, self.latency_ms))
        try:
            ftdi.write_data(stream.data)
            answer = bytes(ftdi.read_data_bytes(need, attempts))
        except TransportError:
            raise
        except Exception as exc:
            raise TransportError(
                f"USB transfer to the FT232H failed ({exc}). Check the USB cable and that the "
                "adapter is still plugged in; a command may or may not have reached the chip: "
                "read back what matters before going on", port=self.url) from exc
        st = self.stats
        st.round_trips += 1
        st.bytes_out += len(stream.data)
        st.bytes_in += len(answer)
        st.bus_cycles += stream.strobes
        if len(answer) != need and stream.waits:
            raise Stalled(answer)
        if len(answer) != need:
            raise TransportError(
                f"the FT232H returned {len(answer)} of the {need} bytes the stream reads "
                f"(stream of {len(stream.data)} bytes). Check the USB cable and that no other "
                "program uses the adapter; the commands of this program may or may not have "
                "reached the chip", port=self.url)
        self.last_end = self.clock.now()
        return answer

    def lead(self) -> dict[int, float]:
        """The busy wait still owed to each chip's last transfer of the previous streams."""
        if self.last_end < 0:
            return {}
        gone = self.clock.now() - self.last_end
        return {k: max(0.0, v - gone) for k, v in self.owed.items() if v > gone}


__all__ = ["Stalled", "StreamExchange"]
