"""The twin of a bench: the plant identified and kept in the profile, ``sim://`` built from it,
and ``lm629 twin check``.

Benches are ``sim://`` URLs whose motor the host is not told (the tuner finds it); the twin is
``sim://?profile=FILE&axis=x``.  The tolerances are the issue's: a twin's trapezoid overshoot
within 2 counts or 10 % of the bench's, its settle time within 5 ms or 10 %
(:data:`lm629_host.bench.twin.MATCH_OVERSHOOT`, :data:`~lm629_host.bench.twin.MATCH_SETTLE`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host import cli
from lm629_host.physics.pid import sample_period_s
from lm629_host.config.profile import ProfileError, load_profile, parse_profile, save_gains, template
from lm629_host.sim.model.motor import Motor
from lm629_host.sim.model.params import MotorParams
from lm629_host.bench.tuning_session import measure_move
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.predict import MoveProfile
from lm629_host.bench.twin import (
    MATCH_OVERSHOOT,
    MATCH_RMS,
    MATCH_SETTLE,
    SETTLE_BAND,
    Plant,
    Side,
    close,
    judged_side,
    rms_difference,
    settle_close,
    twin_profile,
)
from lm629_host.transports.ports import profile_port, twin_port

from sim_urls import UNO, with_params

SAMPLE_S = sample_period_s(8e6)
TRAVEL = 5000
DISTANCE = 2000
#: a heavy axis with a load: 10x the default inertia, 0.004 N m pulling down
BENCH = "inertia=4e-5&load_torque=0.004"


@pytest.fixture
def run():
    def _run(*args: str):
        return CliRunner().invoke(cli.main, list(args), env={"LM629_PORT": "",
                                                             "LM629_PROFILE": ""},
                                  catch_exceptions=False)
    return _run


def _si_to_plant(p: MotorParams) -> Plant:
    """docs/model.md's mapping of the SI parameters onto the plant's units."""
    counts_per_rad = 4 * p.lines / (2 * math.pi)
    accel = p.amp_volts * p.torque_constant / (p.resistance * p.inertia) * counts_per_rad
    tau = p.inertia / (p.torque_constant ** 2 / p.resistance + p.friction)
    full_torque = p.torque_constant * p.amp_volts / p.resistance  # stall torque, full output
    return Plant(accel, tau, p.coulomb / full_torque, p.load_torque / full_torque, p.reversed)


# ---------------------------------------------------------------------------------- the units
@pytest.mark.parametrize("si", [MotorParams(), MotorParams(inertia=4e-5, load_torque=0.004,
                                                           coulomb=1e-3, amp_volts=6,
                                                           friction=3e-5, reversed=True)])
def test_the_plant_in_its_units_makes_the_same_motor_as_the_si_parameters(si):
    """A motor built from the plant (as docs/model.md maps it) runs sample for sample as the
    one built from the SI numbers: same drive, same positions."""
    plant = _si_to_plant(si)
    twin = MotorParams(accel=plant.accel, tau=plant.tau, dry=plant.dry, load=plant.load,
                       reversed=plant.reversed)
    a, b = Motor(si, SAMPLE_S), Motor(twin, SAMPLE_S)
    # the acceleration at full-scale output (the amplifier's volts are the plant's accel)
    assert b.accel_per_volt * twin.amp_volts == pytest.approx(a.accel_per_volt * si.amp_volts,
                                                              rel=1e-12)
    assert b.rate == pytest.approx(a.rate, rel=1e-12)
    for k in range(400):
        drive = 0.5 * math.sin(k / 40)  # both ways, through the dry friction's sticking
        a.run(drive * si.amp_volts)
        b.run(drive * twin.amp_volts)
        assert b.angle == pytest.approx(a.angle, rel=1e-9, abs=1e-9)


def test_plant_and_tuner_model_convert_both_ways():
    m = AxisModel(accel=0.39, rate=0.01, coulomb=0.002, load=0.01)
    p = Plant.from_model(m, SAMPLE_S)
    # 0.39 counts/sample^2 at 256 us a sample: 5.95e6 counts/s^2; 100 samples: 25.6 ms
    assert p.accel == pytest.approx(0.39 / SAMPLE_S ** 2)
    assert p.tau == pytest.approx(100 * SAMPLE_S)
    assert (p.dry, p.load) == (pytest.approx(0.002 / 0.39), pytest.approx(0.01 / 0.39))
    back = p.model(SAMPLE_S)
    assert (back.accel, back.rate, back.coulomb, back.load) == pytest.approx(
        (m.accel, m.rate, m.coulomb, m.load))


def test_bad_plant_numbers_are_refused_by_name():
    with pytest.raises(ValueError, match="tau=0.0: must be > 0"):
        Motor(MotorParams(tau=0.0), SAMPLE_S)
    with pytest.raises(ValueError, match="dry=1.5"):
        Motor(MotorParams(dry=1.5), SAMPLE_S)
    with pytest.raises(ValueError, match="unknown simulator parameter.*tau_s"):
        lm629_host.open("sim://?tau_s=1")


# ---------------------------------------------------------------------------------- the profile
PROFILE = """\
# the rig
[board]
port = "sim://"

