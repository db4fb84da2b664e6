"""A late host: frames it did not ask for, exact simulated sleeps with the failsafe armed, and
(as separate processes on a served bench, in real time) a held lock, busy CPUs and a paused
host.

Numbers: the failsafe is 0.5 s by default.  On the wall clock the keep-alive feeds a link quiet
for a quarter of it (0.125 s), on a simulated clock after three quarters (0.375 s), exactly
then.  The served moves run at 2 counts/sample (velocity word 131072, 0.01 counts/sample^2
ramp: word 655) on the default 8 MHz chip (sample 256 us), so 20000 counts take about 2.6 s.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

import lm629_host
from lm629_host import FailsafeTripped
from lm629_host.bridge.protocol import FAILSAFE_FEED, FailsafeState, FrameType, encode_frame
from lm629_host.transports.failsafe import SIMULATED_FEED
from lm629_host.transports.simemu import open_emulated
from served import FAR_ENDS, serve

from sim_urls import available

#: a trip as the bridge reports it: cs 0 stopped abruptly after 0.5 s of silence
TRIP = FailsafeState(timeout_ms=500, tripped=True, chips=0b1, silent_ms=500, at_ms=12_345)


def _queue_to_host(t, frame: bytes) -> None:
    """Put ``frame`` on the line from the far end, ahead of whatever it answers next."""
    pipe = t.pipe
    now = t.clock.now()
    for b in frame:
        pipe._to_host.append((now, b, pipe.rate))


def test_an_unsolicited_failsafe_report_between_request_and_answer_is_an_event():
    """A FAILSAFE_REPLY with the feed's seq arrives before the answer to a RUN whose seq
    would be that seq's neighbour: it goes to the failsafe as a trip heard (never read as the
    RUN's answer, never "reflash"), the RUN gets its own answer, and the next program is told
    the trip, once, with what the bridge stopped and how."""
    t = open_emulated("sim://")
    chip = lm629_host.LM629(t)
    chip.reset()
    t._seq = 0xFF  # the next request's seq would come round to the feed's (0)
    _queue_to_host(t, encode_frame(FrameType.FAILSAFE_REPLY, 0, TRIP.encode()))
    assert chip.read_real_position() == 0  # the RUN's own answer
    assert t._seq == 1 and t.stale_replies == 0
    assert t.failsafe_report == TRIP
    with pytest.raises(FailsafeTripped) as e:
        chip.read_real_position()
    msg = str(e.value)
    assert "\n" not in msg and "reflash" not in msg
    assert "the bridge stopped cs 0 (abrupt stop) after the host was silent for 0.50 s" in msg
    assert "nothing of this program ran" in msg and "lm629 clear" in msg
    assert e.value.stopped == (0,) and e.value.action == "abrupt"
    assert chip.read_real_position() == 0  # told once; reads go on


def test_a_trip_the_keep_alive_hears_is_said_once(caplog):
    """A trip report the keep-alive reads while nobody calls the chip: a host that calls within
    a second is told by the error alone (a command line prints one line, not a notice and then
    the error); a host busy in its own code for longer hears it in the log, once."""
    caplog.set_level("WARNING")
    for busy_s, logged in ((0.5, 0), (3.0, 1)):
        caplog.clear()
        t = open_emulated("sim://")
        chip = lm629_host.LM629(t)
        chip.reset()
        _queue_to_host(t, encode_frame(FrameType.FAILSAFE_REPLY, 0, TRIP.encode()))
        chip.clock.sleep(busy_s)  # the simulated clock's keep-alive feeds and reads meanwhile
        assert t.failsafe_report == TRIP
        said = [r for r in caplog.records if "the bridge stopped cs 0" in r.getMessage()]
        assert len(said) == logged, (busy_s, caplog.text)
        with pytest.raises(FailsafeTripped, match="the bridge stopped cs 0"):
            chip.read_real_position()
        chip.clock.sleep(3.0)
        t.close()
        said = [r for r in caplog.records if "the bridge stopped cs 0" in r.getMessage()]
        assert len(said) == logged, (busy_s, caplog.text)


def test_a_report_without_a_trip_and_a_feeds_pong_change_nothing():
    t = open_emulated("sim://")
    chip = lm629_host.LM629(t)
    _queue_to_host(t, encode_frame(FrameType.FAILSAFE_REPLY, 0,
                                   FailsafeState(timeout_ms=500).encode()))
    _queue_to_host(t, encode_frame(FrameType.PONG, 0))
    assert chip.read_real_position() == 0
    assert t.failsafe_report is None and t.stale_replies == 0
    assert chip.read_real_position() == 0


@pytest.mark.parametrize("url", ["sim+emu://", "sim+avr://", "sim+avr://?usb=uno"])
def test_a_simulated_sleep_is_exact_with_the_failsafe_armed(url):
    """clock.sleep(10.0) advances the chip by 10.000 s (+- 2 ms), fed all the while: the feeds
    are written between the steps of the sleep, never added to it (it was 10.19 s)."""
    if not available(url.split("?")[0]):
        pytest.skip(f"{url} not available here")
    chip = lm629_host.open(url)
    try:
        t = chip.transport
        assert t.failsafe_state().timeout_ms == 500
        model = t.model
        for seconds in (10.0, 0.3, 1.0):
            t0 = model.now()
            chip.clock.sleep(seconds)
            assert abs(model.now() - t0 - seconds) <= 0.002, (seconds, model.now() - t0)
        assert not t.failsafe_state().tripped
    finally:
        chip.close()


def test_script_feed_mode_feeds_only_on_the_scripts_calls():
    """failsafe_feed=script: a sleep feeds nothing, so a script that stops calling trips the
    bridge; a script that calls feed() does not."""
    chip = lm629_host.open("sim+emu://?failsafe_feed=script")
    t = chip.transport
    chip.reset()
    for _ in range(8):
        chip.clock.sleep(0.3)
        chip.transport.feed()
    assert not t.emulator.failsafe.tripped
    chip.clock.sleep(0.6)
    assert t.emulator.failsafe.tripped
    with pytest.raises(FailsafeTripped, match="failsafe_feed=script"):
        chip.read_real_position()


# ---------------------------------------------------------------------- served, in real time
CLIENT = textwrap.dedent('''
    import sys, time
    import lm629_host
    from lm629_host import FailsafeTripped
    port, scenario = sys.argv[1], sys.argv[2]
    chip = lm629_host.open(port)
    t = chip.transport
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    try:
        if scenario == "lock":
            with t.lock:
                time.sleep(2.0)  # a user sequence holding the lock, doing nothing on the bus
        elif scenario == "idle":
            time.sleep(3.0)
        elif scenario == "move":
            move = chip.move_to(20000, velocity=131072, acceleration=655)
            print("moving", flush=True)
            move.wait(timeout=30)
            print("position", chip.read_real_position(), flush=True)
        state = t.failsafe_state()
        ka = getattr(getattr(t, "failsafe", None), "keepalive", None)  # how late the feeder got
        print("tripped" if state.tripped else "fed", round(getattr(ka, "worst_gap_s", -1), 3),
              getattr(ka, "gaps", -1), flush=True)
    except FailsafeTripped as exc:
        print("FailsafeTripped:", exc, flush=True)
        sys.exit(3)
''')


def _client(tmp_path, bench, scenario: str) -> subprocess.Popen:
    script = tmp_path / "client.py"
    script.write_text(CLIENT)
    return subprocess.Popen([sys.executable, str(script), f"serial://{bench.link}", scenario],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.under_load
@pytest.mark.parametrize("far_end", FAR_ENDS[:2])
def test_a_host_holding_the_lock_for_2_s_is_not_tripped(tmp_path, far_end):
    """The keep-alive sends between programs under the link's own lock, not the user's."""
    with serve(tmp_path, far_end) as bench:
        p = _client(tmp_path, bench, "lock")
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, out + err
        assert out.split()[0] == "fed", out


@pytest.fixture
def cpu_hogs(request):
    """Two processes burning CPU beside the test (this machine has two cores): those the run
    has already (``--cpu-hogs``, the busy-machine pass) count towards the two."""
    have = request.config.getoption("--cpu-hogs")
    hogs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"])
            for _ in range(max(0, 2 - have))]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
            h.wait()


@pytest.mark.under_load
@pytest.mark.parametrize("far_end", FAR_ENDS[:2])
def test_an_idle_host_beside_two_cpu_hogs_is_not_tripped(tmp_path, far_end, cpu_hogs):
    with serve(tmp_path, far_end) as bench:
        p = _client(tmp_path, bench, "idle")
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, out + err
        verdict, worst, _late = out.split()
        assert verdict == "fed", out
        assert float(worst) < 0.5, out  # the feeder's worst turn, well inside the timeout


def _pause(p: subprocess.Popen, seconds: float) -> None:
    line = p.stdout.readline()
    assert line.startswith("moving"), line + p.stderr.read()
    time.sleep(0.5)  # mid-move
    os.kill(p.pid, signal.SIGSTOP)
    time.sleep(seconds)
    os.kill(p.pid, signal.SIGCONT)


#: the firmware's trip strobes all four chip selects: the served firmware bench is built with
#: a chip on each (a bench with fewer makes the harness stop at the unwired one's strobe, a far
#: end matter of its own)
FULL_BOARD = {"python": "sim://", "firmware": "sim://?axes=4"}


@pytest.mark.under_load
@pytest.mark.parametrize("far_end", FAR_ENDS[:2])
def test_a_host_paused_2_s_mid_move_is_told_the_truth(tmp_path, far_end):
    """SIGSTOP for 2 s mid-move: the bridge stops the axis after 0.5 s of silence; the host,
    woken, hears it before its next program: FailsafeTripped, one line, what the bridge
    stopped and how, and that this host was silent (not a cable, not "reflash")."""
    with serve(tmp_path, far_end, FULL_BOARD[far_end]) as bench:
        p = _client(tmp_path, bench, "move")
        _pause(p, 2.0)
        out, err = p.communicate(timeout=60)
        assert p.returncode == 3, out + err
        line = [ln for ln in out.splitlines() if ln.startswith("FailsafeTripped")]
        assert len(line) == 1, out + err
        msg = line[0]
        assert "the bridge stopped cs 0" in msg
        assert "(abrupt stop) after the host was silent for 0.50 s" in msg
        # told by whichever woke first: the program (its own silence) or the keep-alive
        assert "this host sent nothing for" in msg or "keep-alive was held up for" in msg
        assert "paused" in msg
        for lie in ("COULD NOT STOP", "reflash", "cable"):
            assert lie not in msg
        assert bench.status()["failsafe"]["tripped"] is False  # the next open acknowledged it


@pytest.mark.under_load
@pytest.mark.parametrize("far_end", FAR_ENDS[:2])
def test_a_host_paused_0_2_s_mid_move_finishes_it(tmp_path, far_end):
    with serve(tmp_path, far_end) as bench:
        p = _client(tmp_path, bench, "move")
        _pause(p, 0.2)
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, out + err
        pos = int(out.split("position")[1].split()[0])
        assert abs(pos - 20000) <= 20, out
        assert "fed" in out


# ---------------------------------------------------------------------- PROFILE in top-ups
def test_a_schedule_longer_than_the_bridge_holds_is_streamed_in_top_ups():
    """150 pieces 20 ms apart (3 s; the bridge holds 64): the first 63 go out at once, the
    rest as the host gets to the link (here: a status read every 0.2 s, and the sleeps'
    keep-alive turns); every piece is issued by the bridge, none later than one program."""
    chip = lm629_host.open("sim+emu://")
    t = chip.transport
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.load_trajectory(acceleration=655, velocity=65536, position=10_000_000, start=True)
    pieces = [(0.02 * (k + 1), 65536 + 655 * (k % 7)) for k in range(150)]
    state = t.profile(None, pieces, new=True)
    assert state.queued == 150 - 63 and state.issued + state.pending == 63
    emu = t.emulator
    for _ in range(20):
        chip.clock.sleep(0.2)
        chip.read_status()
    state = t.profile(None, [], new=False)
    assert state.queued == 0 and state.pending == 0 and not state.cancelled
    assert state.issued == emu.stats.pieces == 150
    assert state.late_max_s < 0.011
    assert not t.profiles.streaming


def test_a_stream_is_topped_up_by_the_keep_alive_of_a_host_that_only_sleeps():
    chip = lm629_host.open("sim+emu://")
    t = chip.transport
    chip.reset()
    chip.load_trajectory(acceleration=655, velocity=65536, position=10_000_000, start=True)
    t.profile(None, [(0.02 * (k + 1), 65536) for k in range(100)], new=True)
    chip.clock.sleep(2.5)  # no program: the keep-alive's turns (every 0.375 s) top it up
    state = t.profile(None, [], new=False)
    assert state.issued == 100 and state.queued == 0 and state.late_max_s < 0.011


class _StalledPipe:
    """A pipe whose host stalls in every read (the process paused for ``stall`` s): its clock
    jumps past the read's timeout and nothing has come."""

    def __init__(self, stall: float) -> None:
        self.stall = stall
        self.clock = self
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s

    def write(self, data: bytes) -> None:
        pass

    def read(self, timeout_s: float) -> bytes:
        self.t += timeout_s + self.stall
        return b""

    def close(self) -> None:
        pass


