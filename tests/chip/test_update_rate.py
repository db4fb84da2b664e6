"""AN-706 4.6.2, the command update rate: "The LM628/629 aborts the current trajectory
calculation when it receives a new STT command, resulting in the output staying at the value
of the previous sample ... it is recommended that trajectory is not updated at a greater rate
than once every 10 ms."

The model reproduces the abort (model choice 34); the library spaces its trajectory updates
10 ms apart on the transport's clock, or raises when told to.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host import ProtocolViolation, UpdateTooSoon
from lm629_host.bus.opcodes import SAMPLE_CLOCKS, Cmd

T = SAMPLE_CLOCKS / 8e6  # one sample at 8 MHz


def _running(url: str, trace=None) -> lm629_host.LM629:
    chip = lm629_host.open(url, trace=trace)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=2 * 65536, velocity_mode=True, start=True)
    return chip


def test_two_stts_2_ms_apart_go_out_10_ms_apart_on_the_simulated_clock():
    stts: list[int] = []
    holder: list = []

    def trace(cycle) -> None:  # the chip's clock when each STT byte reaches it
        if cycle.kind == "command" and cycle.value == Cmd.STT and holder:
            stts.append(holder[0].tick)

    with _running("sim://?strict=1", trace) as chip:
        chip.clock.sleep(0.05)
        holder.append(chip.transport.model)
        chip.load_trajectory(velocity=3 * 65536, velocity_mode=True, start=True)
        first = chip.clock.now()
        chip.clock.sleep(2e-3)
        chip.load_trajectory(velocity=4 * 65536, velocity_mode=True, start=True)  # held back
        assert chip.clock.now() - first >= 10e-3
        assert len(stts) == 2
        assert 10e-3 <= (stts[1] - stts[0]) / 8e6 < 10.5e-3
        assert not chip.transport.model.violations


def test_strict_rule_raises_before_any_bus_cycle_and_stops_are_never_held():
    with _running("sim://?strict=1") as chip:
        chip.clock.sleep(0.05)
        chip.update_rule = "raise"
        chip.load_trajectory(velocity=3 * 65536, velocity_mode=True, start=True)
        chip.clock.sleep(2e-3)
        programs = chip.transport.stats.programs
        with pytest.raises(UpdateTooSoon) as exc:
            chip.load_trajectory(velocity=4 * 65536, velocity_mode=True, start=True)
        assert 2e-3 <= exc.value.since_s < 3e-3 and exc.value.interval_s == 10e-3
        assert chip.transport.stats.programs == programs
        # a stop goes out at once, and is no violation of the strict model
        t0 = chip.clock.now()
        chip.load_trajectory(stop="abrupt", start=True)
        assert chip.clock.now() - t0 < 2e-3
        # the override: a user who knows the chip turns the rule off: the next update goes
        # out at once, 1 ms after the stop (which counts as the last STT), and the model,
        # told not to raise, records the one update it calls too soon
        chip.update_interval = 0
        chip.transport.set_strict(False)
        chip.transport.take_violations()
        chip.clock.sleep(1e-3)
        t0 = chip.clock.now()
        chip.load_trajectory(velocity=3 * 65536, velocity_mode=True, start=True)
        assert chip.clock.now() - t0 < 2e-3
        assert len(chip.transport.take_violations()) == 1


def test_the_model_aborts_when_the_rule_is_broken_through_raw():
    """Two STTs 2 ms apart through raw(): the second is a violation (recorded without strict),
    and the sample after it keeps the output word of the sample before: the trajectory
    calculation was aborted.  The sample after that computes the output again."""
    with _running("sim://?strict=0") as chip:
        model = chip.transport.model
        chip.clock.sleep(0.1)  # at speed: the output word changes every sample
        chip.raw(Cmd.STT)
        chip.clock.sleep(2e-3)
        chip.load_trajectory(velocity=3 * 65536, velocity_mode=True)
        m = model.motion
        # line up just before the next sample (50 us: a status read and a command byte
        # take a few), then send STT
        chip.clock.sleep((model.next_sample - model.tick) / model.clock_hz - 50e-6)
        out = m.output
        chip.raw(Cmd.STT)
        assert len(model.violations) == 1
        assert "aborts the trajectory calculation" in model.violations[0]
        desired = m.desired_position
        model.advance_to(model.next_sample)  # the aborted sample: output held
        assert m.output == out and m.desired_position != desired
        model.advance_to(model.next_sample)  # the one after: the filter runs again
        assert m.output != out


def test_strict_model_raises_on_a_second_stt_within_10_ms():
    with _running("sim://?strict=1") as chip:
        chip.clock.sleep(0.05)
        chip.raw(Cmd.STT)
        chip.clock.sleep(5e-3)
        with pytest.raises(ProtocolViolation, match=r"STT 5\.\d\d ms after the last one"):
            chip.raw(Cmd.STT)


def test_update_s_0_turns_the_model_rule_off():
    with _running("sim://?strict=1&update_s=0") as chip:
        chip.update_interval = 0
        chip.raw(Cmd.STT)
        chip.raw(Cmd.STT)
        assert not chip.transport.model.violations
        assert chip.transport.model.motion.velocity_mode  # the chip is still in velocity mode


def test_an_update_after_sleeping_what_update_due_said_is_never_too_soon():
    """A script that sleeps ``update_due()`` and then updates under ``update_rule = "raise"``
    is on time: the clock's float sums (1e-17 s short) are no "10.00 ms after the last STT"."""
    with _running("sim://?strict=1") as chip:
        chip.update_rule = "raise"
        for i in range(60):
            chip.clock.sleep(chip.update_due())
            chip.load_trajectory(velocity=(3 + i % 5) * 65536, velocity_mode=True, start=True)
        assert not chip.transport.model.violations
