"""The bring-up sequence (lm629_host.bench.bringup) on the chip model, without click.

Numbers: 8 MHz -> T = 256 us.  The default small move is 1000 counts at 0.5 counts/sample
with acceleration word 65536 // 400 = 163: ramps of 32768 / 163 = 201.03 samples, a whole move
of 201.03 + 1000 / 0.5 = 2201.03 samples = 0.56346 s.  At kp = 20 the P-only dead band is 256 / 20 = 12.8 counts (AN-706 5.2.4),
so the settle band is ceil(12.8) + 1 = 14 counts.
"""

from __future__ import annotations

import pytest

from lm629_host import Cmd, Status, TrajectoryFlags
from lm629_host.bench.bringup import run_bringup

T = 2048 / 8e6


def test_default_simulator_passes_every_step(open_chip):
    chip = open_chip("sim://?record=1")
    seen = []
    report = run_bringup(chip, report=seen.append)
    assert [s.name for s in seen] == ["reset", "phasing", "hold", "move", "settle", "next"]
    assert report.passed and not report.reset_failed
    # the last step names the tuner, with the room the bring-up's move showed (1000 counts)
    assert report.step("next").summary.endswith("lm629 tune --travel 1000")
    reset = report.step("reset")
    first, done, cleared = reset.data["statuses"]
    assert first == 0x00 and done in (0x84, 0xC4) and cleared in (0x80, 0xC0)
    assert "00 " in reset.summary
    # phasing (the tuner's check, travel 4000): steps of 4000 / 8 = 500 counts at
    # kp = 16 x 256 / 500 = 8 (first output 1/8 of full scale), followed both ways
    phasing = report.step("phasing").data
    assert (phasing["desired_moved"], phasing["kp"], phasing["load"]) == (500, 8, 0)
    assert 0 < phasing["real_moved"] < phasing["desired_moved"]
    assert phasing["followed"][0] >= 250 and phasing["followed"][1] <= -250
    assert report.step("hold").data["dead_band"] == 14
    assert abs(report.step("hold").data["following_error"]) <= 14
    move = report.step("move").data
    profile = (32768 / 163 + 2000) * T
    assert move["profile_s"] == pytest.approx(profile, abs=1e-4)
    # completion seen by a 2 ms poll: not before the profile ends, at most a poll or two later
    assert profile - T <= move["seconds"] <= profile + 0.005
    settle = report.step("settle").data
    assert abs(settle["final_error"]) <= 14
    assert 0 <= settle["settle_s"] < 2.0
    assert 0 < abs(settle["max_following_error"]) < 200
    # the motor is left holding (drive on, not stopped by the safety net)
    assert not chip.read_status() & Status.MOTOR_OFF


def test_reversed_leads_fail_phasing_and_stop_the_motor(open_chip):
    chip = open_chip("sim://?reversed=1&record=1")
    report = run_bringup(chip)
    assert [s.name for s in report.steps] == ["reset", "phasing"]
    step = report.step("phasing")
    assert step.ok is False and "swap the motor leads" in step.summary.lower()
    assert step.summary.startswith("RUNAWAY: ") and step.data["reason"] == "runaway"
    # away from the +500 step by a tenth of it: the drive turned off and the shaft slowing
    assert step.data["real_moved"] <= -50 < 0 < step.data["desired_moved"] == 500
    assert not report.passed and not report.reset_failed
    model = chip.transport.model
    assert model.motor_off
    # the last four commands: LTRJ abrupt stop, STT, LTRJ motor off, STT
    tail = [(c, w) for c, w in model.history if c != Cmd.RSTI][-4:]
    assert tail == [(Cmd.LTRJ, (int(TrajectoryFlags.STOP_ABRUPT),)), (Cmd.STT, ()),
                    (Cmd.LTRJ, (int(TrajectoryFlags.MOTOR_OFF),)), (Cmd.STT, ())]


def test_stalled_rotor_says_the_shaft_did_not_turn(open_chip):
    report = run_bringup(open_chip("sim://?stall=1"))
    step = report.step("phasing")
    assert step.ok is False and "did not turn" in step.summary
    assert step.data["real_moved"] == 0


def test_chip_that_never_leaves_reset(open_chip):
    report = run_bringup(open_chip("sim://?fault=reset"))
    assert len(report.steps) == 1 and report.steps[0].ok is False
    assert report.reset_failed and not report.passed
    assert report.steps[0].summary.startswith("status bytes seen: 00 00")


def test_declining_the_question_moves_nothing(open_chip):
    chip = open_chip("sim://?record=1")
    questions = []
    report = run_bringup(chip, confirm=lambda q: questions.append(q) or False)
    assert len(questions) == 1 and "turn" in questions[0]
    assert report.step("phasing").ok is None and not report.passed and not report.reset_failed
    assert Cmd.STT not in [c for c, _ in chip.transport.model.history]


def test_a_load_torque_fails_the_hold_with_advice_and_stops_the_motor(open_chip):
    """A constant load of 0.5 mN m pulls the shaft back: 0.5e-3 / 0.025 N m/A x 4 ohm = 0.08 V,
    under one output step (12 V / 128 = 94 mV) but more than dry friction (0.2 mN m) holds, so
    at kp = 20 the shaft rests at least one step's worth of error, 256 / 20 = 12.8 counts, behind:
    outside the 14-count band once it has sagged.  The phasing at kp = 1 still follows."""
    chip = open_chip("sim://?load_torque=0.0005")
    report = run_bringup(chip)
    assert report.step("phasing").ok is True
    hold = report.step("hold")
    assert hold.ok is False and hold.data["following_error"] > 14
    assert "add ki" in hold.summary
    assert not report.passed and not report.reset_failed
    assert chip.read_status() & Status.MOTOR_OFF


