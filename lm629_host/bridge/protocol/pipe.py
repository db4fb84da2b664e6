"""What a byte stream to a bridge must offer (a serial port, a simulated UART, the Python far
end); the transport over it is :class:`~lm629_host.transports.link.LinkTransport`."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from lm629_host.clock import Clock


@runtime_checkable
class Pipe(Protocol):
    """A byte stream to a bridge, with its own clock.

    ``read(timeout_s)`` waits up to ``timeout_s`` on ``clock`` for the first byte and returns
    what is available then (``b""`` on timeout).  A simulated pipe advances its simulated clock
    while it waits; a serial port waits in real time.
    """

    @property
    def clock(self) -> Clock: ...

    def write(self, data: bytes) -> None: ...

    def read(self, timeout_s: float) -> bytes: ...

    def close(self) -> None: ...
