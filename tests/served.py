"""Helpers for the tests that drive the installed ``lm629`` command and a persistent
``lm629 sim serve`` bench from separate processes (shared by tests/cli, tests/wiring,
tests/integrations and the others that start a served bench)."""

from __future__ import annotations

import inspect
import json
import os
import shutil
import signal
import subprocess
import re
import pytest
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import hogs
from lm629_host.sim.harness import toolchain_missing


@contextmanager
def _sim_serve():
    """``lm629 sim serve --tcp`` as its own process (a board that keeps its state, real
    time): yields the port URL the tests pass as --lm629-port."""
    env = {k: v for k, v in os.environ.items() if k not in ("LM629_PORT", "LM629_SIM_STRICT")}
    proc = subprocess.Popen([_console_script(), "sim", "serve", "--tcp", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        banner = proc.stdout.readline()
        m = re.search(r"on TCP port ([\d.]+:\d+)", banner)
        assert m, banner + proc.stderr.read()
        yield f"socket://{m.group(1)}"  # a pyserial URL is a port as it is
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)


#: the far ends served; "+uno": behind an Arduino Uno R3's USB chip (``usb=uno``: the 16U2's
#: 4.096 ms flush tick and 1 ms frames, lm629_host/sim/usb.py), in real time as on a bench
FAR_ENDS = ["python", "firmware", "firmware+uno"]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "LM629_PORT"}
    env["LM629_SIM_STRICT"] = "1"
    return env


class Bench:
    def __init__(self, link: Path, proc: subprocess.Popen) -> None:
        self.link = link
        self.server = proc
        self.exe = _console_script()

    def argv(self, *args: str) -> list[str]:
        return [self.exe, "--port", f"serial://{self.link}", *args]

    def run(self, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
        return subprocess.run(self.argv(*args), capture_output=True, text=True,
                              timeout=timeout, env=_env())

    def status(self) -> dict:
        p = self.run("status", "--json")
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout)

    def ready(self, kp: int = 20) -> None:
        for args in (("reset",), ("filter", "--kp", str(kp), "--ds", "1")):
            p = self.run(*args)
            assert p.returncode == 0, p.stderr


@contextmanager
def serve(tmp: Path, far_end: str, url: str = "sim://"):
    """``lm629 sim serve --pty tmp/bench`` as a process; ready once it printed its banner."""
    far_end, _, usb = far_end.partition("+")
    if usb:
        url += f"{'&' if '?' in url else '?'}usb={usb}"
    if far_end == "firmware":
        missing = toolchain_missing()
        if missing:
            pytest.skip(f"AVR toolchain missing ({', '.join(missing)})")
    link = tmp / "bench"
    argv = [_console_script(), "sim", "serve", "--pty", str(link), "--url", url]
    if far_end == "firmware":
        argv.append("--firmware")
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env())
    try:
        banner = proc.stdout.readline()  # blocks until the server is serving (or died)
        assert banner.startswith("serving "), banner + proc.stderr.read()
        assert link.is_symlink()
        yield Bench(link, proc)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)
    assert not os.path.lexists(link)  # it removed the link it made


def err_lines(result) -> list[str]:
    return [ln for ln in result.stderr.splitlines() if ln.strip()]


def _console_script() -> str:
    """The installed ``lm629`` script: next to this interpreter (a venv, CI) or on PATH.  Its
    absence is a failure, not a skip: the console script is part of what is tested."""
    import sysconfig

    for exe in (os.path.join(sysconfig.get_path("scripts"), "lm629"), shutil.which("lm629")):
        if exe and os.path.exists(exe):
            return exe
    pytest.fail("the lm629 console script is not installed (pip install -e .)")


#: how many CPU-burning processes run beside the tests (``pytest --cpu-hogs N``, or the
#: environment variable): a lab PC is not idle, and whatever is timed must hold on a busy one
CPU_HOGS_ENV = "LM629_CPU_HOGS"


@contextmanager
def cpu_hogs(n: int) -> Iterator[list[subprocess.Popen]]:
    """``n`` CPU-burning processes (:func:`hogs.spawn`) for the duration of the block."""
    procs = hogs.spawn(n)
    try:
        yield procs
    finally:
        hogs.end(procs)


#: documents whose blocks run against the served bench (tests/test_docs.py starts one per
#: document on first use; the blocks after it share its state)
_SERVED_DOC_WORDS = ("/dev/ttyACM0", "/dev/ttyUSB0", "sim serve", "socket://")
#: test modules that drive a served bench from separate processes
SERVED_MODULES = frozenset({"test_served_bench", "test_served_bench_failsafe",
                            "test_served_bench_profile", "test_served_bench_trip", "test_journey"})


def is_served(item: pytest.Item, served_docs: set[Path]) -> bool:
    """Whether ``item`` runs against a ``lm629 sim serve`` far end in real time (the
    ``served`` marker; only those also marked ``under_load`` run beside CPU hogs)."""
    if item.path.stem in SERVED_MODULES or "served" in item.name or _starts_a_server(item):
        return True
    block = getattr(item, "callspec", None) and item.callspec.params.get("block")
    return block is not None and getattr(block, "doc", None) in served_docs


def _starts_a_server(item: pytest.Item) -> bool:
    """Whether the test's own body starts a served bench (:func:`serve`, :func:`_sim_serve`,
    or ``lm629 sim serve`` as an argv of its own)."""
    func = getattr(item, "function", None)
    if func is None:
        return False
    try:
        source = inspect.getsource(func)
    except (OSError, TypeError):
        return False
    return any(w in source for w in ("with serve(", "_sim_serve()", '"sim", "serve"'))


def served_docs(items: list[pytest.Item]) -> set[Path]:
    """The documents one of whose blocks uses the served bench."""
    docs: set[Path] = set()
    for item in items:
        block = getattr(item, "callspec", None) and item.callspec.params.get("block")
        text = getattr(block, "text", "")
        if block is not None and any(w in text for w in _SERVED_DOC_WORDS):
            docs.add(block.doc)
    return docs
