"""What the FT232H transport does when a stream's checks did not all pass: poll the status in
short exchanges until busy clears (before a repeat, or where a SYNC asked to wait), and after
a stream that stalled at a wait on the busy pin, purge the adapter and say which operation
the chip did not take (:mod:`.ftdi` has the busy discipline both serve).

Apart from the loop that runs a program's streams because each is a short exchange of its own
on the same wire and compiler, with its own way to end (a clear status, a
:class:`~lm629_host.errors.BusyTimeout`, a :class:`~lm629_host.errors.TransportError`), and
the loop only asks for it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from lm629_host.bus.opcodes import BUSY_BIT
from lm629_host.bus.program import BusCycle, Program
from lm629_host.errors import BusyTimeout, TransportError
from lm629_host.transports.ftdi_exchange import StreamExchange
from lm629_host.transports.ftdi_open import reenter_mpsse
from lm629_host.transports.mpsse import Stream, StreamCompiler, chips_of_units

log = logging.getLogger("lm629_host.ftdi")

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)


class Resync:
    """Status polls and the stall recovery of one FT232H transport: its ``wire`` and
    ``compiler``, ``emit`` (the transport's: each poll is a bus cycle its observers see) and
    the line D0 is wired to (``busy_pin``, None: not wired)."""

    def __init__(self, wire: StreamExchange, compiler: StreamCompiler,
                 emit: Callable[[BusCycle], None], busy_pin: str | None) -> None:
        self.wire = wire
        self.compiler = compiler
        self.emit = emit
        self.busy_pin = busy_pin
        self.stalls = 0  #: streams that stopped at a wait on the busy pin and were purged

    def poll_until_clear(self, program: Program, index: int, deadline: float,
                         words: list[int]) -> int:
        """Status reads, one short exchange each, until busy is clear; BusyTimeout at
        ``deadline``."""
        wire = self.wire
        chip = chips_of_units(program.ops).get(index, 0)
        poll = self.compiler.status_stream(chip, "status", index)
        while True:
            status = wire.run(poll)[0]
            wire.stats.busy_polls += 1
            self.emit(BusCycle("status", status))
            if not status & _BUSY:
                wire.owed = {k: v for k, v in wire.owed.items() if k != chip}
                return status
            if wire.clock.now() >= deadline:
                raise BusyTimeout(program.ops[index].describe(), program.busy_timeout_s, status,
                                  index, words)

    def after_stall(self, program: Program, stream: Stream, answer: bytes,
                    reads: dict[int, int]) -> BusyTimeout:
        """A stream stopped at a wait on the busy pin (MPSSE waits for ever; the read gave up):
        purge the FT232H and enter MPSSE again with the lines idle
        (:func:`.ftdi_open.reenter_mpsse`: the held status read ends), read the status once.
        The operation whose check never came is the one the chip did not take; those before
        it were taken.  Returns the BusyTimeout to raise."""
        wire = self.wire
        self.stalls += 1
        index = stream.slots[len(answer)].op if len(answer) < len(stream.slots) else -1
        log.warning("%s: busy never cleared during the wait on %s before %s: purging the "
                    "FT232H and setting its lines idle again", wire.url, self.busy_pin,
                    program.ops[index].describe() if index >= 0 else "the end")
        try:
            reenter_mpsse(wire.ftdi, self.compiler.tck_hz)
            chip = chips_of_units(program.ops).get(index, 0)
            status: int | None = wire.run(self.compiler.status_stream(chip, "status", index))[0]
        except TransportError:
            raise
        except Exception as exc:  # pyftdi raises FtdiError, UsbToolsError, USBError...
            raise TransportError(
                f"the FT232H stalled on the busy pin and could not be reset ({exc}); unplug "
                "and replug it: a command may or may not have reached the chip",
                port=wire.url) from exc
        wire.last_end = wire.clock.now()
        words = [reads[k] for k in sorted(reads)]
        return BusyTimeout(program.ops[index].describe() if index >= 0 else "the end of the "
                           "program", program.busy_timeout_s, status, index, words)

    def unwired(self, what: str) -> TransportError:
        """A check after a wait on the busy pin still saw busy before ``what``."""
        return TransportError(
            f"busy_pin={self.busy_pin}: the status read after the wait on the pin still showed "
            f"busy before {what}, so the pin did not follow D0: check the wire from D0 (C0) to "
            "ADBUS5 and that HI is no longer on ADBUS5 (docs/ftdi.md, 'Waiting on the busy "
            "bit'). The transfers after it in the same exchange may have been ignored by the "
            "chip: read back what matters (a move may have started) before going on, or open "
            "the port without busy_pin", port=self.wire.url)


__all__ = ["Resync"]
