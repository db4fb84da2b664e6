"""``LM629.batch()`` and the one-exchange ``move_to``: exchanges counted in
``transport.stats.round_trips`` on the Python far end and on the compiled firmware."""

from __future__ import annotations

import sys
import threading

import pytest

import lm629_host
from lm629_host import CommandError
from lm629_host.bus.opcodes import Cmd, Status, TrajectoryFlags
from lm629_host.urls import with_query

URLS = ["sim+emu://?fast_baud=1000000", "sim+avr://?fast_baud=1000000"]


def _chip(url: str, request):
    if "avr" in url:
        request.getfixturevalue("firmware_built")
    chip = lm629_host.open(url + "&record=1")
    chip.reset()
    return chip


@pytest.mark.parametrize("url", URLS)
def test_ten_calls_are_one_exchange(url, request):
    with _chip(url, request) as chip:
        chip.load_filter(kp=20)
        chip.update_filter()
        chip.move_to(500, velocity=65536, acceleration=655).wait()
        st = chip.transport.stats
        before = st.round_trips
        model = chip.transport.model
        model.record_clear()
        with chip.batch() as b:
            h = [b.read_real_position(), b.read_desired_position(), b.read_status(),
                 b.snapshot(), b.load_filter(kp=30, kd=100), b.update_filter(),
                 b.read_signals(), b.set_breakpoint(200), b.read_integration_sum(),
                 b.read_desired_velocity()]
            with pytest.raises(RuntimeError, match="not run yet"):
                _ = h[0].value
        assert st.round_trips - before == 1
        assert len(h) == 10
        cmds = [c for c, _ in model.history]
        # each value is what the call returns outside a batch, read again now (at rest)
        assert h[0].value == chip.read_real_position() == h[3].value.real_position
        assert h[1].value == 500 == h[3].value.desired_position
        assert h[4].value is None and h[9].value == 0
        # the commands reached the chip once each, in call order
        assert cmds == [Cmd.RDRP, Cmd.RDDP, Cmd.RDSIGS, Cmd.RDDP, Cmd.RDRP, Cmd.RDDV, Cmd.RDRV,
                        Cmd.RDSUM, Cmd.LFIL, Cmd.UDF, Cmd.RDSIGS, Cmd.SBPA, Cmd.RDSUM, Cmd.RDDV]
        assert chip.derivative_interval == 1


@pytest.mark.parametrize("url", URLS)
def test_move_to_starts_in_one_exchange(url, request):
    with _chip(url, request) as chip:
        chip.load_filter(kp=20)
        chip.update_filter()
        st = chip.transport.stats
        # after a reset the start is not known: one read first, so that the move's length is
        # checked before anything moves (move_rules.max_duration)
        before = st.round_trips
        m = chip.move_to(1000, velocity=65536, acceleration=655)
        assert st.round_trips - before == 2
        assert m.start.desired_position == 0 and m.start.real_position == 0
        assert abs(m.wait().error) <= 20
        # once a read saw the chip at rest on its target, the next move is one exchange
        before = st.round_trips
        m = chip.move_to(2000, velocity=65536, acceleration=655)
        assert st.round_trips - before == 1
        assert m.start.desired_position == 1000
        assert abs(m.wait().error) <= 20


def test_a_command_error_names_the_call():
    """The chip refuses an STT that changes the acceleration while it moves with the drive on
    (AN-706 4.6.1): the third call's."""
    with lm629_host.open("sim+emu://") as chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        with pytest.raises(CommandError, match=r"batch call 3 of 3, "
                                               r"load_trajectory\(acceleration=200, start=True\)"):
            with chip.batch() as b:
                p = b.read_real_position()
                b.load_trajectory(acceleration=100, velocity=65536, position=100000, start=True)
                b.load_trajectory(acceleration=200, start=True)
        assert p.value == 0  # the calls before it have their values
        assert chip.read_status() & Status.COMMAND_ERROR


def test_bad_arguments_and_unbatchable_calls_send_nothing():
    with lm629_host.open("sim+emu://") as chip:
        st = chip.transport.stats
        with pytest.raises(ValueError, match="kp"):
            with chip.batch() as b:
                b.read_real_position()
                b.load_filter(kp=-1)
        with pytest.raises(AttributeError, match="cannot be queued"):
            chip.batch().reset()
        assert st.round_trips == 0


def _polled_move(url: str) -> float:
    with lm629_host.open(url) as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        return chip.move_to(4000, velocity=4 * 65536, acceleration=6553).wait().duration


