"""Several axes on one bus: chip selects, one reset, synchronized start, straight
lines.  Each behaviour runs on every simulated transport (``fast_transport_url``) with two
chips; the numbers checked are the chip's own (every desired position at every sample, the
sample a trajectory completes), read from the chip models behind the transport."""

from __future__ import annotations

import math

import pytest

import lm629_host
from lm629_host import AxisError, ResetError
from lm629_host.physics.linear import plan_linear
from lm629_host.physics.plan import plan as plan_move
from lm629_host.sim.model import chips_of
from lm629_host.sim.model.chip import SAMPLE_CLOCKS
from lm629_host.bus.opcodes import Status

from sim_urls import with_params



def open2(url: str, **kw) -> lm629_host.Board:
    return lm629_host.open_board(with_params(url, "axes=2"), **kw)


def chips(board):
    return chips_of(board.transport.model)


def sample_s(board) -> float:
    return SAMPLE_CLOCKS / chips(board)[0].clock_hz


def tune(board, kp: int = 20) -> None:
    for a in board.axes:
        a.load_filter(kp=kp)
        a.update_filter()


def run_samples(board, limit: int, seen: list[dict[int, int]] | None = None):
    """Step the board's clock one sample at a time until every chip's trajectory is done;
    returns (per-sample desired positions in 1/65536 count, the sample each finished).
    ``seen``: per chip, filled with its sample count -> desired position."""
    models = chips(board)
    done = [None] * len(models)
    path = []
    dt = sample_s(board)
    for _ in range(1, limit + 1):
        board.clock.sleep(dt)
        path.append(tuple(m.motion.traj.position for m in models))
        for k, m in enumerate(models):
            if seen is not None:
                seen[k][m.samples] = m.motion.traj.position
        for k, m in enumerate(models):
            if done[k] is None and m.motion.traj.done:
                done[k] = m.samples
        if all(d is not None for d in done):
            return path, done
    raise AssertionError(f"not done after {limit} samples: {done}")


# ------------------------------------------------------------------------------ planning
def test_plan_shares_the_words_by_distance():
    plan = plan_linear({0: (0, 12000), 1: (0, 6000)}, velocity=65536, acceleration=1000)
    x, y = plan.axes
    # the path is sqrt(12000^2 + 6000^2) = 13416.4 counts: x has 0.894 of it, y 0.447
    assert abs(x.velocity - 65536 * 12000 / 13416.4) < 65536 * 0.005
    assert abs(x.acceleration - 894) <= 2 and y.acceleration * 2 == x.acceleration
    # the duration each pair of words gives, exactly, is the same within a tenth of a sample
    assert plan.spread < 0.1
    assert abs(plan_move(12000, x.velocity, x.acceleration).samples / plan.samples - 1) < 0.005


def test_plan_rejects_what_the_chip_cannot_do():
    with pytest.raises(ValueError, match="velocity"):
        plan_linear({0: (0, 100)}, velocity=0, acceleration=10)
    with pytest.raises(ValueError, match="axis 1.*resolution"):
        plan_linear({0: (0, 100000), 1: (0, 1)}, velocity=65536, acceleration=10)


# ------------------------------------------------------------------------------ the board
def test_one_reset_checks_every_chip(fast_transport_url):
    url = fast_transport_url
    with open2(url) as board:
        assert [int(s) for s in board.reset()] == [0xC0, 0xC0]
        assert board.transport.stats.programs == 2  # /RST + checks, then MSKI/RSTI on each
        # a chip that never leaves reset on axis 1: the error names it and its bytes
        chips(board)[1].params.fault = "reset"
        with pytest.raises(ResetError, match=r"^axis 1: .*status read 00 00 00 00") as info:
            board.reset()
        assert info.value.axis == 1


def test_independent_moves_end_each_on_its_own_target(fast_transport_url):
    url = fast_transport_url
    with open2(url) as board:
        board.reset()
        tune(board)
        x, y = board.axes
        x.load_trajectory(acceleration=2000, velocity=3 * 65536, position=3000)
        y.load_trajectory(acceleration=500, velocity=65536, position=-1200)
        x.start()
        y.start()
        path, done = run_samples(board, 5000)
        assert path[-1] == (3000 << 16, -1200 << 16)
        assert x.read_desired_position() == 3000 and y.read_desired_position() == -1200
        # x: 1.5 counts/sample ramp of 98 samples; y slower: their ends differ
        assert done[0] != done[1]
        board.clock.sleep(0.3)  # settle: P-only at kp = 20 rests 0..12 counts short (choice 22)
        assert 0 <= 3000 - x.read_real_position() <= 12
        assert 0 <= -1200 - y.read_real_position() <= 12


