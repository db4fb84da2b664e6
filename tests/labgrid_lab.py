"""A real labgrid lab on loopback, for the tests: a ``labgrid-coordinator``, one
``labgrid-exporter`` per bench (each bench a ``lm629 sim serve --pty``, exported as a
``RawSerialPort`` that the exporter serves through its own ser2net as RFC 2217), and places
created and matched with ``labgrid-client``.

Loopback only: labgrid's exporter starts ser2net listening on every interface (``tcp,PORT``);
a ``ser2net`` first on the exporter's PATH rewrites that to ``tcp,127.0.0.1,PORT`` and execs the
real one (docs/testing.md says how a lab does the same).  The exporter refuses a
``RawSerialPort`` whose path does not start with ``/dev/``, so a bench is exported by its pty's
real path (``/dev/pts/N``), not the link ``sim serve`` made.

labgrid runs from its own virtual environment (``LM629_LABGRID_PYTHON``, built by .ci/run):
its fork of pyserial must not replace the real one of the test environment.

Everything the lab starts, it stops (:meth:`Lab.close`), and then checks the process list:
no coordinator, exporter, ser2net or bench of this lab is left running.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from served import Bench, serve

#: Debian's ser2net (the wrapper below execs it)
SER2NET = "/usr/sbin/ser2net"
#: the ``ser2net`` an exporter finds first on its PATH: loopback only, then the real one
#: (docs/testing.md shows this very file: tests/integrations/test_labgrid_lab.py checks)
SER2NET_LOOPBACK = r"""#!/bin/sh
# labgrid's exporter asks ser2net for "...,tcp,PORT" (every interface): keep it on loopback
for a in "$@"; do
  shift
  set -- "$@" "$(printf '%s' "$a" | sed -E 's/,tcp,([0-9]+)/,tcp,127.0.0.1,\1/g')"