@pytest.mark.parametrize("url", URLS)
def test_move_wait_sees_the_end_on_the_far_side(url, request):
    """A 4000-count move at 4 counts/sample: each exchange waits on the bridge for trajectory
    complete (at most a poll) and reads a snapshot; once complete, one exchange holds the
    snapshots the settle rule still needs, a poll apart.  The end is seen when ``sim://``'s
    polling loop (no link) sees it, give or take a poll and the 1 Mbaud link's exchanges."""
    polled = _polled_move("sim://")
    with _chip(url, request) as chip:
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        st = chip.transport.stats
        before = st.round_trips
        move = chip.move_to(4000, velocity=4 * 65536, acceleration=6553)
        assert move.waiter is not None
        seen: list[float] = []
        r = move.wait(progress=lambda s: seen.append(s.time))
        rules = chip.move_rules
        assert abs(r.error) <= 20
        assert abs(r.duration - polled) <= rules.poll + 0.003, (r.duration, polled)
        # polls while it moves, then one or two settle exchanges
        assert st.round_trips - before <= polled / rules.poll + 3
        assert len(seen) >= st.round_trips - before + 3  # the settle check's snapshots


# ---------------------------------------------------------------- threads, nesting, direct calls
BOTH = ["sim://", "sim+emu://"]


def _at_rest_on(url: str, target: int):
    """A chip (``record=1``) holding at ``target`` with kp = 20 (a dead band of 12.8 counts,
    so the shaft rests and every later read of its position has one answer)."""
    chip = lm629_host.open(with_query(url, {"record": "1", "record_window": "100000"}))
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.move_to(target, velocity=4 * 65536, acceleration=6553).wait()
    return chip


@pytest.fixture
def switch_often():
    """Threads switch every 10 us instead of every 5 ms, so that the calls of two threads
    interleave within a few hundred calls (as on a loaded machine) instead of by chance."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    yield
    sys.setswitchinterval(before)


def _batches_in_a_thread(chip, stop: threading.Event, errors: list[BaseException]) -> threading.Thread:
    def loop() -> None:
        try:
            while not stop.is_set():
                with chip.batch() as b:
                    b.read_status()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)
    th = threading.Thread(target=loop)
    th.start()
    return th


@pytest.mark.parametrize("url", BOTH)
def test_a_batch_captures_only_its_own_threads_calls(url, switch_often):
    """Thread A runs batches back to back while the main thread reads the position directly
    3000 times: every read reaches the bus and returns the resting position (never a queued
    call's dummy 0), and the main thread's 2000 DFH all reach the chip."""
    with _at_rest_on(url, 3000) as chip:
        rest = chip.read_real_position()
        assert abs(rest - 3000) <= 13
        model = chip.transport.model
        stop, errors = threading.Event(), []
        th = _batches_in_a_thread(chip, stop, errors)
        try:
            rdrp = sum(1 for c, _ in model.history if c == Cmd.RDRP)
            reads = [chip.read_real_position() for _ in range(3000)]
            rdrp = sum(1 for c, _ in model.history if c == Cmd.RDRP) - rdrp
            before = sum(1 for c, _ in model.history if c == Cmd.DFH)
            for _ in range(2000):
                chip.define_home()
            homes = sum(1 for c, _ in model.history if c == Cmd.DFH) - before
        finally:
            stop.set()
            th.join()
        assert not errors
        assert reads == [rest] * 3000
        assert rdrp == 3000  # each read reached the bus: the batches only read the status
        assert homes == 2000
        assert model.history.dropped == 0


def test_a_stop_from_another_thread_reaches_the_chip_during_batches(switch_often):
    """A move runs; thread A runs batches back to back; the main thread (a safety loop) sends
    an abrupt stop 300 times, then the emergency stop: every one reaches the chip, which ends
    with the motor off short of the target."""
    from lm629_host.chip.safety import emergency_stop
    with _at_rest_on("sim+emu://", 0) as chip:
        model = chip.transport.model
        chip.move_to(400000, velocity=4 * 65536, acceleration=6553)
        chip.clock.sleep(0.05)
        sent = len(model.history)
        stop, errors = threading.Event(), []
        th = _batches_in_a_thread(chip, stop, errors)
        try:
            for _ in range(300):
                chip.load_trajectory(stop="abrupt", start=True)
            ok, note = emergency_stop(chip)
        finally:
            stop.set()
            th.join()
        assert not errors and ok, note
        ltrj = [w[0] for c, w in model.history[sent:] if c == Cmd.LTRJ]
        abrupt, off = int(TrajectoryFlags.STOP_ABRUPT), int(TrajectoryFlags.MOTOR_OFF)
        assert ltrj == [abrupt] * 301 + [off]  # the emergency stop: abrupt, then motor off
        assert model.motor_off and 0 < chip.read_desired_position() < 400000
        assert model.history.dropped == 0


@pytest.mark.parametrize("url", BOTH)
def test_a_nested_batch_on_the_same_bus_is_refused(url):
    """The inner batch would put its UDF on the bus before the outer one's LFIL (the active kp
    would stay 20): it is refused when its block opens, and nothing of either is sent."""
    with _at_rest_on(url, 0) as chip:
        model = chip.transport.model
        sent = len(model.history)
        with pytest.raises(RuntimeError, match="a batch is already open on .* in this thread"):
            with chip.batch() as b:
                b.load_filter(kp=30)
                with chip.batch() as i:
                    i.update_filter()
        assert len(model.history) == sent
        assert model.filter.kp == 20 and model.filter_buffer.kp == 20
        with chip.batch() as b:  # the refusal left nothing open: the two as one batch
            b.load_filter(kp=30)
            b.update_filter()
        chip.clock.sleep(256e-6)  # UDF takes effect at the next sample (256 us at 8 MHz)
        assert [c for c, _ in model.history[sent:]] == [Cmd.LFIL, Cmd.UDF]
        assert model.filter.kp == 30


@pytest.mark.parametrize("url", BOTH)
def test_direct_calls_inside_a_batch_block_keep_their_state(url):
    """A direct LFIL with a derivative interval of 7 inside the block runs at once; the batch
    does not roll the host back: the interval stays 7 (control word 06xx: the byte is
    interval - 1) in the batch's own LFIL, built when the block ends, and in the next one."""
    with _at_rest_on(url, 0) as chip:
        model = chip.transport.model
        sent = len(model.history)
        with chip.batch() as b:
            s = b.read_status()
            b.load_filter(kp=30)
            chip.load_filter(derivative_interval=7)
        assert chip.derivative_interval == 7 and s.value & Status.MOTOR_OFF == 0
        chip.load_filter(kd=50)
        lfil = [w for c, w in model.history[sent:] if c == Cmd.LFIL]
        # direct (ds only), the batch's (ds, kp = 30 = 001E), the next (ds, kd = 50 = 0032)
        assert lfil == [(0x0600,), (0x0608, 30), (0x0602, 50)]