def test_synchronized_start_is_one_program_and_identical_profiles_end_together(fast_transport_url):
    url = fast_transport_url
    with open2(url) as board:
        board.reset()
        tune(board)
        for a in board.axes:
            a.load_trajectory(acceleration=1500, velocity=2 * 65536, position=2500)
        before = board.transport.stats.programs, board.transport.stats.round_trips
        board.start()
        assert board.transport.stats.programs - before[0] == 1
        assert board.transport.stats.round_trips - before[1] == 1
        models = chips(board)
        seen: list[dict[int, int]] = [{}, {}]  # per chip: its sample count -> desired position
        path, done = run_samples(board, 5000, seen=seen)
        # The two STTs are consecutive bus cycles of one program, microseconds apart: well
        # within one sample period (256 us at 8 MHz), so at most one sample tick falls between
        # them (the chips share the clock and the /RST that phased their sample timers; no
        # input starts them on one tick). Identical profiles then run sample for sample, one
        # chip at most one sample behind the other, and end that far apart.
        lag = done[1] - done[0]
        assert lag in (-1, 0, 1), done
        assert len(path) == len(seen[0])  # one sample a step
        assert all(seen[1].get(n + lag) == p for n, p in seen[0].items() if n + lag in seen[1])
        assert models[0].motion.traj.position == models[1].motion.traj.position == 2500 << 16


def test_move_linear_keeps_to_the_line_and_lands_both(fast_transport_url):
    url = fast_transport_url
    with open2(url) as board:
        board.reset()
        tune(board)
        x, y = board.axes
        m = board.move_linear({x: 3000, y: -1700}, velocity=3 * 65536, acceleration=2000)
        path, done = run_samples(board, 5000)
        assert abs(done[0] - done[1]) <= 1
        assert path[-1] == (3000 << 16, -1700 << 16)
        # every sample: the desired point (whole counts, as RDDP reads) within 1.5 counts of
        # the line from (0, 0) to (3000, -1700)
        length = math.hypot(3000, -1700)
        worst = max(abs((px >> 16) * -1700 - (py >> 16) * 3000) / length for px, py in path)
        assert worst <= 1.5, worst
        results = m.wait(timeout=3, tolerance=13)
        assert [r.target for r in results] == [3000, -1700]
        assert all(abs(r.error) <= 13 for r in results)


def test_move_linear_the_issue_example_on_sim():
    with open2("sim://") as board:
        board.reset()
        tune(board)
        x, y = board.axes
        board.move_linear({x: 12000, y: 6000}, velocity=65536, acceleration=1000)
        path, done = run_samples(board, 20000)
        assert abs(done[0] - done[1]) <= 1
        worst = max(abs((px >> 16) * 6000 - (py >> 16) * 12000) / math.hypot(12000, 6000)
                    for px, py in path)
        assert worst <= 1.5, worst
        assert path[-1] == (12000 << 16, 6000 << 16)


def test_a_fault_on_one_axis_names_it_and_stops_both(fast_transport_url):
    url = fast_transport_url
    with open2(url) as board:
        board.reset()
        tune(board)
        x, y = board.axes
        chips(board)[1].set_motor_params(stall=True)
        m = board.move({x: 2000, y: 2000}, velocity=2 * 65536, acceleration=1500)
        with pytest.raises(lm629_host.MotionError, match=r"^axis 1: motion fault \(stall\)") as e:
            m.wait(timeout=5)
        assert e.value.axis == 1
        # both drives off afterwards
        assert all(s & Status.MOTOR_OFF for s in board.statuses())


# ------------------------------------------------------------------------------ axis errors
def test_axis_beyond_the_board_is_one_clear_error():
    with pytest.raises(AxisError, match="axis 2 does not exist.*1 chip select"):
        lm629_host.open("sim://?cs=2")
    with pytest.raises(AxisError, match="axis 2 does not exist.*2 chip select"):
        lm629_host.open("sim://?axes=2&cs=2")
    with pytest.raises(AxisError, match="axis 2 does not exist.*1 chip select"):
        lm629_host.open_board("sim+emu://?bridge=1&baud=1000000", axes=3)  # a one-chip bridge
    with pytest.raises(ValueError, match="axes=3 conflicts with axes=1 in sim://[?]axes=1"):
        lm629_host.open_board("sim://?axes=1", axes=3)  # the URL and the argument disagree
    with lm629_host.open("sim://?axes=2&cs=1") as chip:
        chip.reset()
        assert chip.axis == 1 and chip.read_desired_position() == 0
    with open2("sim://") as board, pytest.raises(AxisError):
        board.start(2)


