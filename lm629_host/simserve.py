"""``lm629 sim serve --pty PATH``: a simulated bridge on a pseudo-terminal.

The server creates a pseudo-terminal, links its device at ``PATH`` and answers on it like a
bridge on a USB serial port, so that several CLI invocations, a lab script and a serial
terminal can all talk to one simulated chip through the unchanged ``serial://PATH`` transport.

The far end is the Python bridge (:class:`~lm629_host.bridge_emu.BridgeEmulator`) by default;
with ``firmware=True`` it is the real compiled firmware running in simavr, when the firmware
colleague's harness (:mod:`lm629_host.avrsim`) provides a far end (see :func:`firmware_far_end`).

Time: this is a real-time service, so its clock follows the wall clock.  The chip model keeps
its own simulated clock; before handling bytes the server advances the model to the wall time
elapsed since start, and when a program took the model past the wall time (a WAIT, a long
busy) the server sleeps until the wall clock catches up before it answers, as the real bridge
would answer that late.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from .bridge_emu import BridgeEmulator
from .model import ChipModel
from .transports.sim import build_model

log = logging.getLogger("lm629_host.simserve")

#: how often the idle server moves the model forward (the motor keeps moving in real time)
IDLE_TICK_S = 0.02


class FarEnd:
    """What the server needs from a far end: bytes in, reply bytes out, a model to advance."""

    model: ChipModel

    def receive(self, data: bytes) -> list[bytes]: ...  # pragma: no cover - interface

    def describe(self) -> str: ...  # pragma: no cover - interface


class EmuFarEnd(FarEnd):
    def __init__(self, model: ChipModel) -> None:
        self.model = model
        self.emulator = BridgeEmulator(model)

    def receive(self, data: bytes) -> list[bytes]:
        return self.emulator.receive(data)

    def describe(self) -> str:
        return f"Python bridge emulator (firmware {self.emulator.info.firmware_version})"


def firmware_far_end(url: str) -> FarEnd:
    """The compiled firmware in simavr as a far end, from :mod:`lm629_host.avrsim`.

    That module belongs to the firmware harness; it must offer ``far_end(url) -> obj`` with
    ``model``, ``receive(bytes) -> list[bytes]`` and ``describe()``.  Raises RuntimeError with
    what is missing otherwise.
    """
    try:
        from . import avrsim  # type: ignore[attr-defined]
    except ImportError as exc:
        raise RuntimeError(f"--firmware needs the simavr harness (lm629_host.avrsim): {exc}. "
                           "Build it with `make -C firmware_bridge` (needs gcc-avr, simavr, "
                           "libsimavr-dev), or serve the Python emulator without --firmware."
                           ) from None
    factory = getattr(avrsim, "far_end", None)
    if factory is None:
        raise RuntimeError("lm629_host.avrsim has no far_end(url) yet: serve the Python "
                           "emulator without --firmware")
    return factory(url)


class SimServer:
    """A far end served on a pseudo-terminal linked at ``link``."""

    def __init__(self, link: str | os.PathLike, url: str = "sim://", *,
                 firmware: bool = False, far_end: FarEnd | None = None) -> None:
        self.link = Path(link)
        self.url = url
        if far_end is None:
            far_end = firmware_far_end(url) if firmware else EmuFarEnd(build_model(url))
        self.far = far_end
        self.model = far_end.model
        self.master: int | None = None
        self.slave: int | None = None
        self.device = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.bytes_in = 0
        self.bytes_out = 0

    # ------------------------------------------------------------------ set-up
    def open(self) -> str:
        """Create the pseudo-terminal and the link; returns the pty's device path."""
        if self.link.exists() and not self.link.is_symlink():
            raise FileExistsError(f"{self.link} exists and is not a symlink: choose another "
                                  "--pty path")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a byte pipe like a USB serial port
        self.master, self.slave = master, slave
        self.device = os.ttyname(slave)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        self.link.symlink_to(self.device)
        # the server keeps the slave open, so the pty survives clients that come and go
        return self.device

    def close(self) -> None:
        self.stop()
        for fd in (self.master, self.slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = None
        with contextlib.suppress(OSError):
            if self.link.is_symlink() and os.readlink(self.link) == self.device:
                self.link.unlink()

    def __enter__(self) -> SimServer:
        if self.master is None:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ serving
    def serve_forever(self, on_ready: Callable[[], None] | None = None) -> None:
        """Answer until :meth:`stop` (or KeyboardInterrupt)."""
        if self.master is None:
            self.open()
        master = self.master
        model = self.model
        hz = model.clock_hz
        wall0 = time.monotonic()
        tick0 = model.tick
        if on_ready is not None:
            on_ready()
        while not self._stop.is_set():
            ready, _, _ = select.select([master], [], [], IDLE_TICK_S)
            wall = time.monotonic() - wall0
            model.advance_to(tick0 + int(wall * hz))
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                continue  # EIO while no client has the slave open (the slave is ours too)
            self.bytes_in += len(data)
            replies = self.far.receive(data)
            if not replies:
                continue
            ahead = (model.tick - tick0) / hz - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)  # real-time service: answer no earlier than a bridge would
            for r in replies:
                os.write(master, r)
                self.bytes_out += len(r)

    def start(self) -> SimServer:
        """Serve in a background thread (tests, scripts)."""
        if self.master is None:
            self.open()
        ready = threading.Event()
        self._thread = threading.Thread(target=self.serve_forever, args=(ready.set,),
                                        name=f"lm629-sim-serve {self.link}", daemon=True)
        self._thread.start()
        ready.wait(5)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5)
            self._thread = None

    def describe(self) -> str:
        p = self.model.params
        return (f"{self.far.describe()} with a simulated {p.variant.upper()} at "
                f"{p.clock_hz / 1e6:g} MHz, on {self.device} (linked at {self.link})")


__all__ = ["EmuFarEnd", "FarEnd", "SimServer", "firmware_far_end"]
