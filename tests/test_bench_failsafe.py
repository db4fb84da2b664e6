"""The link failsafe on a served bench: one ``lm629 sim serve`` far end on a pty, each client
its own process, killed or cut off as a lab PC would be.

The server runs in this process (:class:`~lm629_host.sim.serve.SimServer`, the code behind
``lm629 sim serve``) so that :class:`RestWatch` can see, on the simulator's clock, when each
shaft last moved; the clients are separate processes on ``serial://LINK``.  The bound is the
one of tests/test_failsafe.py: failsafe (0.5 s) + the same abrupt stop sent by a live host
(measured on the same model) + 20 ms, from the host's last frame (the trip report: bridge
time of the trip minus the silence).  The served bench runs in real time, so each test waits
about a second of wall time for the bridge's timer.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from lm629_host.sim.model import chips_of
from lm629_host.sim.serve import SimServer
from test_bench import _env
from test_cli import _console_script
from test_failsafe import _host_stop_s

#: the far ends served here ("+uno": behind an Arduino Uno R3's USB chip)
FAILSAFE_FAR_ENDS = ["python", "python+uno", "firmware", "firmware+uno"]

CLIENT = textwrap.dedent("""\
    import os, sys, time
    from lm629_host.board import open_board
    url, how = sys.argv[1], sys.argv[2]
    b = open_board(url, axes=2)
    b.reset()
    for ax in b.axes:
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
    def run():
        for ax in b.axes:
            ax.load_trajectory(acceleration=655, velocity=131072, velocity_mode=True,
                               start=True)
    if how == "raise":
        with b:
            run()
            print("moving", flush=True)
            b.clock.sleep(0.1)
            1 / 0
    run()
    print("moving", flush=True)
    if how == "unplug":  # the port goes away under a live process: no byte reaches the bridge
        os.close(b.transport.pipe.port.fd)
    time.sleep(60)
    """)


class RestWatch:
    """When each chip's shaft last moved, on the simulator's clock: the model is run in
    steps of 1 ms (8192 clocks at 8 MHz) while ``watching``."""

    STEP = 8192

    def __init__(self, model) -> None:
        self.chips = chips_of(model)
        self.pos = [c.motion.real_position for c in self.chips]
        self.moved = [0.0] * len(self.chips)
        self.watching = False
        for k, c in enumerate(self.chips):
            c.advance_to = self._stepper(k, c, c.advance_to)

    def _stepper(self, k, chip, advance):
        def advance_to(tick: int) -> None:
            if not self.watching:
                advance(tick)
                return
            while chip.tick < tick:
                advance(min(tick, chip.tick + self.STEP))
                if chip.motion.real_position != self.pos[k]:
                    self.pos[k], self.moved[k] = chip.motion.real_position, chip.now()
        return advance_to

    def start(self) -> None:
        """Watch from now: every shaft counts as moving now."""
        self.pos = [c.motion.real_position for c in self.chips]
        self.moved = [c.now() for c in self.chips]
        self.watching = True

    def at_rest_for(self, seconds: float) -> bool:
        now = self.chips[0].now()
        return all(now - m >= seconds for m in self.moved)


@contextmanager
def served(tmp: Path, far_end: str) -> Iterator[tuple[SimServer, RestWatch]]:
    kind, _, usb = far_end.partition("+")
    url = "sim://?axes=2" + (f"&usb={usb}" if usb else "")
    if kind == "firmware":
        from lm629_host.sim.avr import toolchain_missing
        missing = toolchain_missing()
        if missing:
            pytest.skip(f"AVR toolchain missing ({', '.join(missing)})")
    server = SimServer(tmp / "bench", url, firmware=kind == "firmware")
    watch = RestWatch(server.model)
    with server:
        server.start()
        yield server, watch


def _lm629(link: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([_console_script(), "--port", f"serial://{link}", *args],
                          capture_output=True, text=True, timeout=60, env=_env())


def _client(link: Path, how: str) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", CLIENT, f"serial://{link}", how],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    line = p.stdout.readline()
    assert line.strip() == "moving", line + p.stderr.read()
    return p


def _wait_rest(watch: RestWatch, limit_s: float = 5.0) -> None:
    """Wall time, as the served bench runs in real time: until every shaft rested 0.1 s."""
    end = time.monotonic() + limit_s
    while not watch.at_rest_for(0.1):
        assert time.monotonic() < end, "the shafts never came to rest"
        time.sleep(0.02)


def _status(link: Path) -> tuple[dict, str]:
    p = _lm629(link, "--axis", "0,1", "status", "--json")
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), p.stderr


def death_to_rest(tmp: Path, far_end: str) -> tuple[float, dict, str]:
    """SIGKILL a client mid velocity-mode move on a two-axis board; returns the time from
    its last frame to the last shaft at rest (simulator seconds), the next process's status
    and its stderr."""
    with served(tmp, far_end) as (server, watch):
        client = _client(server.link, "kill")
        watch.start()
        client.send_signal(signal.SIGKILL)
        client.wait(10)
        _wait_rest(watch)
        watch.watching = False
        status, err = _status(server.link)
    trip = status["failsafe"]["trip"]
    assert trip is not None, err
    last = trip["at_s"] - trip["silent_s"]
    return max(watch.moved) - last, status, err


@pytest.mark.parametrize("far_end", FAILSAFE_FAR_ENDS)
def test_a_killed_host_has_every_axis_at_rest_and_the_next_process_is_told(tmp_path, far_end):
    took, status, err = death_to_rest(tmp_path, far_end)
    assert 0.5 <= took <= 0.5 + _host_stop_s("abrupt") + 0.020, took
    assert "the bridge stopped cs 0, cs 1 (abrupt stop) after the host was silent" in err
    assert status["failsafe"]["trip"]["cs"] == [0, 1]
    for row in status["axes"]:
        assert row["desired_velocity"] == 0 and row["real_velocity"] == 0
        assert "MOTOR_OFF" not in row["status_flags"]  # the PID holds
    assert status["failsafe"]["armed_s"] == 0.5 and not status["failsafe"]["tripped"]


@pytest.mark.parametrize("far_end", ["python", "firmware+uno"])
def test_a_pulled_cable_trips_the_bridge(tmp_path, far_end):
    with served(tmp_path, far_end) as (server, watch):
        client = _client(server.link, "unplug")  # alive, but nothing reaches the bridge
        watch.start()
        _wait_rest(watch)
        status, err = _status(server.link)
        client.kill()
        client.wait(10)
    assert status["failsafe"]["trip"]["cs"] == [0, 1], err


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_clean_close_after_move_no_wait_leaves_the_axis_moving(tmp_path, far_end):
    with served(tmp_path, far_end) as (server, _watch):
        link = server.link
        for args in (("reset",), ("filter", "--kp", "20", "--ds", "1"),
                     ("move", "200000", "--no-wait")):
            p = _lm629(link, *args)
            assert p.returncode == 0, p.stderr
        time.sleep(0.8)  # past the failsafe's 0.5 s on the bridge's clock
        a = _status(link)[0]
        time.sleep(0.1)
        b, err = _status(link)
    assert a["failsafe"]["trip"] is None and b["failsafe"]["trip"] is None, err
    assert b["axes"][0]["real_position"] > a["axes"][0]["real_position"] > 0


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_with_block_raising_mid_move_leaves_the_axes_at_rest(tmp_path, far_end):
    with served(tmp_path, far_end) as (server, _watch):
        p = _client(server.link, "raise")
        _, err = p.communicate(timeout=30)
        assert p.returncode == 1 and "ZeroDivisionError" in err
        status, err = _status(server.link)
    assert status["failsafe"]["trip"] is None, err  # the host stopped them, not the bridge
    for row in status["axes"]:
        assert row["desired_velocity"] == 0 and "MOTOR_OFF" not in row["status_flags"]