# ------------------------------------------------------------------------------ old bridges
def test_a_one_chip_bridge_works_with_this_host_and_axis_1_is_one_clear_error():
    # a one-chip bridge (firmware 1.0): one chip select, no SELECT operation
    with lm629_host.open("sim+emu://?bridge=1&baud=1000000") as chip:
        assert chip.transport.info.chip_selects == 1
        assert not chip.transport.info.capabilities & 0x10
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        move = chip.move_to(500, velocity=65536, acceleration=2000)
        assert abs(move.wait(timeout=3).error) <= 13
    with lm629_host.open_board("sim+emu://?bridge=1&baud=1000000") as board:
        assert len(board.axes) == 1
        board.reset()
    with pytest.raises(AxisError, match="axis 1 does not exist.*1 chip select"):
        lm629_host.open("sim+emu://?bridge=1&cs=1")
    with pytest.raises(AxisError, match="axis 1 does not exist.*1 chip select"):
        lm629_host.open_board("sim+emu://?bridge=1&axes=2")


def test_a_bridge_without_select_gets_one_run_per_chip():
    """A two-select bridge that cannot switch chip inside a program (no Capability.SELECT):
    the host cuts the program at each SELECT, the RUN's cs field names the chip; correct, one
    round trip per chip."""
    from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
    from lm629_host.bridge.protocol import HelloInfo
    from lm629_host.transports.link import LinkTransport
    from lm629_host.sim.build import build_bus

    bus = build_bus("sim://?axes=2")
    emu = BridgeEmulator(bus, HelloInfo(chip_selects=2))
    t = LinkTransport(EmuPipe(emu, baud=1000000), "emu-2cs")
    t.model, t.models = bus, chips_of(bus)
    board = lm629_host.Board(t)
    board.reset()
    for a in board.axes:
        a.load_trajectory(acceleration=1500, velocity=2 * 65536, position=800)
    t.stats.reset()
    board.start()
    # the start program: sync 0 | sync 1 | STT 0 | STT 1 | sync 0 | sync 1: six runs
    assert t.stats.programs == 1 and t.stats.round_trips == 6
    path, done = run_samples(board, 3000)
    assert path[-1] == (800 << 16, 800 << 16)


# ------------------------------------------------------------------------------ FT232H
def test_ftdi_streams_cut_per_chip():
    """An STT after a load on the same chip starts a new stream (its loads must be checked
    first); an STT on another chip does not: a synchronized start is one USB exchange."""
    from lm629_host.bus.opcodes import Cmd
    from lm629_host.bus.program import Program
    from lm629_host.transports.mpsse import streams_of
    p = Program().command(Cmd.LTRJ).write(0).command(Cmd.STT)
    assert len(streams_of(p.ops)) == 2
    q = Program().sync().command(Cmd.STT).select(1).sync().command(Cmd.STT)
    assert len(streams_of(q.ops)) == 1
    r = Program().command(Cmd.STT).select(1).command(Cmd.LTRJ).write(0).command(Cmd.STT)
    assert len(streams_of(r.ops)) == 2


def _load_both_and_stretch_chip0_busy(board):
    """Both axes loaded for 800 counts, recordings cleared, and chip 0's next transfer holds
    busy 300 us: 3x its documented 100 us worst case."""
    board.reset()
    for a in board.axes:
        a.load_trajectory(acceleration=1500, velocity=2 * 65536, position=800)
    for c in chips(board):
        c.record_clear()
    board.transport.device.chip_pins.stretch_busy(1, 300e-6)