def test_a_timeout_after_the_host_stalled_says_the_host_was_late():
    """Every wait for the answer came back 1.5 s late by the host's own clock: the give-up
    says this host stalled (paused, starved of CPU), not that the line is noisy."""
    from lm629_host.errors import LinkError
    from lm629_host.transports.link import LinkTransport

    t = LinkTransport(_StalledPipe(1.5), "serial:///dev/ttyACM0", handshake=False)
    with pytest.raises(LinkError) as e:
        t._exchange(FrameType.RUN_SHORT, b"\x00", 0.05, "RUN of 1 operation(s)", 1)
    msg = str(e.value)
    assert "this host was late: it stalled for 1.55 s" in msg
    assert e.value.host_late_s == pytest.approx(1.55)
    assert "cable" not in msg and "too noisy" not in msg and "\n" not in msg


def test_a_pipe_on_a_pty_or_a_socket_never_says_check_the_usb_cable(tmp_path):
    from lm629_host.transports.serial import line_advice_of

    master, slave = os.openpty()
    try:
        link = tmp_path / "bench"
        link.symlink_to(os.ttyname(slave))  # as `lm629 sim serve --pty` links it
        for device in (os.ttyname(slave), str(link)):
            assert "pseudo-terminal" in line_advice_of(device)
    finally:
        os.close(master)
        os.close(slave)
    assert "network" in line_advice_of("socket://127.0.0.1:5000")
    assert line_advice_of("/dev/ttyACM0") is None  # a USB serial adapter: the cable advice


