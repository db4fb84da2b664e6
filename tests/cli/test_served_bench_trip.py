"""A served bench outlives what happens to its clients and to itself, as a board does: a
client killed mid-move on a one-chip bench trips the failsafe and the server stays up
(``status`` reports the trip, ``clear`` and a new move work); a server paused for 1.5 s (a busy
machine, SIGSTOP) does not trip an idle client that was feeding it all along.  Each client is
its own process; the far ends are the Python bridge, the compiled firmware in simavr, and the
firmware behind an Uno's USB chip."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from served import _env, serve

FAR_ENDS = ["python", "firmware", "firmware+uno"]
#: timed behaviour a busy lab PC must keep: CI runs these beside two CPU hogs (-m under_load)
pytestmark = pytest.mark.under_load


@pytest.mark.parametrize("far_end", FAR_ENDS)
def test_a_client_killed_mid_move_on_a_one_chip_bench_trips_and_the_server_lives(tmp_path, far_end):
    """The failsafe's scan strobes every chip select: on a one-chip firmware bench the
    unwired ones float (read FF) and are skipped, as on a board, instead of ending the server
    with "the firmware strobed chip select 1"."""
    with serve(tmp_path, far_end) as b:
        b.ready()
        mover = subprocess.Popen(b.argv("move", "2000000"), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, env=_env())
        assert mover.stdout is not None
        line = mover.stdout.readline()  # "moving to ...": the move has started
        assert line.startswith("moving to"), line + mover.communicate()[1]
        time.sleep(0.3)
        assert mover.poll() is None, mover.communicate()
        mover.kill()
        mover.communicate(timeout=10)
        time.sleep(1.0)  # past the 0.5 s failsafe
        assert b.server.poll() is None, b.server.communicate(timeout=10)
        st = b.status()
        trip = st["failsafe"]["trip"]
        assert trip is not None and trip["cs"] == [0], st["failsafe"]
        assert st["desired_velocity"] == 0 and st["real_velocity"] == 0
        p = b.run("clear")
        assert p.returncode == 0, p.stderr
        start = st["real_position"]
        p = b.run("move", str(start + 1000))
        assert p.returncode == 0, p.stderr
        after = b.status()
        assert abs(after["real_position"] - (start + 1000)) <= 20
        assert after["failsafe"]["trip"] is None
        assert b.server.poll() is None


@pytest.mark.parametrize("far_end", FAR_ENDS)
def test_a_command_paused_mid_move_says_the_trip_in_one_line(tmp_path, far_end):
    """`lm629 move` stopped (SIGSTOP) for 1.5 s mid-move: the bridge stops the axis after
    0.5 s of silence, and the command, woken, says so once: one line naming the stop, exit 3
    (the keep-alive that heard it first leaves the telling to the error)."""
    with serve(tmp_path, far_end) as b:
        b.ready()
        mover = subprocess.Popen(b.argv("move", "2000000"), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True, env=_env())
        assert mover.stdout is not None
        line = mover.stdout.readline()
        assert line.startswith("moving to"), line + mover.communicate()[1]
        time.sleep(0.3)
        mover.send_signal(signal.SIGSTOP)
        time.sleep(1.5)
        mover.send_signal(signal.SIGCONT)
        out, err = mover.communicate(timeout=60)
        assert mover.returncode == 3, out + err
        said = [ln for ln in (out + err).splitlines() if "the bridge stopped cs 0" in ln]
        assert len(said) == 1, out + err
        assert said[0].startswith("lm629: error:") and "paused" in said[0], said


_IDLE_CLIENT = """
import sys, lm629_host
with lm629_host.open(sys.argv[1]) as chip:
    chip.read_status()
    print("open", flush=True)
    sys.stdin.readline()  # idle: only the failsafe feeder talks
    chip.read_status()
    state = chip.transport.failsafe_state()
    print("tripped" if state.tripped else "not tripped", flush=True)
"""


@pytest.mark.parametrize("far_end", FAR_ENDS)
def test_a_far_end_paused_for_1_5_s_does_not_trip_an_idle_client(tmp_path, far_end):
    """The client's feeds reached the pseudo-terminal while the server was stopped, as a real
    bridge's UART takes bytes whatever its program is doing; the server reads them before it
    judges the host silent, so it wakes up without tripping and answers the next request."""
    with serve(tmp_path, far_end) as b:
        client = subprocess.Popen([sys.executable, "-c", _IDLE_CLIENT, f"serial://{b.link}"],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, env=_env())
        assert client.stdout is not None and client.stdout.readline().strip() == "open"
        time.sleep(0.5)
        b.server.send_signal(signal.SIGSTOP)
        time.sleep(1.5)
        b.server.send_signal(signal.SIGCONT)
        time.sleep(0.3)
        out, err = client.communicate("\n", timeout=60)
        assert client.returncode == 0, err
        assert out.strip() == "not tripped", err
        assert "silent" not in err and "HELLO unanswered" not in err, err


def test_a_client_that_gave_up_on_a_long_wait_leaves_the_firmware_answering(tmp_path):
    """A client's RUN waits 10 s for a status mask no status matches (0), then the client is
    gone (a burst of random frames with valid CRCs did this): the next client's HELLO ends
    the wait, so `status` works at once instead of "is the bridge firmware flashed?"."""
    import serial

    from lm629_host.bridge.protocol import FrameType, encode_frame

    with serve(tmp_path, "firmware") as b:
        with serial.Serial(str(b.link), 115200, timeout=0.2) as port:
            port.write(encode_frame(FrameType.RUN, 1, bytes((0, 0, 0, 0x08, 0x00, 0x27, 0x10))))
            assert port.read(64) == b""  # still waiting
        p = b.run("status", timeout=30)
        assert p.returncode == 0, p.stderr