done
exec /usr/sbin/ser2net "$@"
"""

#: how long a lab part may take to say it is ready (a busy 2-core machine)
READY_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _alive(pid: int) -> bool:
    """Running (a zombie, ended but not yet reaped by its parent, is not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            with contextlib.suppress(OSError):
                if int(d.joinpath("stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(d.name))
    return out


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def listening(port: int) -> list[str]:
    """The local addresses (hex, as /proc/net/tcp{,6} writes them) that listen on TCP ``port``."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                addr, _, hexport = local.partition(":")
                if state == "0A" and int(hexport, 16) == port:  # 0A: LISTEN
                    found.append(addr)
    return found


@dataclass
class Exporter:
    name: str
    bench: Bench
    proc: subprocess.Popen
    log: Path
    ser2net: list[int] = field(default_factory=list)  #: every ser2net seen (Lab.ser2nets)

    @property
    def device(self) -> str:
        return os.path.realpath(self.bench.link)


@dataclass
class Lab:
    """A coordinator, its exporters (one bench each) and the places on them."""

    tmp: Path
    bin: Path  #: labgrid's venv's bin/ (labgrid-coordinator, -exporter, -client)
    coordinator: str = ""
    coordinator_proc: subprocess.Popen | None = None
    exporters: dict[str, Exporter] = field(default_factory=dict)
    started: list[int] = field(default_factory=list)  #: every pid this lab started
    _coordinator_log: Path = Path()

    def env(self, **extra: str) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("LM629_", "LG_"))}
        env.update(LG_COORDINATOR=self.coordinator, **extra)
        return env

    def client(self, *args: str, user: str | None = None,
               check: bool = True) -> subprocess.CompletedProcess[str]:
        """``labgrid-client ARGS`` as this machine's user, or as ``user`` ("host/name")."""
        extra = {}
        if user:
            extra["LG_HOSTNAME"], extra["LG_USERNAME"] = user.split("/")
        p = subprocess.run([str(self.bin / "labgrid-client"), *args], capture_output=True,
                           text=True, timeout=60, env=self.env(**extra))
        if check:
            assert p.returncode == 0, f"labgrid-client {' '.join(args)}: {p.stdout}{p.stderr}"
        return p

    def _wait_for(self, log: Path, banner: str, proc: subprocess.Popen) -> None:
        deadline = time.monotonic() + READY_S
        while banner not in log.read_text():
            assert proc.poll() is None, f"{proc.args[0]} ended: {log.read_text()}"
            assert time.monotonic() < deadline, f"no {banner!r} in {READY_S} s: {log.read_text()}"
            time.sleep(0.05)

    def _spawn(self, argv: list[str], cwd: Path, env: dict[str, str]
               ) -> tuple[subprocess.Popen, Path]:
        log = cwd / "log.txt"
        with log.open("w") as out:
            proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)
        self.started.append(proc.pid)
        return proc, log

    def start_coordinator(self) -> None:
        """Started, not waited for (:meth:`coordinator_ready`): the benches start meanwhile."""
        self.coordinator = f"127.0.0.1:{free_port()}"
        where = self.tmp / "coordinator"
        where.mkdir()
        self.coordinator_proc, self._coordinator_log = self._spawn(
            [str(self.bin / "labgrid-coordinator"), "-l", self.coordinator], where, self.env())

    def coordinator_ready(self) -> None:
        assert self.coordinator_proc is not None
        self._wait_for(self._coordinator_log, "Coordinator ready", self.coordinator_proc)

    def add_exporter(self, name: str, bench: Bench, group: str = "lm629-bench",
                     more: dict[str, str] | None = None) -> Exporter:
        """An exporter named ``name`` exporting ``bench``'s pty as ``RawSerialPort`` in
        ``group`` (and ``more``: group -> device), its ser2net on loopback."""
        self.started.append(bench.server.pid)
        where = self.tmp / name
        where.mkdir(exist_ok=True)
        wrappers = self.tmp / "bin"
        if not wrappers.exists():
            wrappers.mkdir()
            (wrappers / "ser2net").write_text(SER2NET_LOOPBACK)
            (wrappers / "ser2net").chmod(0o755)
        device = os.path.realpath(bench.link)
        assert device.startswith("/dev/"), device  # the exporter serves only /dev/ paths
        (where / "exporter.yaml").write_text("".join(
            f"{g}:\n  RawSerialPort:\n    port: {d}\n    speed: 115200\n"
            for g, d in {group: device, **(more or {})}.items()))
        env = self.env(PATH=f"{wrappers}:{os.environ.get('PATH', '')}")
        proc, log = self._spawn(
            [str(self.bin / "labgrid-exporter"), "-c", self.coordinator, "--hostname",
             "127.0.0.1", "-n", name, "exporter.yaml"], where, env)
        exp = Exporter(name, bench, proc, log)
        self.exporters[name] = exp
        return exp

    def ser2nets(self) -> dict[str, list[int]]:
        """The ser2net each exporter runs now (it starts one when a place with its port is
        acquired, on a fresh TCP port, and stops it on release), recorded as started."""
        found = {n: [c for c in children(e.proc.pid) if "ser2net" in cmdline(c)]
                 for n, e in self.exporters.items()}
        for n, pids in found.items():
            self.exporters[n].ser2net = sorted(set(self.exporters[n].ser2net) | set(pids))
            self.started += pids
        return found

    def wait_resources(self) -> str:
        """``labgrid-client resources`` once every exporter's bench is listed."""
        for e in self.exporters.values():
            self._wait_for(e.log, "Exporter ready", e.proc)
        deadline = time.monotonic() + READY_S
        while True:
            out = self.client("resources").stdout
            if all(f"{n}/" in out for n in self.exporters):
                return out
            assert time.monotonic() < deadline, out
            time.sleep(0.1)

    def add_places(self, matches: dict[str, str]) -> None:
        """Create each place and add its match (place -> pattern), the places at once."""
        for step in (("create",), ("add-match",)):
            procs = {place: subprocess.Popen(
                [str(self.bin / "labgrid-client"), "-p", place, *step,
                 *((matches[place],) if step == ("add-match",) else ())],
                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=self.env())
                for place in matches}
            for place, proc in procs.items():
                out, _ = proc.communicate(timeout=60)
                assert proc.returncode == 0, f"{place} {step}: {out}"

    def held(self) -> dict[str, str]:
        """Every acquired place and who holds it ("host/user"), from ``labgrid-client who``."""
        rows = [ln.split() for ln in self.client("who").stdout.splitlines()[1:] if ln.strip()]
        return {row[2]: f"{row[1]}/{row[0]}" for row in rows}

    def left_running(self) -> list[str]:
        """What this lab started that still runs, and any process naming its directory."""
        left = [f"{pid} {cmdline(pid)}" for pid in self.started if _alive(pid)]
        for d in Path("/proc").iterdir():
            if d.name.isdigit() and int(d.name) != os.getpid() and str(self.tmp) in cmdline(
                    int(d.name)) and _alive(int(d.name)):
                left.append(f"{d.name} {cmdline(int(d.name))}")
        return sorted(set(left))

    def close(self) -> None:
        """Stop the exporters (they stop their ser2net), then the coordinator; any ser2net an
        exporter left is ended by its own pid."""
        self.ser2nets()
        procs = [e.proc for e in self.exporters.values()]
        if self.coordinator_proc is not None:
            procs.append(self.coordinator_proc)
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for e in self.exporters.values():
            for pid in e.ser2net:
                if _alive(pid):
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGTERM)


@contextlib.contextmanager
def running_lab(tmp: Path, labgrid_bin: Path,
                far_ends: dict[str, tuple[str, str]]) -> Iterator[Lab]:
    """A lab with one exporter per ``far_ends`` item (exporter name -> ("python" or
    "firmware", the served chip's URL: ``sim://?clock=6MHz``)), each exporting its bench as
    ``NAME/lm629-bench/*``; the first also exports ``NAME/lm629-spare/*``, a pseudo-terminal
    with nothing behind it (a bench whose board is off), the others ``NAME/lm629-link/*``,
    their bench by its link outside /dev/; stopped at the end, and the process list checked:
    nothing it started is left running."""
    lab = Lab(tmp, labgrid_bin)
    spare = os.openpty()
    with contextlib.ExitStack() as stack:
        for fd in spare:
            stack.callback(os.close, fd)
        try:
            lab.start_coordinator()
            benches = {}
            for name, (far_end, url) in far_ends.items():
                (tmp / name).mkdir()
                benches[name] = stack.enter_context(serve(tmp / name, far_end, url))
            lab.coordinator_ready()
            for i, (name, bench) in enumerate(benches.items()):
                # the first exporter also a spare port; the second its bench once more, by
                # the link sim serve made (not under /dev/: the exporter refuses to serve it)
                more = ({"lm629-spare": os.ttyname(spare[1])} if i == 0
                        else {"lm629-link": str(bench.link)})
                lab.add_exporter(name, bench, more=more)
            lab.wait_resources()
            yield lab
        finally:
            lab.close()
    # the benches stopped with the stack; now nothing of the lab may run
    deadline = time.monotonic() + 5
    while (left := lab.left_running()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not left, "the lab left processes running:\n" + "\n".join(left)