def test_ftdi_repeat_after_busy_never_runs_another_chips_stt_twice():
    """Chip 0 holds busy 3x its worst case after its RSTI: the check before the next transfer
    on chip 0 fails; the units chip 1 took in that stream (its RSTI, its STT) are left out of
    the repeat, so each chip sees exactly one STT."""
    with lm629_host.open_board("sim+ftdi://?axes=2&record=1") as board:
        _load_both_and_stretch_chip0_busy(board)
        board.start(clear=Status.TRAJECTORY_COMPLETE)
        assert board.transport.stats.retries == 1  # one stretched busy: one failed check, one repeat
        for c in chips(board):
            stts = [cmd for cmd, _ in c.history if cmd == 0x01]
            rstis = [w for cmd, w in c.history if cmd == 0x1D]
            assert len(stts) == 1, c.history
            assert rstis and rstis[-1] == (0x7E & ~0x04,)  # RSTI clears bit 2 only
        path, done = run_samples(board, 3000)
        assert path[-1] == (800 << 16, 800 << 16)


def test_ftdi_busy_pin_waits_out_one_chips_long_busy_in_a_synchronized_start():
    """The same chip holding busy 3x its worst case, with D0 on GPIOL1: the stream waits on the
    pin for chip 0 (the chips share D0; only the selected one drives it), no repeat, and each
    chip sees exactly one RSTI and one STT."""
    with lm629_host.open_board("sim+ftdi://?axes=2&record=1&busy_pin=gpiol1") as board:
        _load_both_and_stretch_chip0_busy(board)
        trips = board.transport.stats.round_trips
        board.start(clear=Status.TRAJECTORY_COMPLETE)
        assert board.transport.stats.retries == 0
        assert board.transport.stats.round_trips - trips == 1
        assert board.transport.device.chip_pins.busy_stretched == 1
        for c in chips(board):
            assert [cmd for cmd, _ in c.history] == [0x1D, 0x01], c.history  # RSTI, STT
            assert not c.violations
        path, done = run_samples(board, 3000)
        assert path[-1] == (800 << 16, 800 << 16)


def test_resetting_one_axis_leaves_the_other_alone():
    """/RST is shared: LM629.reset() of one board axis sends the RESET command to its chip
    only, so the other axis keeps its filter and its position."""
    with open2("sim://") as board:
        board.reset()
        tune(board)
        x, y = board.axes
        y.move_to(300, velocity=2 * 65536, acceleration=3000).wait(timeout=3)
        assert not x.uses_reset_line and not y.uses_reset_line
        assert x.reset() in (Status(0x80), Status(0xC0))
        assert y.read_desired_position() == 300 and chips(board)[1].filter.kp == 20
        assert chips(board)[0].filter.kp == 0


def test_stt_skew_of_a_synchronized_start_is_below_one_sample(fast_transport_url):
    url = fast_transport_url
    """The STT strobes as the chips see them (their own clock ticks), in one program: the
    skew must be below one sample (2048 chip clocks, 256 us at 8 MHz); the bench prints it
    (tools/bench_multiaxis.py): 1 us on sim://, 2 us on the Python bridge, 17 us through the
    firmware, 7.5 us on the FT232H."""
    with open2(url) as board:
        board.reset()
        seen = []
        for k, m in enumerate(chips(board)):
            def note(byte, _k=k, _m=m, _w=m.write_command):
                if byte == 0x01:
                    seen.append((_k, _m.tick))
                _w(byte)
            m.write_command = note
        for a in board.axes:
            a.load_trajectory(acceleration=4000, velocity=4 * 65536, position=0)
        board.start()
        assert sorted(k for k, _ in seen) == [0, 1]
        skew = max(t for _, t in seen) - min(t for _, t in seen)
        assert 0 < skew < SAMPLE_CLOCKS // 8  # well inside a sample: 32 us at 8 MHz


def test_the_firmware_built_for_one_chip_under_this_host():
    """The compiled firmware reporting one chip select (build/lm629_bridge_1chip.elf) in
    simavr: HELLO says 1, the host drives its chip, axis 1 is one clear error before any
    traffic, and a board of two is refused at open."""
    from lm629_host.sim.harness import BUILD_DIR, ensure_built
    ensure_built()
    fw = BUILD_DIR / "lm629_bridge_1chip.elf"
    url = f"sim+avr://?baud=1000000&firmware={fw}"
    with lm629_host.open(url) as chip:
        assert chip.transport.info.chip_selects == 1 and chip.transport.chip_selects == 1
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        assert abs(chip.move_to(400, velocity=2 * 65536, acceleration=3000).wait(3).error) <= 13
    with pytest.raises(AxisError, match="axis 1 does not exist.*1 chip select"):
        lm629_host.open(url + "&cs=1")
    with pytest.raises(AxisError, match="axis 1 does not exist.*1 chip select"):
        lm629_host.open_board(url + "&axes=2")
    with lm629_host.open_board("sim+avr://?baud=1000000&axes=2") as board:
        assert board.transport.info.chip_selects == 4 and len(board.axes) == 2