def test_a_recording_during_a_stream_is_not_cut_by_a_top_up():
    """The keep-alive's turns during a recording feed it (FAILSAFE_FEED) and never top the
    stream up (any other byte would end the recording); the next program does."""
    chip = lm629_host.open("sim+emu://")
    t = chip.transport
    chip.reset()
    chip.load_trajectory(acceleration=655, velocity=65536, position=10_000_000, start=True)
    t.profile(None, [(0.02 * (k + 1), 65536) for k in range(100)], new=True)
    trace = chip.record(0.01, 1.0)
    assert len(trace.rows) == 100 and not trace.missing
    assert t.profiles.streaming  # the rest waits for the host's next program
    chip.read_status()
    chip.clock.sleep(1.5)
    assert t.profile(None, [], new=False).issued == 100


# ---------------------------------------------------------------------- which trip message
class _FeedsLost:
    """A line that loses every keep-alive feed (and nothing else): the host's keep-alive keeps
    turning, the bridge hears nothing between programs."""

    def __init__(self, pipe) -> None:
        self.pipe = pipe
        self.clock = pipe.clock

    def write(self, data: bytes) -> None:
        if data not in (FAILSAFE_FEED, SIMULATED_FEED):
            self.pipe.write(data)

    def __getattr__(self, name: str):
        return getattr(self.pipe, name)