[axis.x]
cs = 0
kp = 889     # tuned
kd = 12921
ds = 1

[axis.y]
cs = 1
kp = 20
"""


def test_plant_table_is_read_checked_and_written_keeping_comments(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(PROFILE)
    plant = {"accel": 5.9e6, "tau": 0.0253, "dry": 0.0027, "load": 0.04, "reversed": False,
             "rms": 0.8, "steps": 2, "date": "2026-11-27T07:00:00+00:00", "port": "sim://"}
    save_gains(path, "x", {}, plant=plant)
    text = path.read_text()
    assert "# the rig" in text and "kp = 889     # tuned" in text  # the rest kept
    assert load_profile(path).axis("x").plant == plant
    assert load_profile(path).axis("y").plant is None
    # saved again: the plant replaced, a key not measured this time removed
    save_gains(path, "x", {"kp": 900}, plant={"accel": 1e6, "tau": 0.1})
    ax = load_profile(path).axis("x")
    assert ax.kp == 900 and ax.plant == {"accel": 1e6, "tau": 0.1}
    bad = text.replace("tau = 0.0253", "tau = -1")
    with pytest.raises(ProfileError, match=r"rig.toml:\d+: \[axis.x.plant\] tau: -1 is outside"):
        parse_profile(bad, path)
    with pytest.raises(ProfileError, match=r"\[axis.x.plant\] inertia: unknown key"):
        parse_profile(text.replace("tau = 0.0253", "inertia = 1"), path)


def test_sim_url_builds_each_axis_from_its_plant(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(PROFILE)
    save_gains(path, "y", {}, plant={"accel": 1e6, "tau": 0.05, "dry": 0.01, "load": -0.02})
    with lm629_host.open_board(f"sim://?profile={path}") as board:
        motors = [m.motion.motor for m in board.transport.models]
    assert len(motors) == 2
    default = Motor(MotorParams(), SAMPLE_S)
    assert motors[0].rate == pytest.approx(default.rate)  # x: no plant, the URL's motor
    y = motors[1]
    assert y.accel_per_volt * 12 == pytest.approx(1e6)
    assert y.rate == pytest.approx(20.0)
    assert (y.coulomb_accel, y.load_accel) == pytest.approx((1e4, -2e4))
    with lm629_host.open(f"sim://?profile={path}&axis=y") as chip:
        assert chip.transport.model.motion.motor.rate == pytest.approx(20.0)
    with pytest.raises(ValueError, match="no axis 'z'"):
        lm629_host.open(f"sim://?profile={path}&axis=z")
    with pytest.raises(ValueError, match="axis= names an axis of a profile"):
        lm629_host.open("sim://?axis=y")


def test_profile_with_a_bare_sim_port_is_a_twin_and_a_described_one_a_bench(tmp_path):
    prof = parse_profile(PROFILE, tmp_path / "rig.toml")
    assert f"profile={tmp_path / 'rig.toml'}" in profile_port(prof).text
    emu = twin_port(prof, "sim+emu://?usb=uno")
    assert f"profile={tmp_path / 'rig.toml'}" in emu.text and "usb=uno" in emu.text
    assert twin_port(prof, "serial:///dev/ttyACM0").text == "serial:///dev/ttyACM0"
    path = tmp_path / "rig.toml"
    path.write_text(PROFILE)
    save_gains(path, "x", {}, plant={"accel": 1e6, "tau": 0.05})
    # a URL that gives its own motor's dynamics is that motor; a fault applies to the twin
    with lm629_host.open(twin_port(prof, "sim://?inertia=4e-5")) as chip:
        assert len(chip.transport.models) == 2  # the profile's chips, the URL's motor
        assert chip.transport.models[0].motion.motor.rate == pytest.approx(
            Motor(MotorParams(inertia=4e-5), SAMPLE_S).rate)
    with lm629_host.open(twin_port(prof, "sim://?axis=x&reversed=1")) as chip:
        motor = chip.transport.model.motion.motor
        assert motor.rate == pytest.approx(20.0) and motor.accel_per_volt * 12 == -1e6


# ---------------------------------------------------------------------------------- end to end
def _fresh(url: str) -> lm629_host.LM629:
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    return chip


def _gains(path: Path) -> tuple[Gains, Plant]:
    ax = load_profile(path).axis("x")
    assert ax.kp is not None and ax.plant is not None
    return Gains(ax.kp, ax.ki or 0, ax.kd or 0, ax.il or 0, ax.ds), Plant.from_values(ax.plant)


def _trapezoid(url: str, gains: Gains, move: MoveProfile) -> Side:
    with _fresh(url) as chip:
        m, rec = measure_move(chip, gains, distance=DISTANCE, travel=TRAVEL, duration_s=0.6,
                              tolerance=SETTLE_BAND, profile=move)
    return judged_side(m, rec, SETTLE_BAND)


def _matches(bench: Side, twin: Side) -> None:
    assert bench.metrics.settle_s is not None and twin.metrics.settle_s is not None
    assert close(bench.metrics.overshoot, twin.metrics.overshoot, *MATCH_OVERSHOOT), (bench,
                                                                                      twin)
    assert settle_close(bench, twin), (bench.metrics, bench.settle_range, twin.metrics,
                                       twin.settle_range)


# about 10 s on an idle machine, once per run (a module fixture: its tests share one xdist
# group, tests/selection.py): a whole `tune --save` of the hidden bench
@pytest.fixture(scope="module")
def tuned(tmp_path_factory) -> Path:
    """A profile tuned with `tune --save` on the hidden bench (sim://)."""
    path = tmp_path_factory.mktemp("twin") / "bench.toml"
    path.write_text(template(port=None))
    _fresh(f"sim://?{BENCH}").close()
    r = CliRunner().invoke(cli.main, ["--profile", str(path), "--port", f"sim://?{BENCH}",
                                      "tune", "--travel", str(TRAVEL), "--yes", "--save"],
                           env={"LM629_PORT": "", "LM629_PROFILE": ""}, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "saved the plant into [axis.x.plant]" in r.output
    return path


@pytest.mark.parametrize("base", ["sim://", f"sim+emu://?{UNO}"])
def test_twin_of_a_tuned_bench_moves_as_the_bench(tuned, base, tmp_path, run):
    """The saved plant: 10x the default inertia (accel 596,831 counts/s^2, tau 253 ms) and a
    load of 0.004 N m, 5.3 % of the full-output torque (0.075 N m); the twin's trapezoid as
    the bench's, and `identify --save` behind an Uno's USB gives a twin as good."""
    gains, plant = _gains(tuned)
    true = _si_to_plant(MotorParams(inertia=4e-5, load_torque=0.004))
    assert plant.accel == pytest.approx(true.accel, rel=0.05)
    assert plant.load == pytest.approx(true.load, abs=0.005)
    assert plant.tau == pytest.approx(true.tau, rel=0.1)
    path = tmp_path / "bench.toml"
    shutil.copy(tuned, path)
    bench = with_params(base, BENCH)
    if base != "sim://":
        _fresh(bench).close()
        r = run("--profile", str(path), "--port", bench, "identify", "--travel", str(TRAVEL),
                "--yes", "--save")
        assert r.exit_code == 0, r.output
        assert _gains(path)[0] == gains  # no gains changed
        assert "saved the plant into [axis.x.plant]" in r.output
    move = twin_profile(plant, SAMPLE_S)
    _matches(_trapezoid(bench, gains, move), _trapezoid(f"sim://?profile={path}&axis=x",
                                                          gains, move))


def test_twin_check_matches_the_same_bench_and_not_a_changed_one(tuned, run):
    for params, code, word in ((BENCH, 0, "matches"),
                               ("inertia=8e-5&load_torque=0.004", 1, "differs"),
                               ("inertia=4e-5&load_torque=0.008", 1, "differs")):
        _fresh(f"sim://?{params}").close()
        r = run("--profile", str(tuned), "--port", f"sim://?{params}", "twin", "check",
                "--travel", str(TRAVEL), "--yes")
        assert r.exit_code == code, (params, r.output)
        lines = r.output.splitlines()
        assert lines[-1] == word
        assert any(ln.split()[:2] == ["trapezoid", "rms"] for ln in lines)


def test_twin_check_needs_a_plant(tmp_path, run):
    path = tmp_path / "rig.toml"
    path.write_text(PROFILE)
    r = run("--profile", str(path), "--axis", "x", "twin", "check", "--travel", "5000",
            "--yes")
    assert r.exit_code != 0 and "has no plant: `lm629 identify --save`" in r.output


USER_TEST = textwrap.dedent('''
    import json, os
    import pytest
    from lm629_host.bench.tuning_session import measure_move
    from lm629_host.physics.predict import MoveProfile

    @pytest.mark.lm629_motion
    def test_settles(lm629_board):
        x = lm629_board["x"]
        m, _ = measure_move(x, None, distance=2000, travel=5000, duration_s=0.6, tolerance=5,
                            profile=MoveProfile(int(os.environ["V"]), int(os.environ["A"])))
        with open(os.environ["OUT"], "w") as f:
            json.dump({"settle_s": m.settle_s, "overshoot": m.overshoot}, f)
''')


def test_plugin_runs_a_users_test_file_on_the_twin(tuned, pytester, monkeypatch):
    gains, plant = _gains(tuned)
    move = twin_profile(plant, SAMPLE_S)
    bench = _trapezoid(f"sim://?{BENCH}", gains, move)
    out = pytester.path / "settle.json"
    monkeypatch.setenv("V", str(move.velocity))
    monkeypatch.setenv("A", str(move.acceleration))
    monkeypatch.setenv("OUT", str(out))
    monkeypatch.delenv("LM629_PORT", raising=False)
    pytester.makepyfile(test_user=USER_TEST)
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--lm629-profile", str(tuned),
                                      "--lm629-port", "sim://")
    r.assert_outcomes(passed=1)
    twin = json.loads(out.read_text())
    # the same move, the same code measuring it: the settle times as the plugin's user sees
    # them, at the band the user's file gives (5 counts)
    assert bench.metrics.settle_s is not None and twin["settle_s"] is not None
    assert close(bench.metrics.settle_s, twin["settle_s"], *MATCH_SETTLE), (bench, twin)
    assert close(bench.metrics.overshoot, twin["overshoot"], *MATCH_OVERSHOOT), (bench, twin)


def test_twin_check_on_a_served_bench_behind_usb(tuned, tmp_path):
    """The same hidden bench served by `lm629 sim serve` behind an Uno's USB, in real time,
    each command its own process: the twin from the profile matches it."""
    from served import serve
    with serve(tmp_path, "python+uno", f"sim://?{BENCH}") as b:
        b.ready()
        p = b.run("--profile", str(tuned), "twin", "check", "--travel", str(TRAVEL), "--yes",
                  timeout=120)
        assert p.returncode == 0, p.stdout + p.stderr
        assert p.stdout.splitlines()[-1] == "matches"


@pytest.mark.parametrize("late_s", [0.004, 0.015, 0.040])
@pytest.mark.parametrize("trapezoid", [True, False], ids=["trapezoid", "step"])
def test_a_host_that_stamped_its_stt_late_compares_the_same_move(late_s, trapezoid):
    """Found by CI (docs/twin.md's `twin check` on a busy machine): a bench and its own twin
    differed by 34 counts rms in the trapezoid, their settle times alike (5.2 and 5.0 ms).
    A host that stamps an STT late (paused between sending it and reading its clock, or
    behind a flush tick) shifts that step's row times by the delay; past rms_difference's
    10 ms search the comparison saw a delay that no shaft had.  The same recorded move, its
    STTs stamped ``late_s`` later, compares as itself: each step counts from its first row
    with the desired position moved."""
    move = MoveProfile(velocity=0x40000, acceleration=0x2000) if trapezoid else None
    with _fresh("sim://") as chip:
        m, rec = measure_move(chip, None, distance=DISTANCE, travel=TRAVEL, duration_s=0.3,
                              tolerance=SETTLE_BAND, profile=move)
    late = dataclasses.replace(rec, steps=[(t + late_s, target) for t, target in rec.steps])
    on_time, stamped_late = judged_side(m, rec, SETTLE_BAND), judged_side(m, late, SETTLE_BAND)
    # the recorded move itself: 2000 counts out and back, hundreds of rows each way
    assert [len(t) > 100 and max(abs(p) for p in real) >= DISTANCE - SETTLE_BAND
            for t, real in on_time.segments] == [True, True]
    assert rms_difference(on_time, stamped_late) <= MATCH_RMS[0]


def _side(settle_s, lo=None, hi=None):
    from lm629_host.physics.metrics import MoveMetrics
    m = MoveMetrics(distance=1000, final_error=0, overshoot=0, settle_s=settle_s, rise_s=None,
                    peak_following_error=0)
    return Side(metrics=m, segments=[], settle_range=(lo, hi))


@pytest.mark.parametrize("a, b, close", [
    # spans 40-50 ms and 100-120 ms: 50 ms apart, more than 10 % of 120 ms: not close, whichever
    # side is the bench (the rule is symmetric: each side's span is checked against the other's)
    ((0.045, 0.040, 0.050), (0.110, 0.100, 0.120), False),
    ((0.110, 0.100, 0.120), (0.045, 0.040, 0.050), False),
    # 100-120 and 125-130: 5 ms apart, within 10 % of 130 ms
    ((0.110, 0.100, 0.120), (0.128, 0.125, 0.130), True),
    ((0.128, 0.125, 0.130), (0.110, 0.100, 0.120), True),
    # overlapping spans
    ((0.050, 0.040, 0.060), (0.055, 0.050, 0.070), True),
    # one side never settles: not close either way; neither: close
    ((None, None, None), (0.050, 0.040, 0.060), False),
    ((0.050, 0.040, 0.060), (None, None, None), False),
    ((None, None, None), (None, None, None), True),
])
def test_settle_close_is_judged_both_ways(a, b, close):
    """MATCH_SETTLE (5 ms or 10 % of the later span's end) between the two sides' settle spans,
    with the spans swapped too: a rule that looked one way only would call a twin that
    settles far earlier than its bench a match."""
    assert settle_close(_side(*a), _side(*b)) is close
    assert settle_close(_side(*b), _side(*a)) is close
