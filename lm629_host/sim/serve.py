"""``lm629 sim serve --pty PATH``: a simulated bridge on a pseudo-terminal.

The server creates a pseudo-terminal, links its device at ``PATH`` and answers on it like a
bridge on a USB serial port, so that several CLI invocations, a lab script and a serial
terminal can all talk to one simulated chip through the unchanged ``serial://PATH`` transport.

The far end is the Python bridge (:class:`~lm629_host.sim.bridge.BridgeEmulator`) by default;
with ``firmware=True`` it is the real compiled firmware running in simavr, taken from the
``sim+avr://`` transport.  ``usb=uno|ftdi|cdc`` in the URL puts a USB adapter's latency
(:mod:`.usb`) between the pseudo-terminal and either far end, as on a bench.  The far ends are
:mod:`.far_ends`; this module serves one.

Time: this is a real-time service, so its clock follows the wall clock.  The far end keeps its
own simulated clock; the server advances it to the wall time elapsed since start (the motor
keeps moving between clients), and when a request took the simulation past the wall time (a
WAIT, a long busy) the server sleeps until the wall clock catches up before it answers, as the
real bridge would answer that late.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable, Sequence
from pathlib import Path

from lm629_host.sim.far_ends import EmuFarEnd, FarEnd, emulator_far_end, firmware_far_end
from lm629_host.sim.vcd import vcd_of
from lm629_host.sim.model import chips_of

log = logging.getLogger("lm629_host.sim.serve")

#: how often the idle server moves the simulation forward
IDLE_TICK_S = 0.02
#: how often it does while the far end owes a reply it has not sent yet (a long program),
#: and how far (simulated seconds) it runs it between two looks at the host's bytes
OWED_TICK_S = 0.002
OWED_SLICE_S = 0.02


class SimServer:
    """A far end served on a pseudo-terminal linked at ``link``, or on a TCP port (``tcp=(host,
    port)``, port 0: any free one) for ``socket://host:port`` clients, as a bridge
    behind ser2net would be.  On TCP one client is served at a time, as ser2net and a pty
    do: a second connection is refused (closed at once) while one is connected, so that it
    never ends a running client's link; the chip keeps its state between clients, as a board
    does.  :meth:`power_cycle` cycles the chips' supply (``lm629 sim serve``: SIGUSR1)."""

    def __init__(self, link: str | os.PathLike | None = None, url: str = "sim://", *,
                 firmware: bool = False, far_end: FarEnd | None = None,
                 tcp: tuple[str, int] | None = None) -> None:
        if (link is None) == (tcp is None):
            raise ValueError("serve on a pty link or on a TCP port: give one of them")
        self.link = Path(link) if link is not None else None
        self.tcp = tcp
        self.url = url
        if vcd_of(url) is not None:
            raise ValueError(f"{url}: vcd= draws the bus of a simulator a script opens (or "
                             "`lm629 --vcd FILE <command>`); a served bench runs until Ctrl-C "
                             "and writes none: run the script on sim:// or sim+avr:// with vcd= instead")
        if far_end is None:
            far_end = firmware_far_end(url) if firmware else emulator_far_end(url)
        self.far = far_end
        self.model = far_end.model
        self.master: int | None = None
        self.slave: int | None = None
        self.device = ""
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        #: (host, port) the TCP server listens on, once open
        self.address: tuple[str, int] | None = None
        self._stop = threading.Event()
        self._power_cycle = threading.Event()
        self._thread: threading.Thread | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        #: the model and wall clocks' origins while serving, and the frames of the last read
        #: still to hand over (the Python far end's waits look at them: _host_byte_at)
        self._sim0 = 0.0
        self._wall0 = 0.0
        self._parts_left = 0

    @property
    def client_url(self) -> str:
        """What a client passes to ``--port``."""
        if self.tcp is not None:
            host, port = self.address or self.tcp
            return f"socket://{host}:{port}"
        return f"serial://{self.link}"

    @property
    def _opened(self) -> bool:
        return self.master is not None or self._listener is not None

    # ------------------------------------------------------------------ set-up
    def open(self) -> str:
        """Open where clients connect: the TCP port, or the pseudo-terminal and its link.
        Returns the pty's device path, or ``host:port``."""
        if self.tcp is not None:
            return self._open_tcp()
        return self._open_pty()

    def _open_tcp(self) -> str:
        assert self.tcp is not None
        listener = socket.create_server(self.tcp)
        listener.setblocking(False)
        self._listener = listener
        host, port = listener.getsockname()[:2]
        self.address = (self.tcp[0] or host, port)
        self.device = f"{self.address[0]}:{port}"
        return self.device

    def _open_pty(self) -> str:
        """Create the pseudo-terminal and the link; returns the pty's device path.

        The link is only ever created here, never taken over: a path that exists (a file, a
        directory, a link to a live pseudo-terminal that another server holds) is refused
        with FileExistsError.  Only a dangling link to a pseudo-terminal (left by a server
        that was killed) is replaced.  :meth:`close` removes the link only while it is still
        the one this server made."""
        assert self.link is not None
        parent = self.link.parent
        if not parent.is_dir():
            raise ValueError(f"--pty {self.link}: the directory {parent} does not exist")
        if self.link.is_symlink():
            target = os.readlink(self.link)
            if os.path.exists(self.link):
                raise FileExistsError(
                    f"{self.link} -> {target} is in use (another `lm629 sim serve`, or "
                    "another program, holds it): stop that server or choose another --pty path")
            if not target.startswith("/dev/pts/"):
                raise FileExistsError(f"{self.link} is a link to {target}, not a pseudo-"
                                      "terminal this tool made: choose another --pty path")
            os.unlink(self.link)  # stale: its server is gone
        elif os.path.lexists(self.link):
            raise FileExistsError(f"{self.link} exists and is not a link this tool made: "
                                  "choose another --pty path")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a byte pipe like a USB serial port
        self.device = os.ttyname(slave)
        try:
            os.symlink(self.device, self.link)  # fails if another server won the race
        except OSError:
            os.close(master)
            os.close(slave)
            self.device = ""
            raise
        self.master, self.slave = master, slave
        # the server keeps the slave open, so the pty survives clients that come and go
        return self.device

    def close(self) -> None:
        self.stop()
        self.far.close()
        for fd in (self.master, self.slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = None
        for sock in (self._client, self._listener):
            if sock is not None:
                sock.close()
        self._client = self._listener = None
        with contextlib.suppress(OSError):
            if self.device and self.link is not None and self.link.is_symlink() \
                    and os.readlink(self.link) == self.device:
                self.link.unlink()

    def __enter__(self) -> SimServer:
        if not self._opened:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ serving
    def _fds(self) -> Sequence[int | socket.socket]:
        if self._listener is None:
            assert self.master is not None
            return [self.master]
        return [self._listener] + ([self._client] if self._client is not None else [])

    def _read(self, ready: Sequence[int | socket.socket]) -> bytes:
        """Bytes from the client; on TCP also takes a new connection (which replaces the last)."""
        if self._listener is None:
            assert self.master is not None
            try:
                return os.read(self.master, 4096)
            except OSError:
                return b""  # EIO while no client has the slave open (ours stays open)
        if self._listener in ready:
            with contextlib.suppress(BlockingIOError):
                client, peer = self._listener.accept()
                if self._client is not None:  # busy: the running client keeps the link
                    log.info("client %s:%s refused: another client is connected", *peer[:2])
                    client.close()
                    return b""
                client.setblocking(True)
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._client = client
                log.info("client %s:%s connected", *peer[:2])
                return b""
        if self._client is not None and self._client in ready:
            try:
                data = self._client.recv(4096)
            except OSError:
                data = b""
            if not data:  # the client went away: wait for the next one
                self._client.close()
                self._client = None
            return data
        return b""

    def _write(self, data: bytes) -> None:
        if self._listener is None:
            assert self.master is not None
            os.write(self.master, data)
        elif self._client is not None:
            with contextlib.suppress(OSError):  # a client gone while we answered
                self._client.sendall(data)

    def serve_forever(self, on_ready: Callable[[], None] | None = None) -> None:
        """Answer until :meth:`stop` (or KeyboardInterrupt)."""
        if not self._opened:
            self.open()
        far = self.far
        wall0 = self._wall0 = time.monotonic()
        sim0 = self._sim0 = far.now()
        if isinstance(far, EmuFarEnd):  # its waits hear the host's bytes as the firmware's do
            far.emulator.host_byte_at = self._host_byte_at
        if on_ready is not None:
            on_ready()
        while not self._stop.is_set():
            ready, _, _ = select.select(self._fds(), [], [],
                                        OWED_TICK_S if far.owes_reply else IDLE_TICK_S)
            if self._power_cycle.is_set():
                self._power_cycle.clear()
                self._cycle_power()
            now = sim0 + time.monotonic() - wall0
            if not ready:
                # the time is taken first, then what is waiting read: a server paused between
                # its select and the clock (SIGSTOP, a busy machine) still gets every byte the
                # host sent before ``now``, never a silent host it did not look at
                ready, _, _ = select.select(self._fds(), [], [], 0)
            data = self._read_waiting(ready) if ready else b""
            self.bytes_in += len(data)
            replies = self._deliver(data, now)
            if not replies:
                continue
            ahead = (far.now() - sim0) - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)  # real-time service: answer no earlier than a bridge would
            for r in replies:
                self._write(r)
                self.bytes_out += len(r)

    def _host_byte_at(self, t: float) -> float | None:
        """:attr:`BridgeEmulator.host_byte_at` on this bench: a frame of the last read still to
        hand over arrived already; else the far end waits, in real time, until model time
        ``t`` or a byte from the client, whichever comes first (so that the Python far end,
        in a long WAIT_STATUS, hears a new client's HELLO as the firmware does).  A server
        told to stop ends the wait too."""
        if self._parts_left or self._stop.is_set():
            return self.far.now()
        ahead = (t - self._sim0) - (time.monotonic() - self._wall0)
        fds: list[int | socket.socket] = (
            [self.master] if self._listener is None and self.master is not None
            else [self._client] if self._client is not None else [])
        ready = select.select(fds, [], [], max(0.0, ahead))[0] if fds else []
        if ready and self._client is not None and self._client in ready:
            with contextlib.suppress(OSError):
                if not self._client.recv(1, socket.MSG_PEEK):  # gone, not a byte
                    ready = []
        if ready:
            return min(t, self._sim0 + time.monotonic() - self._wall0)
        left = (t - self._sim0) - (time.monotonic() - self._wall0)
        if left > 0:  # no client to hear (or one that left): the wait still takes its time
            time.sleep(left)
        return None

    def _read_waiting(self, ready: Sequence[int | socket.socket]) -> bytes:
        """Every byte the client has written so far (the pty or socket may hold more than one
        read's worth after the server was paused)."""
        data = self._read(ready)
        while data:
            more, _, _ = select.select(self._fds(), [], [], 0)
            chunk = self._read(more) if more else b""
            if not chunk:
                break
            data += chunk
        return data

    def _deliver(self, data: bytes, now: float) -> list[bytes]:
        """Run the far end up to simulated time ``now`` and hand it ``data``: what it sends.

        The bytes arrived at some time since the far end last ran.  A real bridge's UART and
        timer keep running while nobody looks, so the host's bytes reached it in time; a
        server that was itself late (a busy machine, SIGSTOP) must not judge the host silent
        for the time it did not look.  So the frames waiting are credited across that gap,
        evenly, the last one now (a single request is taken now, as it always was), and the
        far end runs to each one's time before it gets it (its failsafe, rows and pieces at
        their own times in between)."""
        far = self.far
        out: list[bytes] = []
        if data:
            # frame by frame: each ends with its 0x00 delimiter (a partial tail goes last)
            parts = [p + b"\0" for p in data.split(b"\0")[:-1]]
            if not data.endswith(b"\0"):
                parts.append(data[data.rfind(b"\0") + 1:])
            start = far.now()
            # a far end still running a request (a long WAIT_STATUS in simavr runs slower
            # than real time, so it falls behind) takes the bytes now, on its own clock: the
            # firmware ends such a wait when the host sends (a new client's HELLO), which it
            # must see before it simulates its way through the rest of the wait
            end = start if far.owes_reply else now
            for k, part in enumerate(parts):
                stray = far.advance_to(start + (end - start) * (k + 1) / len(parts))
                if stray:
                    out.append(stray)
                self._parts_left = len(parts) - 1 - k  # arrived already: they end a wait
                out += far.receive(part)
            self._parts_left = 0
        # while a request runs, in slices, so that the host's next bytes are read between them
        stray = far.advance_to(min(now, far.now() + OWED_SLICE_S) if far.owes_reply else now)
        if stray:
            out.append(stray)
        return out

    def power_cycle(self) -> None:
        """Cycle the chips' supply, as a bench's switch would: every chip comes back as from
        power-on (filter, LPES and output mode gone, positions 0, motor off); the bridge and
        the link stay up (the Uno is powered by USB).  Safe from a signal handler: the serving
        loop does it between two exchanges."""
        self._power_cycle.set()

    def _cycle_power(self) -> None:
        self.model.reset_pulse()  # /RST is what power-on does to every register the host set
        log.info("power cycled: every chip as from power-on")

    def start(self) -> SimServer:
        """Serve in a background thread (tests, scripts)."""
        if not self._opened:
            self.open()
        ready = threading.Event()
        self._thread = threading.Thread(target=self.serve_forever, args=(ready.set,),
                                        name=f"lm629-sim-serve {self.link or self.device}", daemon=True)
        self._thread.start()
        ready.wait(5)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5)
            self._thread = None

    def describe(self) -> str:
        where = (f"TCP port {self.device}" if self.tcp is not None
                 else f"{self.device} (linked at {self.link})")
        chips = chips_of(self.model)
        return f"{self.far.describe()} with a {chips[0].describe(len(chips))}, on {where}"


__all__ = ["SimServer"]
