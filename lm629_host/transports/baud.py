"""The baud switch of a link (PROTOCOL.md, SET_BAUD): both ends move to a faster rate, and go
back by themselves when the new rate carries nothing.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from lm629_host.bridge.protocol.constants import BAUD_WINDOW_MS, Capability, FrameType, Result
from lm629_host.bridge.protocol.framing import wire_size
from lm629_host.bridge.protocol.hello import HelloInfo
from lm629_host.errors import TransportError

if TYPE_CHECKING:
    from lm629_host.transports.session import LinkSession

log = logging.getLogger("lm629_host.bridge.protocol")


def switch_baud(link: LinkSession, baud: int) -> bool:
    """Ask the bridge to run the line at ``baud`` (SET_BAUD; the pipe must have
    ``set_baud``).  True when the link runs at it now.  False when it stays at the rate it
    had, with a warning that says why: a bridge without BAUD_SWITCH (then nothing is
    sent), a rate the bridge cannot make, or no answer at the new rate (a USB serial
    adapter that cannot do it): then the bridge goes back by itself after
    BAUD_WINDOW_MS, and so does the host.  A failure to talk at either rate afterwards is
    a :class:`TransportError`."""
    set_baud = getattr(link.pipe, "set_baud", None)
    info = link.info
    if (set_baud is None or info is None or not info.capabilities & Capability.BAUD_SWITCH
            or baud == link.baud):
        return False
    old = link.baud
    try:
        frame = link.request(FrameType.SET_BAUD, baud.to_bytes(4, "big"), f"SET_BAUD {baud}",
                             wire_size(9))
        result = frame.payload[0] if frame.payload else -1
    except TransportError:
        result = None  # the bridge may or may not have switched: wait its window out
    moved, why = False, ""
    if result == Result.OK:
        try:  # the host's end: a local UART, or the far UART of ser2net (RFC 2217 SET-BAUDRATE)
            set_baud(baud)
            moved = True
        except TransportError as exc:  # the bridge moved, the line did not: its window ends it
            why = f"the port cannot run at {baud} baud ({exc})"
    if moved:
        link.baud = baud
        # three HELLOs at the new rate, all within the bridge's window
        tries = 3
        hello_s = max(link.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)),
                      BAUD_WINDOW_MS * 1e-3 * 0.6 / tries)
        try:
            link.request(FrameType.HELLO, b"", f"HELLO at {baud} baud",
                         wire_size(4 + HelloInfo.SIZE), retries=tries - 1, resync=False,
                         timeout_s=hello_s)
        except TransportError:
            pass
        else:
            log.info("%s: the link runs at %d baud", link.url, baud)
            return True
        why = f"no answer at {baud} baud (can the USB serial adapter do it?)"
    elif result == Result.OK:
        pass  # why: the port's refusal, above
    elif result is None:
        why = "no answer to SET_BAUD"
    else:
        why = f"the bridge cannot make {baud} baud (result {result})"
    # back to the old rate; the bridge goes back too once its window has passed
    if moved:
        set_baud(old)
        link.baud = old
    if result is None or result == Result.OK:  # else the bridge never left the old rate
        link.clock.sleep(BAUD_WINDOW_MS * 1e-3 * 1.2)
    link.invalidate()  # HELLO at the old rate before anything else
    try:
        link.resync()
    except TransportError:
        if not moved:
            raise
        # its answer to our HELLO at the new rate may have been lost, so that it stayed
        set_baud(baud)
        link.baud = baud
        link.invalidate()
        link.resync()
        log.info("%s: the link runs at %d baud", link.url, baud)
        return True
    log.warning("%s: staying at %d baud: %s", link.url, old, why)
    return False


__all__ = ["switch_baud"]
