"""A served bench behind the real ser2net (Debian's, started and stopped by the tests on
127.0.0.1): ``rfc2217://`` (telnet with RFC 2217) and ``socket://`` (raw TCP), with both far
ends, the Python bridge and the compiled firmware in simavr (``lm629 sim serve --pty``).

Numbers: the far end starts at 115200 baud (the firmware's rate).  After the handshake the host
asks for 1,000,000 (``fast_baud``'s default): through RFC 2217 the request reaches ser2net as
SET-BAUDRATE and ser2net sets its device to it, which the pty's own termios shows (B1000000);
raw TCP carries bytes only, so the link stays at 115200 and says so.  The moves run at 2
counts/sample (velocity word 131072; acceleration word 655, 0.01 counts/sample^2) on the 8 MHz
chip (a sample is 256 us): 4000 counts take about 0.6 s.  A recording of 0.3 s every 5 ms is
60 rows, 5 ms apart on the bridge's clock.  The S-curve (30000 counts/s, 400000 /s^2, 8e6 /s^3)
lands 6000 counts in about 0.3 s, within the 20-count tolerance.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import termios
import time

import pytest

import lm629_host
from lm629_host import SCurve, Status, TransportError
from served import _env, serve
from ser2net_fixture import ser2net, ser2net_version

FAR = ["python", "firmware"]
PROTOCOLS = ["rfc2217", "raw"]
#: the firmware's trip strobes all four chip selects: its bench has a chip on each
#: (tests/transports/test_late_host.py)
FULL_BOARD = {"python": "sim://", "firmware": "sim://?axes=4"}
VELOCITY, ACCELERATION = 131072, 655
#: 2 counts a sample of 256 us
COUNTS_PER_S = 2 / 256e-6


def lm629(url: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """The installed ``lm629`` on ``url``, as its own process."""
    from served import _console_script
    return subprocess.run([_console_script(), "--port", url, *args], capture_output=True,
                          text=True, timeout=timeout, env=_env())


def pty_speed(device: str) -> int:
    """The output speed (termios B constant) the pseudo-terminal is set to now: what ser2net
    set its device to (a pty shares one termios between its two ends)."""
    fd = os.open(os.path.realpath(device), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        return termios.tcgetattr(fd)[5]
    finally:
        os.close(fd)


@pytest.mark.parametrize("protocol", PROTOCOLS)
@pytest.mark.parametrize("far_end", FAR)
def test_every_command_a_wait_a_recording_and_a_shaped_move_through_ser2net(
        tmp_path, far_end, protocol):
    """The link through ser2net does all a bench does: the CLI's selftest, a far-side wait, a
    recording during a move and a shaped move, at the rate the far UART really runs at."""
    assert ser2net_version().startswith("4.")  # the YAML config (4.3.11 here, in the docs)
    with serve(tmp_path, far_end) as bench, ser2net(bench.link, tmp_path, protocol) as s2n:
        url = s2n.url
        # every command: the selftest's core runs the chip's command set and compares each
        # read with the model, from its own process, as a user would
        p = lm629(url, "selftest")
        assert p.returncode == 0 and "verdict: PASS" in p.stdout, p.stdout + p.stderr
        with lm629_host.open(url) as chip:
            t = chip.transport
            fast = protocol == "rfc2217"
            baud, why = t.line_rate()
            if fast:  # SET-BAUDRATE reached ser2net, which set its device to it
                assert (baud, why) == (1_000_000, "switched from 115200 baud after the handshake")
                assert pty_speed(bench.link) == termios.B1000000
            else:
                assert baud == 115200 and "raw TCP cannot set the far UART's rate" in why
                assert pty_speed(bench.link) == termios.B115200
            chip.reset()
            chip.load_filter(kp=20, kd=100)
            chip.update_filter()
            # a wait on the far side (WAIT_STATUS through ser2net)
            chip.load_trajectory(acceleration=ACCELERATION, velocity=VELOCITY, position=4000,
                                 start=True)
            assert chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5) & Status.TRAJECTORY_COMPLETE
            assert chip.read_desired_position() == 4000
            # a move, and a recording while it runs: 60 rows 5 ms apart on the bridge's clock
            move = chip.move_to(0, velocity=VELOCITY, acceleration=ACCELERATION)
            trace = chip.record(0.005, 0.3)
            assert trace.far_side and len(trace.rows) == 60 and not trace.missing
            steps = [b - a for a, b in zip(trace.t, trace.t[1:])]
            assert all(abs(s - 0.005) < 1e-6 for s in steps), steps[:5]
            assert trace.desired[0] > trace.desired[-1]  # it recorded the move going down
            assert abs(move.wait(timeout=10).position) <= 20
            # a shaped move, its pieces issued by the bridge
            shaped = chip.move_profile(6000, SCurve(velocity=30000, acceleration=400000,
                                                    jerk=8e6))
            result = shaped.wait(timeout=10)
            assert abs(result.position - 6000) <= 20
            assert chip.read_desired_position() == 6000
        st = lm629(url, "status", "--json")
        assert st.returncode == 0, st.stderr
        link = json.loads(st.stdout)["link"]
        assert link["baud"] == (1_000_000 if protocol == "rfc2217" else 115200)
        assert json.loads(st.stdout)["failsafe"]["trip"] is None  # closed, not tripped


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_a_second_client_is_refused_in_one_line(tmp_path, protocol):
    """ser2net serves one client at a time: the second is told so in one line that says
    ser2net answered "Port already in use", and the first keeps its link."""
    with serve(tmp_path, "python") as bench, ser2net(bench.link, tmp_path, protocol) as s2n:
        with lm629_host.open(s2n.url) as first:
            first.reset()
            p = lm629(s2n.url, "status")
            assert p.returncode == 3, p.stdout + p.stderr
            lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
            assert len(lines) == 1, p.stderr
            assert "Port already in use" in lines[0] and "another client" in lines[0], lines
            assert f"cannot open {s2n.url}" in lines[0] or s2n.url in lines[0]  # as typed
            assert "ign_set_control" not in lines[0]
            assert first.read_status() & Status.MOTOR_OFF  # the first client's link still works
        p = lm629(s2n.url, "status")  # once the first has gone, the next one is served
        assert p.returncode == 0, p.stderr


@pytest.mark.under_load  # a failsafe trip: timed behaviour a busy host must keep
@pytest.mark.parametrize("protocol", PROTOCOLS)
@pytest.mark.parametrize("far_end", FAR)
def test_ser2net_killed_mid_move_the_bridge_stops_the_axis_and_the_next_open_is_told(
        tmp_path, far_end, protocol):
    """ser2net dies (SIGKILL) 0.3 s into a 100000-count move: the host's next command fails in
    one line naming the network path; the bridge, silent for its failsafe (0.2 s here), stops
    the axis short of the target (about 3000 counts in); the next open through a restarted
    ser2net is told of the trip and acknowledges it, and the shaft is at rest."""
    with serve(tmp_path, far_end, FULL_BOARD[far_end]) as bench, \
            ser2net(bench.link, tmp_path, protocol) as s2n:
        chip = lm629_host.open(f"{s2n.url}?failsafe=0.2")
        try:
            chip.reset()
            chip.load_filter(kp=20, kd=100)
            chip.update_filter()
            t_move = time.monotonic()
            chip.move_to(100_000, velocity=VELOCITY, acceleration=ACCELERATION)
            time.sleep(0.3)
            s2n.kill()
            ran_s = time.monotonic() - t_move + 0.2  # the longest it could run: + the failsafe
            with pytest.raises(TransportError) as e:
                for _ in range(50):  # the keep-alive or this read finds the link gone
                    chip.read_real_position()
                    time.sleep(0.02)
            msg = str(e.value)
            assert "\n" not in msg and "is it still running" in msg, msg
            assert "ign_set_control" not in msg  # the port as the user gave it
        finally:
            t0 = time.monotonic()
            chip.close()  # a link already gone closes without a hang
            assert time.monotonic() - t0 < 2.0
        s2n.start()
        p = lm629(s2n.url, "status", "--json")
        assert p.returncode == 0, p.stderr
        first = json.loads(p.stdout)
        trip = first["failsafe"]["trip"]
        assert trip is not None and 0 in trip["cs"], first
        assert trip["silent_s"] == pytest.approx(0.2, abs=0.01)
        assert "after the host was silent for 0.20 s" in trip["text"]
        p = lm629(s2n.url, "status", "--json")
        again = json.loads(p.stdout)
        assert again["failsafe"]["trip"] is None  # acknowledged by the first open
        # stopped short of the target where the bridge stopped it (+ 0.25 s for the
        # abrupt stop and the far end's real-time steps), at rest
        assert 0 < first["real_position"] < COUNTS_PER_S * (ran_s + 0.25), (first, ran_s)
        assert first["desired_velocity"] == 0
        assert again["desired_velocity"] == 0 and \
            abs(again["real_position"] - first["real_position"]) <= 20, (first, again)


def test_a_write_ser2net_does_not_take_fails_within_the_write_deadline(tmp_path):
    """pyserial's RFC 2217 client takes no write_timeout; the link's write deadline
    (WRITE_TIMEOUT_S, 2 s, as on every other port) is its socket's timeout instead.  ser2net
    stopped (SIGSTOP) takes nothing: once the kernel's buffers are full a write fails, 2 s
    after it started waiting (pyserial's own socket timeout was 5 s), as a TransportError."""
    from lm629_host.transports.netport import WRITE_TIMEOUT_S
    from lm629_host.transports.serial import SerialPipe, open_port

    with serve(tmp_path, "python") as bench, ser2net(bench.link, tmp_path, "rfc2217") as s2n:
        pipe = SerialPipe(open_port(s2n.url, 115200), device=s2n.url)
        try:
            s2n.proc.send_signal(signal.SIGSTOP)
            chunk = bytes(64 * 1024)
            longest = 0.0
            with pytest.raises(TransportError, match="write failed") as e:
                for _ in range(2000):  # 128 MB: far more than the loopback buffers hold
                    t0 = time.monotonic()
                    pipe.write(chunk)
                    longest = max(longest, time.monotonic() - t0)
            waited = time.monotonic() - t0
            assert WRITE_TIMEOUT_S - 0.1 <= waited < WRITE_TIMEOUT_S + 1.5, (waited, longest)
            assert "is it still running" in str(e.value)
        finally:
            s2n.proc.send_signal(signal.SIGCONT)
            pipe.close()