def test_a_board_batch_reads_several_axes_in_one_exchange():
    """Two axes at rest at different positions: one exchange reads both, whichever axis comes
    first (axis 0 after axis 1 needs its own SELECT 0: a program starts on chip 0 and axis 0's
    calls carry none)."""
    with lm629_host.open_board("sim+emu://?axes=2") as board:
        board.reset()
        for axis, target in ((0, 1500), (1, -700)):
            a = board[axis]
            a.load_filter(kp=20)
            a.update_filter()
            a.move_to(target, velocity=4 * 65536, acceleration=6553).wait()
        x, y = board[0].read_desired_position(), board[1].read_desired_position()
        assert (x, y) == (1500, -700)
        st = board.transport.stats
        before = st.as_dict()
        with board.batch() as b:
            py = b[1].read_desired_position()
            px = b[0].read_desired_position()
            sx = b[board[0]].snapshot()
            sy = b[1].read_status()
        assert (st.round_trips - before["round_trips"], st.programs - before["programs"]) == (1, 1)
        assert (px.value, py.value, sx.value.desired_position) == (1500, -700, 1500)
        assert sy.value & Status.TRAJECTORY_COMPLETE
        with pytest.raises(KeyError, match="without a profile"):
            board.batch()["x"]
        with pytest.raises(AttributeError, match=r"b\[axis\]\.read_status"):
            board.batch().read_status()


def _value_or_error(handle):
    """A handle's value, or the error reading it raises (a call the batch never ran): a
    value to compare, so that a missing one fails the assertion that lists them all."""
    try:
        return handle.value
    except RuntimeError as exc:
        return exc


@pytest.mark.parametrize("url", URLS)
def test_every_call_of_a_batch_reaches_the_chip_the_last_one_included(url, request):
    """Four calls, the last a write whose only trace is on the bus and in the chip: each
    command is on the chip's bus once, in call order, with the words written (LFIL: control
    word 000F, ds byte 0 and the four gains loaded, then kp ki kd il; SBPA 200: 0000 00C8;
    the chip logs a read without its words); every handle has its value; the filter loaded
    and updated is the chip's working filter."""
    with _chip(url, request) as chip:
        model = chip.transport.model
        model.record_clear()
        raised = None
        try:  # kept, so that a call gone missing fails on what reached the bus, whatever
            # the batch then says about it
            with chip.batch() as b:
                handles = [b.read_real_position(), b.load_filter(kp=30, ki=2, kd=100, il=50),
                           b.update_filter(), b.set_breakpoint(200)]
        except Exception as exc:  # noqa: BLE001 - reported by the assertions below
            raised = exc
        assert list(model.history) == [(Cmd.RDRP, ()), (Cmd.LFIL, (0x000F, 30, 2, 100, 50)),
                                       (Cmd.UDF, ()), (Cmd.SBPA, (0, 200))]
        assert raised is None
        assert [_value_or_error(h) for h in handles] == [0, None, None, None]
        chip.clock.sleep(1e-3)  # UDF takes effect at the next sample
        f = model.filter
        assert (f.kp, f.ki, f.kd, f.il) == (30, 2, 100, 50)
