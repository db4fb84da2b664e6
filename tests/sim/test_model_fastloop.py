"""The flattened sample loops (sim/model/fastloop.py, sim/model/_fastloop.c) against the readable code.

Three chips, ``fast=0`` (Motion.sample + ChipModel._sample only), ``fast=py`` and ``fast=c``,
take exactly the same host traffic; every register, the shaft state and the filter memory must agree after
every step, stepped one sample at a time and in long batches (with skip-ahead).
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.bus.opcodes import FIXED_ONE as ONE
from lm629_host.urls import query_params, with_query

T = 2048 / 8e6  # one sample at 8 MHz


def state(chip) -> tuple:
    c = chip.transport.model
    m, t, p = c.motion, c.motion.traj, c.motion.pid
    return (c.tick, c.samples, int(c.flags), int(c.signals_extra), c.motor_off,
            m.motor.angle, m.motor.speed, m.real_position, m.real_velocity, m.index_position,
            m.output, t.position, t.velocity, t.done, t.target,
            p.error_sum, p.last_error, p.derivative, p.countdown, p.integral, p.output)


try:
    import lm629_host.sim.model._fastloop
    LOOPS = ("0", "py", "c")
except ImportError:  # no C compiler when the package was installed
    LOOPS = ("0", "py")


class Pair:
    """The same chip under every sample loop: readable (0), flattened Python (py), C (c)."""

    def __init__(self, params: str) -> None:
        # the test's params over the defaults (a URL names each option once)
        self.chips = [lm629_host.open(with_query(f"sim://?strict=1&fast={f}", query_params(
            "sim://?" + params))) for f in LOOPS]

    def __getattr__(self, name):
        def call(*args, **kw):
            results = [getattr(c, name)(*args, **kw) for c in self.chips]
            self.check(name)
            return results[0]
        return call

    def check(self, what: str) -> None:
        first, *others = (state(c) for c in self.chips)
        for loop, other in zip(LOOPS[1:], others):
            assert first == other, f"after {what}: readable {first} != fast={loop} {other}"

    def run(self, seconds: float, step: float | None = None) -> None:
        t = 0.0
        while t < seconds:
            dt = step or seconds
            for c in self.chips:
                c.clock.sleep(dt)
            self.check(f"{t + dt:.4f} s")
            t += dt

    def close(self) -> None:
        for c in self.chips:
            c.close()


@pytest.fixture
def pair():
    made = []

    def _make(params: str = "") -> Pair:
        p = Pair(params)
        made.append(p)
        p.reset()
        return p

    yield _make
    for p in made:
        p.close()


def test_bringup_move_sample_by_sample_and_in_batches(pair):
    p = pair()
    p.load_filter(kp=20, ki=2, kd=200, il=300, derivative_interval=2)
    p.update_filter()
    p.load_trajectory(acceleration=ONE // 50, velocity=ONE // 2, position=600, start=True)
    p.run(0.05, step=T)  # every sample during the ramp up
    p.run(0.6, step=0.013)
    p.load_trajectory(velocity=ONE, start=True)  # on the fly
    p.run(1.5)  # one long batch: cruise, deceleration, landing, settling, skip-ahead
    assert p.read_status() & lm629_host.Status.TRAJECTORY_COMPLETE


def test_velocity_mode_stops_lpes_index_reversed(pair):
    p = pair("reversed=1&lines=100&index_offset=37")
    p.load_filter(kp=1)
    p.update_filter()
    p.set_index_position()
    p.load_position_error(3000, stop=True)
    p.load_trajectory(acceleration=ONE // 10, velocity=2 * ONE, velocity_mode=True, forward=True,
                      start=True)
    p.run(1.0, step=0.007)  # runaway, index seen, LPES turns the motor off
    assert p.read_status() & lm629_host.Status.POSITION_ERROR
    p.run(0.5)


def test_stops_wraparound_and_12_bit_output(pair):
    p = pair("chip=lm628&stall=1")
    p.port12()
    p.load_filter(kp=50, kd=100)
    p.update_filter()
    p.load_trajectory(acceleration=ONE * 100, velocity=0x3FFFFFFF, velocity_mode=True, start=True)
    p.run(2.0, step=0.25)
    p.load_trajectory(stop="smooth", start=True)
    p.run(0.5, step=0.1)
    p.load_trajectory(velocity_mode=True, forward=False, start=True)
    p.run(0.5, step=0.1)
    p.load_trajectory(stop="abrupt", start=True)
    p.run(0.1, step=T)
    p.load_trajectory(stop="off", start=True)
    p.run(0.2)


def test_the_c_loop_is_built_and_chosen_by_default():
    """CI installs with a C compiler: the default must be the C loop, not the fallback."""
    from lm629_host.sim.model.fastloop import py_loop
    chip = lm629_host.open("sim://")
    loop = chip.transport.model.fast
    chip.close()
    assert "c" in LOOPS, "lm629_host/sim/model/_fastloop.c was not built (pip install -e .)"
    assert loop is not py_loop and loop.__module__ == "lm629_host.sim.model._fastloop"


def test_unknown_loop_name_is_refused():
    with pytest.raises(ValueError, match="fast='turbo'"):
        lm629_host.open("sim://?fast=turbo")


@pytest.mark.parametrize("seed", range(12))
def test_random_command_sequences_agree(seed):
    """Random moves, stops, filters, homes, breakpoints, SIPs and LPEI/LPES, random waits."""
    import random

    from lm629_host import LM629Error

    rnd = random.Random(seed)
    params = rnd.choice(["", "reversed=1", "stall=1", "lines=50&index_offset=7", "coulomb=0",
                         "chip=lm628", "load_torque=0.001"])
    p = Pair(f"{params}")
    chips = p.chips
    try:
        def each(name, *args, **kw):
            outcomes = []
            for c in chips:
                try:
                    getattr(c, name)(*args, **kw)
                    outcomes.append(None)
                except LM629Error as exc:
                    outcomes.append(type(exc))
            assert len(set(outcomes)) == 1, f"{name}: {outcomes}"
            p.check(name)

        each("reset")
        for _ in range(25):
            op = rnd.randrange(9)
            if op == 0:
                each("load_filter", kp=rnd.choice([0, 1, 20, 400, 0x7FFF]),
                     ki=rnd.choice([0, 5, 300]), kd=rnd.choice([0, 2000, 0x7FFF]),
                     il=rnd.choice([0, 100, 0x7FFF]), derivative_interval=rnd.choice([1, 2, 7]))
                each("update_filter")
            elif op in (1, 2):
                vm = rnd.random() < 0.3
                each("load_trajectory",
                     acceleration=rnd.choice([None, 100, ONE // 50, ONE, 0x3FFFFFFF]),
                     velocity=rnd.choice([None, 1000, ONE // 3, 4 * ONE]),
                     position=None if vm else rnd.choice([None, 0, 500, -3000, 123456]),
                     position_relative=rnd.random() < 0.3, velocity_mode=vm,
                     forward=rnd.random() < 0.5, start=True)
            elif op == 3:
                each("load_trajectory", stop=rnd.choice(["smooth", "abrupt", "off"]), start=True)
            elif op == 4:
                each("define_home")
            elif op == 5:
                each("set_breakpoint", rnd.randrange(-2000, 2000), relative=rnd.random() < 0.5)
            elif op == 6:
                each("set_index_position")
            elif op == 7:
                each("load_position_error", rnd.choice([50, 2000, 0x7FFF]), stop=rnd.random() < 0.5)
            else:
                each("reset_interrupts")
            p.run(rnd.choice([T, 7 * T, 0.01, 0.05, 0.2]))
    finally:
        p.close()


def test_the_loops_take_their_status_bits_from_opcodes():
    """fastloop.py and _fastloop.c hold no hand copy of the opcodes.py bits (one place per fact):
    the Python loop converts the enums, the C loop reads them from lm629_host.bus.opcodes at import."""
    import re
    from pathlib import Path

    from lm629_host.sim.model import fastloop
    from lm629_host.bus.opcodes import Signals, Status

    assert (fastloop._COMPLETE, fastloop._INDEX, fastloop._WRAP, fastloop._PERR, fastloop._BP) == (
        Status.TRAJECTORY_COMPLETE, Status.INDEX_PULSE, Status.WRAPAROUND, Status.POSITION_ERROR,
        Status.BREAKPOINT)
    assert (fastloop._ACQUIRE_INDEX, fastloop._EIGHT_BIT, fastloop._STOP_ON_ERROR) == (
        Signals.ACQUIRE_INDEX, Signals.EIGHT_BIT_OUTPUT, Signals.STOP_ON_ERROR)
    model = Path(fastloop.__file__).parent
    for name in ("fastloop.py", "_fastloop.c"):
        text = (model / name).read_text()
        literal = re.search(r"(events|flags)\s*\|=\s*(0x|\d)", text)
        assert not literal, f"{name}: a literal status bit"


# ---------------------------------------------------------------- the model's scenarios
# The behaviours of tests/sim/test_model_scenarios.py (there on every transport) under all three
# loops, register by register: restarts after stops and motor off, the hold after a completed move, the plant
# through /RST and RESET, RSTI after reset, the default index, buffered and relative values,
# an out-of-range word.

def _motor(p: Pair, **values) -> None:
    for c in p.chips:
        c.transport.model.set_motor_params(**values)
    p.check(f"set_motor_params {values}")


@pytest.mark.parametrize("stop", ["off", "smooth", "abrupt"])
def test_round2_velocity_restart_after_each_stop(pair, stop):
    p = pair()
    p.load_filter(kp=400, kd=2000)
    p.update_filter()
    p.load_trajectory(acceleration=ONE // 100, velocity=2 * ONE, velocity_mode=True,
                      forward=False, start=True)
    p.run(0.2, step=0.011)
    p.load_trajectory(stop=stop, start=True)
    p.run(0.15, step=7 * T)
    p.reset_interrupts()
    p.start()  # resumes backwards at 2 counts/sample
    p.run(0.05, step=T)
    p.run(0.2)
    assert p.read_desired_velocity() == -2 * ONE


def test_round2_hold_after_completion_and_drift(pair):
    p = pair()
    p.load_filter(kp=400, kd=2000)
    p.update_filter()
    p.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=1000, start=True)
    p.run(1.0, step=0.05)
    p.load_trajectory(stop="off", start=True)
    _motor(p, load_torque=0.001)
    p.run(0.15, step=0.01)
    _motor(p, load_torque=0.0)
    p.run(0.3)
    held = p.read_real_position()
    p.start()
    p.run(0.05, step=T)
    p.run(0.3)
    assert p.read_desired_position() == held


@pytest.mark.parametrize("how", ["rst", "command"])
def test_round2_plant_through_reset_and_rsti(pair, how):
    from lm629_host.bus.opcodes import Cmd

    p = pair()
    p.load_filter(kp=400, kd=2000)
    p.update_filter()
    p.load_trajectory(acceleration=ONE // 4, velocity=10 * ONE, velocity_mode=True, start=True)
    p.run(0.4, step=0.05)
    if how == "rst":
        p.reset()
    else:
        p.raw(Cmd.RESET)
        p.run(1.6e-3, step=T / 3)
    p.run(0.01, step=T)  # coasting after the reset, from real position 0
    for _ in range(8):
        p.reset_interrupts()
        p.run(T / 8)
    p.run(0.5)


def test_round2_default_index_buffered_acceleration_relative_sums(pair):
    from lm629_host import CommandError

    p = pair()
    p.load_filter(kp=400, kd=2000)
    p.update_filter()
    p.set_index_position()
    p.run(0.1)
    p.load_trajectory(acceleration=ONE // 100, velocity=2 * ONE, position=1500, start=True)
    p.run(0.1, step=3 * T)
    p.load_trajectory(acceleration=ONE // 10)
    for c in p.chips:
        with pytest.raises(CommandError):
            c.start()
    p.check("refused STT")
    p.reset_interrupts()
    p.run(1.5, step=0.02)  # index at 1000, completion at 1500
    p.load_trajectory(velocity=ONE // 2, velocity_relative=True)
    p.load_trajectory(velocity=ONE // 4, velocity_relative=True, position=0, start=True)
    p.run(0.05, step=T)
    p.run(1.0)


def test_round2_out_of_range_velocity_word_lenient(pair):
    from lm629_host import CommandError
    from lm629_host.bus.opcodes import Cmd

    p = pair("strict=0")
    p.load_filter(kp=400, kd=2000)
    p.update_filter()
    p.load_trajectory(acceleration=ONE // 100, velocity=ONE, velocity_mode=True, start=True)
    p.run(0.1, step=0.01)
    p.raw(Cmd.LTRJ, [0x1808, 0xFDF0, 0xA3D8])
    for c in p.chips:
        with pytest.raises(CommandError):
            c.start()
    p.check("refused STT")
    p.run(0.1, step=T)