def test_a_trip_while_the_keep_alive_kept_turning_blames_the_line():
    """The keep-alive turned at every step of the sleep (no stall), but its feeds were lost:
    the trip message says it kept turning, not that the host was held up."""
    t = open_emulated("sim://", wrap=_FeedsLost)
    chip = lm629_host.LM629(t)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.clock.sleep(1.0)  # 2x the failsafe: fed (and lost) every 0.375 s
    assert t.emulator.failsafe.tripped
    with pytest.raises(FailsafeTripped) as e:  # a trajectory command: the bridge refuses it
        chip.move_to(1000, velocity=131072, acceleration=655)
    msg = str(e.value)
    assert "keep-alive kept turning" in msg and "lost on the line" in msg, msg
    assert "held up" not in msg and "sent nothing" not in msg, msg
    t.close()


def test_a_trip_while_the_keep_alive_was_held_up_says_so(tmp_path):
    """The keep-alive's thread held off the interpreter for 1.2 s (the main thread keeps the
    GIL: a switch interval of 5 s), the host's commands quiet meanwhile: the bridge trips
    after 0.5 s; the keep-alive, let run again, feeds before the next program, so the host
    was not silent at that program: the message says the keep-alive was held up (for ~1.2 s,
    more than half the timeout), not that it kept turning."""
    with serve(tmp_path, "python") as bench:
        chip = lm629_host.open(f"serial://{bench.link}")
        try:
            chip.reset()
            chip.load_filter(kp=20, kd=100)
            chip.update_filter()
            old = sys.getswitchinterval()
            sys.setswitchinterval(5.0)
            try:
                end = time.monotonic() + 1.2
                while time.monotonic() < end:
                    pass
            finally:
                sys.setswitchinterval(old)
            time.sleep(0.2)  # the keep-alive's turn: it feeds (the silence is over)
            with pytest.raises(FailsafeTripped) as e:
                chip.move_to(1000, velocity=131072, acceleration=655)
            msg = str(e.value)
            assert "keep-alive was held up for" in msg, msg
            held = float(msg.split("held up for ")[1].split(" s")[0])
            assert 1.0 <= held <= 2.0, msg
            assert "kept turning" not in msg, msg
        finally:
            chip.transport.clear_failsafe()
            chip.close()