def test_a_flag_on_another_axis_ends_the_wait_at_once():
    """Axis 1 trips its LPES limit (stalled rotor) while the wait still watches axis 0's long
    move: the wait ends at the next poll with MotionError naming axis 1, both motors off."""
    with open2("sim://") as board:
        board.reset()
        tune(board)
        x, y = board.axes
        y.load_position_error(50, stop=True)
        chips(board)[1].set_motor_params(stall=True)
        m = board.move({x: 20000, y: 20000}, velocity=65536, acceleration=500)
        t0 = board.clock.now()
        with pytest.raises(lm629_host.MotionError, match=r"^axis 1: motion fault") as e:
            m.wait()
        assert e.value.axis == 1 and e.value.reason in ("position error", "motor off")
        # axis 0's profile lasts 20000/1 + 65536/500 = 20131 samples = 5.2 s: ended long before
        assert board.clock.now() - t0 < 0.5
        assert all(s & Status.MOTOR_OFF for s in board.statuses())


def test_threads_move_their_own_axes_on_one_board():
    """One thread per axis, each with move_to on its own LM629: the transport's lock keeps
    every program whole (each carries its chip select), both moves end on their targets."""
    import threading
    with open2("sim://") as board:
        board.reset()
        tune(board)
        results, errors = {}, []

        def run(axis, target):
            try:
                a = board.axes[axis]
                results[axis] = a.move_to(target, velocity=65536 * (axis + 1),
                                          acceleration=2000).wait(timeout=5)
            except BaseException as exc:  # noqa: BLE001 - reported below
                errors.append(exc)
        threads = [threading.Thread(target=run, args=(k, t)) for k, t in ((0, 1500), (1, -900))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert not errors, errors
        assert results[0].target == 1500 and results[1].target == -900
        assert [c.motion.desired_position for c in chips(board)] == [1500, -900]


@pytest.mark.parametrize("url", ["sim://", "sim+emu://?baud=0", "sim+ftdi://"])
def test_the_trace_names_the_chip_of_every_cycle(url):
    """A trace shows each chip select change as a "select" cycle, wherever the transport
    carries it (a program's SELECT, a bridge's RUN cs field, an FT232H stream)."""
    from conftest import Recorder
    rec = Recorder()
    with open2(url, trace=rec) as board:
        board.reset()
        rec.clear()
        x, y = board.axes
        y.define_home()
        x.define_home()
        board.start()
    data = rec.data()
    assert data[:2] == [("select", 1), ("command", 0x02)]  # y's DFH
    assert ("command", 0x02) in data[2:]  # x's: a program starts on chip 0
    i = data.index(("command", 0x01))  # the synchronized start: STT, select 1, STT
    assert data[i:i + 3] == [("command", 0x01), ("select", 1), ("command", 0x01)]


def test_a_refused_stt_names_its_axis():
    """The chip refuses an acceleration change while it moves with the drive on (model choice
    13): board.start() reads every axis's status after its STT in the same program and names
    the axis that refused; the other axis's STT was taken."""
    with open2("sim://") as board:
        board.reset()
        tune(board)
        x, y = board.axes
        y.load_trajectory(acceleration=100, velocity=65536, position=100000)
        y.start()
        x.load_trajectory(acceleration=1000, velocity=65536, position=500)
        y.load_trajectory(acceleration=200)  # a new acceleration while y moves
        with pytest.raises(lm629_host.CommandError, match="STT on axis 1"):
            board.start()
        assert chips(board)[0].motion.traj.target == 500


def test_an_unwired_chip_select_says_so():
    """A chip select with no chip reads a floating bus, FF (model choice 32): the busy
    timeout names that case and the ?axes=N fix instead of only the power and clock (the
    Python bridge has four chip selects, one chip wired here)."""
    from lm629_host import BusyTimeout
    with lm629_host.open("sim+emu://?axes=1&cs=2") as chip:
        with pytest.raises(BusyTimeout, match="last status read FF.*no chip drives.*axes=N"):
            chip.read_real_position()


@pytest.mark.parametrize("url", ["sim://", "sim+emu://?baud=1000000"])
def test_a_runaway_on_the_second_axis_is_caught_while_the_first_still_moves(url):
    """Every poll of BoardMove.wait checks every moving axis against its own move's rules,
    not only the first one's: axis 1 with reversed leads runs away while axis 0 has most of
    a long move still to go, and the wait stops both and names axis 1."""
    from lm629_host import MotionError, Status
    with open2(url) as b:
        b.reset()
        tune(b)
        chips(b)[1].set_motor_params(reversed=True)
        m = b.move({0: 200_000, 1: 3000}, velocity=2 * 65536, acceleration=2000)
        with pytest.raises(MotionError) as info:
            m.wait()
        assert info.value.axis == 1 and info.value.reason is MotionError.RUNAWAY
        # the axis's own fault, named for the axis: the same detail, one prefix
        assert str(info.value) == f"axis 1: motion fault (runaway): {info.value.detail}"
        assert "swap the motor leads" in info.value.detail and "axis" not in info.value.detail
        # 200,000 counts at 2 counts/sample take 0.4 s and more; the fault came well before
        assert abs(b.axes[0].read_real_position()) < 100_000
        assert all(a.read_status() & Status.MOTOR_OFF for a in b.axes)  # both stopped


def test_a_board_reset_is_the_chips_reset_routine_with_its_bookkeeping():
    """Board.reset and LM629.reset run one routine (lm629.reset_chips) and leave each axis
    the same way through LM629's public hooks: PORT12 re-issued on the axis that selected it
    (an LM628 with a 12-bit DAC), the derivative interval back to one sample, and the
    command-error flag known clear (the next STT needs no RSTI before it)."""
    from lm629_host import Cmd, Signals
    with lm629_host.open_board("sim://?axes=2&chip=lm628&record=1") as b:
        b.reset()
        x, y = b.axes
        y.port12()
        x.load_filter(kp=20, derivative_interval=4)
        y.raw(int(Cmd.RDSIGS), read=1)  # any raw byte: the command-error flag is no longer known
        assert x.derivative_interval == 4 and y.start_flags() == Status.COMMAND_ERROR
        assert y.port12_selected and not x.port12_selected
        models = chips(b)
        for m in models:
            m.record_clear()
        b.reset()
        assert x.derivative_interval == 1 and y.derivative_interval == 1
        assert x.start_flags() == y.start_flags() == Status(0)
        assert [c for c, _ in models[1].history].count(Cmd.PORT12) == 1
        assert Cmd.PORT12 not in [c for c, _ in models[0].history]
        assert not models[1].signals & Signals.EIGHT_BIT_OUTPUT  # 12-bit again after reset
        # a single chip's reset: the same routine, its programs on its own chip select
        cycles = []
        b.transport.trace = cycles.append
        assert y.reset_statuses()[1][-1] in (0x80, 0xC0)
        assert cycles[0].kind == "select" and cycles[0].value == 1
        first = next(c for c in cycles if c.kind == "command")
        assert first.value == Cmd.RESET  # the RESET command: /RST is shared by the board
        assert any(c.kind == "command" and c.value == Cmd.PORT12 for c in cycles)
        assert not any(c.kind == "reset" for c in cycles)


def test_a_profile_decides_the_boards_axes_and_its_names_drive_moves(tmp_path):
    """A bridge offers four chip selects (the Python far end) and the profile wires two: the
    board opened from the profile has two axes, so ``board.reset()`` checks only chips that
    exist, and a straight line takes the profile's names as keys, as ``board["x"]`` does."""
    from lm629_host.sim.serve import SimServer

    with SimServer(tmp_path / "bench", "sim://?axes=2").start() as srv:
        prof = tmp_path / "p.toml"
        prof.write_text(f'[board]\nport = "{srv.client_url}"\n[axis.pan]\ncs = 0\nkp = 20\n'
                        '[axis.tilt]\ncs = 1\nkp = 20\n')
        with lm629_host.open_board(profile=str(prof)) as board:
            assert len(board.axes) == 2  # not the bridge's 4 selects
            board.reset()
            for ax in board.axes:
                ax.load_filter(kp=20, kd=100)
                ax.update_filter()
            board.move_linear({"pan": 600, "tilt": -300}, velocity=65536,
                              acceleration=2000).wait(timeout=10)
            assert abs(board["pan"].read_real_position() - 600) <= 20
            assert abs(board["tilt"].read_real_position() + 300) <= 20
            with pytest.raises(KeyError, match="pen"):
                board.axis("pen")