def test_a_heavy_load_pulls_the_shaft_away_but_is_not_called_a_runaway(open_chip):
    """12 mN m of load (gravity on an arm) needs 12e-3 / 0.025 x 4 ohm = 1.92 V, 20.5 output
    steps of 12 V / 128: more than the phasing's first output (1/8 of full scale, 16 steps at
    kp = 8 on a 500-count step), so the shaft heads away from the step up.  It keeps going
    with the drive off (a load, not reversed leads, which slow down), follows the step down,
    and at kp = 16 (32 steps) the loop holds it.  This must not be "swap the motor leads"."""
    report = run_bringup(open_chip("sim://?load_torque=0.012"))
    step = report.step("phasing")
    assert step.ok is True and "load pulled it back first, down" in step.summary
    assert (step.data["load"], step.data["kp"]) == (-1, 16)
    assert step.data["real_moved"] <= -50  # a tenth of the step, the wrong way, at first
    assert report.step("hold").ok is False  # and kp = 20 cannot hold such a load in its band


@pytest.mark.parametrize("poll_s", [0.002, 0.01])
def test_the_settle_is_timed_on_the_clock_whatever_the_poll(open_chip, poll_s):
    """The settle rule is `still_s` (50 ms) of the chip's clock at rest inside the dead band
    (MoveWatch's settle rule), not a count of polls: a 10 ms poll settles like a 2 ms one."""
    from lm629_host.bench.bringup import BringupOptions
    chip = open_chip("sim://")
    report = run_bringup(chip, BringupOptions(poll_s=poll_s))
    assert report.passed, [s.summary for s in report.steps]
    settle = report.step("settle").data
    assert abs(settle["final_error"]) <= 14 and 0 <= settle["settle_s"] < 0.5
    move = report.step("move").data
    # completion seen by the poll: not before the profile ends, at most two polls later
    assert move["profile_s"] - T <= move["seconds"] <= move["profile_s"] + 2 * poll_s + T


@pytest.mark.parametrize("motor, words", [({"stall": True}, "motion fault (stall) during the move"),
                                          ({"reversed": True}, "motion fault (runaway) during the move")])
def test_a_fault_in_the_small_move_is_the_move_steps_verdict_with_the_motor_off(open_chip, motor,
                                                                                words):
    """move_steps watches the move with MoveWatch: a rotor that locks (or leads swapped) after
    the hold fails the "move" step with the fault's reason, the motor stopped."""
    from lm629_host.bench.bringup import BringupOptions, hold_step, move_steps
    chip = open_chip("sim://")
    chip.reset()
    o = BringupOptions()
    assert hold_step(chip, o).ok
    chip.transport.model.set_motor_params(**motor)
    steps = list(move_steps(chip, o, chip.clock_hz))
    assert [s.name for s in steps] == ["move"] and steps[0].ok is False
    assert steps[0].summary.startswith(words) and "motor stopped" in steps[0].details[0]
    assert chip.read_status() & Status.MOTOR_OFF


def test_a_failed_reset_names_the_wire(open_chip):
    """The reset step runs the wiring check and names the wire: D2/D3 swapped make
    the reset's C4 read C8 (bits 2 and 3 exchanged)."""
    report = run_bringup(open_chip("sim://?wiring=d2-d3"))
    step = report.steps[0]
    assert step.ok is False and report.reset_failed  # exit 5 in the CLI
    assert "C8" in step.summary
    assert step.details[0].startswith("wiring check: LM629 D2 (pin 9) carries D3's bit")
    assert "Uno D4" in step.details[0] and "Uno D5" in step.details[1]


def _limited_profile(tmp_path, lo: int, hi: int):
    path = tmp_path / "bench.toml"
    path.write_text(f'[board]\nport = "sim://"\n[axis.x]\ncs = 0\nkp = 20\nmin = {lo}\nmax = {hi}\n')
    return path


def test_bringup_on_an_axis_with_soft_limits_checks_its_absolute_targets(tmp_path):
    """From 0 the phasing steps go to +500 and -500 (an eighth of the default 4000-count
    phasing travel) and the small move to +1000: inside -3000..6000 it runs; with max = 800 it
    is refused before anything turns, naming the limit and the room left (+800 counts up to
    max), and with min = -400 the phasing step down is."""
    from click.testing import CliRunner

    from lm629_host.cli import main
    runner = CliRunner()
    ok = _limited_profile(tmp_path, -3000, 6000)
    r = runner.invoke(main, ["--profile", str(ok), "--axis", "x", "bringup", "--yes"])
    assert r.exit_code == 0, r.output
    tight = _limited_profile(tmp_path, -3000, 800)
    r = runner.invoke(main, ["--profile", str(tight), "--axis", "x", "bringup", "--yes"])
    assert r.exit_code == 2, r.output
    line = r.stderr.strip().splitlines()[-1]
    assert "bring-up goes to 1000 is above the soft limit max = 800 counts" in line
    assert f"{tight}:7: [axis.x] max" in line
    assert "room left from 0: +800 counts up to max, -3000 down to min" in line
    low = _limited_profile(tmp_path, -400, 6000)
    r = runner.invoke(main, ["--profile", str(low), "--axis", "x", "bringup", "--yes"])
    assert r.exit_code == 2, r.output
    assert "bring-up goes to -500 is below the soft limit min = -400 counts" in r.stderr
    assert "[PASS] phasing" not in r.stdout and "relative" not in r.stderr