class _FeedsFail(_FeedsLost):
    """A line whose every keep-alive feed fails to be written (the adapter refuses it)."""

    def write(self, data: bytes) -> None:
        if data in (FAILSAFE_FEED, SIMULATED_FEED):
            raise OSError(5, "Input/output error")
        self.pipe.write(data)


def test_a_feed_that_fails_warns_once_with_its_cause_and_the_trip_says_it(caplog):
    """Every feed fails: the keep-alive says so once at WARNING, with the cause (not at
    DEBUG, not once a turn), and the trip message blames that failure, not the line."""
    caplog.set_level("DEBUG")
    t = open_emulated("sim://", wrap=_FeedsFail)
    chip = lm629_host.LM629(t)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.clock.sleep(2.0)  # about five turns that feed, every one failing
    failed = [r for r in caplog.records if "a feed failed" in r.getMessage()]
    assert len(failed) == 1, caplog.text
    assert failed[0].levelname == "WARNING"
    assert "OSError: [Errno 5] Input/output error" in failed[0].getMessage()
    with pytest.raises(FailsafeTripped) as e:
        chip.move_to(1000, velocity=131072, acceleration=655)
    msg = str(e.value)
    assert "its feeds failed (OSError: [Errno 5] Input/output error)" in msg, msg
    assert "lost on the line" not in msg, msg
    t.close()
