"""The real ser2net (Debian's package, 4.x) in front of a served bench, on 127.0.0.1 only.

:class:`Ser2net` writes a YAML config for one connection (RFC 2217 or raw TCP) to one device,
picks a free port, starts ``ser2net -d -u -c FILE`` in the foreground as its own process,
waits until the port listens (read from ``/proc/net/tcp``: connecting to find out would make
ser2net open the device, a client the test did not ask for), and stops it by its own pid.
:meth:`Ser2net.kill` ends it abruptly (a crashed server, the network gone) and
:meth:`Ser2net.start` starts it again on the same port.  :func:`ser2net` is the context
manager the tests use: nothing it started is left running when the block ends.

ser2net wants the real device (a pty's ``/dev/pts/N``, not the symlink a served bench makes:
``os.path.realpath``) and has no access control of its own: whoever reaches the port drives
the bench, so the tests bind to 127.0.0.1 and nothing else.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

#: how long ser2net may take to listen after it starts (it is ready in ~20 ms here; a busy
#: machine with CPU hogs beside it is slower)
START_S = 10.0


def ser2net_exe() -> str:
    """The ser2net program, or a skip that says how to get it (``.ci/run`` installs it, so in
    CI it is always there)."""
    exe = shutil.which("ser2net") or ("/usr/sbin/ser2net" if os.path.exists("/usr/sbin/ser2net")
                                      else None)
    if exe is None:
        if os.environ.get("LM629_REQUIRE_AVR") == "1":  # CI: a missing package is a failure
            pytest.fail("ser2net is not installed (apt-get install ser2net; .ci/run does)")
        pytest.skip("ser2net is not installed (apt-get install ser2net)")
    return exe


def ser2net_version() -> str:
    out = subprocess.run([ser2net_exe(), "-v"], capture_output=True, text=True, timeout=10)
    return out.stdout.strip().rpartition(" ")[2]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening(port: int) -> bool:
    """Whether something listens on 127.0.0.1:``port`` (``/proc/net/tcp``, state 0A)."""
    want = f"0100007F:{port:04X}"
    try:
        with open("/proc/net/tcp") as f:
            return any(ln.split()[1] == want and ln.split()[3] == "0A" for ln in list(f)[1:])
    except OSError:
        return False


class Ser2net:
    """One ser2net process serving ``device`` on 127.0.0.1 as ``protocol`` (``rfc2217`` or
    ``raw``).  ``options``: the connection's ser2net options (``kickolduser``, ``chardelay``...),
    YAML scalars as text."""

    def __init__(self, device: str | Path, workdir: Path, protocol: str = "rfc2217",
                 options: dict[str, str] | None = None, baud: int = 115200) -> None:
        if protocol not in ("rfc2217", "raw"):
            raise ValueError(f"protocol {protocol!r}: rfc2217 or raw")
        self.device = os.path.realpath(device)  # ser2net's serialdev wants the real path
        self.protocol = protocol
        self.port = free_port()
        self.config = workdir / f"ser2net-{self.port}.yaml"
        self.log = workdir / f"ser2net-{self.port}.log"
        accepter = ("telnet(rfc2217),tcp" if protocol == "rfc2217" else "tcp") + \
            f",127.0.0.1,{self.port}"
        lines = ["connection: &bench",
                 f"  accepter: {accepter}",
                 f"  connector: serialdev,{self.device},{baud}n81,local"]
        if options:
            lines.append("  options:")
            lines += [f"    {k}: {v}" for k, v in options.items()]
        self.config.write_text("\n".join(lines) + "\n")
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        """The port URL a client opens: ``rfc2217://`` or, raw, ``socket://``."""
        scheme = "rfc2217" if self.protocol == "rfc2217" else "socket"
        return f"{scheme}://127.0.0.1:{self.port}"

    def start(self) -> Ser2net:
        """Start it (again: same port, same config) and return once the port listens."""
        assert self.proc is None or self.proc.poll() is not None, "ser2net is running"
        # -d: foreground, log to stdout; -u: no UUCP lock files (a pty needs none)
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([ser2net_exe(), "-d", "-u", "-c", str(self.config)],
                                         stdin=subprocess.DEVNULL, stdout=log,
                                         stderr=subprocess.STDOUT)
        deadline = time.monotonic() + START_S
        while not _listening(self.port):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"ser2net did not listen on 127.0.0.1:{self.port} within "
                                   f"{START_S:g} s; its log:\n{self.log.read_text()}")
            time.sleep(0.01)
        return self

    def kill(self) -> None:
        """End it abruptly (SIGKILL): every client's connection drops at once."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)

    def stop(self) -> None:
        """End it (SIGTERM, then SIGKILL if it lingers) and reap it; idempotent."""
        p = self.proc
        if p is None or p.poll() is not None:
            return
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=5)


@contextmanager
def ser2net(device: str | Path, workdir: Path, protocol: str = "rfc2217",
            options: dict[str, str] | None = None) -> Iterator[Ser2net]:
    """ser2net serving ``device`` for the block, stopped (and checked gone) at its end."""
    s = Ser2net(device, workdir, protocol, options).start()
    try:
        yield s
    finally:
        s.stop()
        assert s.proc is None or s.proc.poll() is not None
        assert not _listening(s.port), f"127.0.0.1:{s.port} still listens after ser2net stopped"


__all__ = ["Ser2net", "ser2net", "ser2net_exe", "ser2net_version", "free_port"]
