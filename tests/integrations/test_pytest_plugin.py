"""The pytest plugin (lm629_host/integrations/pytest_plugin.py) as a user meets it: a test file in a fresh
directory outside the checkout, run by plain ``python -m pytest`` in a separate process, found
through the installed entry point (no conftest, no -p).

The user's file is examples/lab/ (the lab script of docs/testing.md and its tests) plus
deliberate failures written here.  The figures: the chip samples every 2048 clocks (256 us at
8 MHz); examples/lab/test_rig.py works out its own expected numbers.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import pytest

from served import _console_script, _sim_serve


EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lab"

FAILURES = '''
import pytest
from lm629_host import Cmd, ProtocolViolation


def test_ltrj_velocity_word_above_3fffffff(lm629):
    # LTRJ, control 0008 (velocity follows), velocity 4000 0000: above the 30-bit range
    lm629.raw(Cmd.LTRJ, [0x0008, 0x4000, 0x0000])


def test_a_caught_violation_still_fails(lm629):
    try:
        lm629.raw(Cmd.LTRJ, [0x0008, 0xFFFF, 0xFFFF])
    except ProtocolViolation:
        pass


def test_deliberate_failure(lm629):
    position = lm629.read_real_position()  # RDRP
    assert False, f"deliberate, at {position}"


def test_unmarked_move_is_a_warning_here(lm629):
    lm629.load_filter(kp=20)
    lm629.update_filter()
    lm629.move_to(100, velocity=65536, acceleration=6554).wait()
'''


@pytest.fixture
def user_dir(pytester, monkeypatch):
    """A fresh directory outside the checkout with the user's files; the suite's own
    LM629_SIM_STRICT is not passed on (the plugin makes its chips strict by itself)."""
    monkeypatch.delenv("LM629_SIM_STRICT", raising=False)
    monkeypatch.delenv("LM629_PORT", raising=False)
    for name in ("rig.py", "test_rig.py"):
        shutil.copy(EXAMPLE / name, pytester.path / name)
    assert not str(pytester.path).startswith(str(EXAMPLE.parent.parent))
    return pytester


def _section(out: str, test: str) -> str:
    """The failure report of ``test`` (from its ____ header to the next one)."""
    m = re.search(rf"_{{3,}} {test} _{{3,}}\n(.*?)(?=\n_{{3,}} |\n={{3,}} )", out, re.S)
    assert m, f"no report for {test}"
    return m.group(1)


def test_installing_the_package_registers_the_plugin():
    points = importlib.metadata.entry_points(group="pytest11")
    assert any(p.name == "lm629" and p.value == "lm629_host.integrations.pytest_plugin" for p in points)


@dataclass(frozen=True)
class UserRun:
    """One plain ``python -m pytest`` run of the user's files (examples/lab and FAILURES) on
    the simulator: its output, and each test's outcome and wall time from its JUnit XML."""

    out: str
    outcomes: dict[str, str]
    wall_s: dict[str, float]


@pytest.fixture(scope="module")
def user_run(tmp_path_factory) -> UserRun:
    """The run the tests below read, once for all of them (a pytest subprocess takes seconds);
    like ``user_dir``, in a fresh directory outside the checkout, without the suite's own
    LM629_* settings."""
    where = tmp_path_factory.mktemp("user")
    assert not str(where).startswith(str(EXAMPLE.parent.parent))
    for name in ("rig.py", "test_rig.py"):
        shutil.copy(EXAMPLE / name, where / name)
    (where / "test_failures.py").write_text(FAILURES)
    env = {k: v for k, v in os.environ.items()
           if k not in ("LM629_SIM_STRICT", "LM629_PORT", "PYTEST_ADDOPTS")}
    p = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rs", "-s",
                        "--junitxml=report.xml"], cwd=where, env=env, capture_output=True,
                       text=True, timeout=300)
    outcomes, wall = {}, {}
    for case in ElementTree.parse(where / "report.xml").iter("testcase"):
        kinds = [child.tag for child in case if child.tag in ("failure", "error", "skipped")]
        outcomes[case.get("name")] = kinds[0] if kinds else "passed"
        wall[case.get("name")] = float(case.get("time"))
    return UserRun(p.stdout, outcomes, wall)


def test_user_file_outcomes_on_the_simulator(user_run):
    """Every test of examples/lab passes on the simulator but the hardware one, skipped; the
    three deliberate failures fail; the unmarked move passes, with one warning for the run."""
    assert user_run.outcomes == {
        "test_reset_leaves_the_motor_off": "passed",
        "test_a_long_move_takes_the_time_of_its_trapezoid": "passed",
        "test_shuttle_ends_every_move_on_target": "passed",
        "test_a_free_shaft_stays_put": "passed",
        "test_a_hanging_load_pulls_the_free_shaft": "passed",
        "test_both_axes_of_a_two_axis_board": "passed",
        "test_the_bench_answers": "skipped",
        "test_ltrj_velocity_word_above_3fffffff": "failure",
        "test_a_caught_violation_still_fails": "failure",
        "test_deliberate_failure": "failure",
        "test_unmarked_move_is_a_warning_here": "passed",
    }
    assert re.search(r"= 3 failed, 7 passed, 1 skipped, 1 warning in ", user_run.out), \
        user_run.out[-500:]


def test_a_long_move_runs_on_the_simulated_clock(user_run):
    """60000 counts at 4 counts/sample with 0.05 counts/sample^2: 80 samples up, 80 down,
    (60000 - 320) / 4 = 14920 samples at speed, 15080 x 256 us = 3.860 s of simulated time;
    the wall clock takes less."""
    m = re.search(r"60000 counts in ([\d.]+) s of simulated time", user_run.out)
    assert m, user_run.out
    simulated = float(m.group(1))
    assert 3.860 <= simulated <= 3.860 + 0.3
    wall = user_run.wall_s["test_a_long_move_takes_the_time_of_its_trapezoid"]
    print(f"60000-count move: {simulated:.3f} s simulated in {wall:.3f} s of wall time")
    assert wall < simulated


def test_a_protocol_violation_fails_the_test_with_its_text_and_time(user_run):
    v = _section(user_run.out, "test_ltrj_velocity_word_above_3fffffff")
    assert re.search(r"ProtocolViolation: host protocol violation at [\d.]+ us: LTRJ velocity word "
                     r"40000000 is above 3FFFFFFF", v)
    assert re.search(r"cs0: LTRJ 0008 4000 0000  !! ProtocolViolation: host protocol violation", v)


def test_a_violation_the_test_catches_still_fails_it(user_run):
    c = _section(user_run.out, "test_a_caught_violation_still_fails")
    assert re.search(r"lm629 host protocol violation at [\d.]+ us of simulated time: LTRJ velocity "
                     r"word FFFFFFFF is above 3FFFFFFF", c)


def test_a_failure_shows_the_last_bus_programs_and_the_chips_snapshot(user_run):
    d = _section(user_run.out, "test_deliberate_failure")
    assert "lm629: last bus programs and chip snapshot" in d
    programs = d[d.index("last bus programs on sim://?strict=1"):].splitlines()
    # the reset (AN-706 4.4.1: 00 at once, C4 after 1.5 ms, C0 after MSKI/RSTI), then the RDRP
    assert re.fullmatch(r" +1\.50\d+  cs0: /RST; status 00 \(none\); wait 1500 us; status C4 "
                        r"\(TRAJECTORY_COMPLETE\|BREAKPOINT\|MOTOR_OFF\)", programs[1])
    assert re.fullmatch(r" +[\d.]+  cs0: MSKI 0000; RSTI 0000; sync C0 \(BREAKPOINT\|MOTOR_OFF\)", programs[2])
    assert re.fullmatch(r" +[\d.]+  cs0: RDRP <- 0000 0000  \[status C0 \(BREAKPOINT\|MOTOR_OFF\)\]",
                        programs[3])
    # read just after the RDRP's second byte: busy for that byte's 20 us, or clear again
    assert re.search(r"chip snapshot cs0 at t=[\d.]+ ms: status C[01] \((BUSY\|)?BREAKPOINT\|MOTOR_OFF\), "
                     r"signals 01C0 .* real position 0, following error 0", d)
    assert "after the failure: cs0: motor stopped (abrupt stop, then motor off)" in d


def test_the_hardware_test_is_skipped_on_the_simulator_saying_why(user_run):
    assert "lm629_hardware: needs a real board (--lm629-port is sim://, simulated)" in user_run.out


def test_an_unmarked_move_on_the_simulator_is_a_warning_naming_the_marker(user_run):
    assert user_run.outcomes["test_unmarked_move_is_a_warning_here"] == "passed"
    assert "starts a trajectory (chip 0) but is not marked @pytest.mark.lm629_motion" in user_run.out


def test_unknown_lm629_sim_parameter_names_the_known_ones(pytester):
    pytester.makepyfile('''
        import pytest

        @pytest.mark.lm629_sim("inertai=4e-5")
        def test_typo(lm629):
            pass
    ''')
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    r.assert_outcomes(errors=1)
    line = next(x for x in r.stdout.lines if "unknown simulator parameter" in x)
    assert "@pytest.mark.lm629_sim('inertai=4e-5')" in line
    assert re.search(r"known: .*inertia.*load_torque.*; also axes", line)
    assert "Traceback" not in r.stdout.str()


def test_a_port_that_does_not_exist_is_one_error_for_the_run(pytester):
    pytester.makepyfile('''
        def test_one(lm629):
            pass

        def test_two(lm629_board):
            pass

        def test_three(lm629):
            pass
    ''')
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--lm629-port", "/dev/ttyNOPE")
    assert r.ret == pytest.ExitCode.USAGE_ERROR
    err = r.stderr.str()
    assert err.count("ERROR: --lm629-port /dev/ttyNOPE cannot be opened: ") == 1, err
    assert "is the board plugged in?" in err
    assert "passed" not in r.stdout.str() and "Traceback" not in err + r.stdout.str()


def test_help_fixtures_and_markers_list_everything(pytester):
    r = pytester.runpytest_subprocess("--help")
    for option in ("--lm629-port=URL", "--lm629-profile=FILE", "--lm629-allow-motion"):
        assert option in r.stdout.str()
    r = pytester.runpytest_subprocess("--fixtures", "-p", "no:cacheprovider")
    out = r.stdout.str()
    assert re.search(r"^lm629 -- .*pytest_plugin", out, re.M)
    assert re.search(r"^lm629_board -- .*pytest_plugin", out, re.M)
    r = pytester.runpytest_subprocess("--markers")
    for marker in ("lm629_sim(params=", "lm629_hardware:", "lm629_motion:"):
        assert f"@pytest.mark.{marker}" in r.stdout.str()



PROFILE = """\
[board]
port = "sim://"

[axis.x]
cs = 0
kp = 20
kd = 200
min = -20000
max = 20000
following_error = 2000
"""

PROFILE_TEST = """
import pytest
from lm629_host import Signals


@pytest.mark.lm629_motion
def test_the_profiles_named_axis(lm629_board):
    x = lm629_board["x"]
    # applied after the fixture's reset: LPES with stop on error arms signals bit 9
    assert x.read_signals() & Signals.STOP_ON_ERROR
    with pytest.raises(ValueError, match="20000"):
        x.move_to(45000, velocity=65536, acceleration=6554)  # past max: nothing sent
    assert x.move_to(1000, velocity=65536, acceleration=6554).wait().position == pytest.approx(1000, abs=20)
"""


def test_profile_option_gives_the_named_axes(pytester):
    pytester.makefile(".toml", board=PROFILE)
    pytester.makepyfile(test_profiled=PROFILE_TEST)
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--lm629-profile", "board.toml")
    r.assert_outcomes(passed=1)
    pytester.makefile(".toml", bad=PROFILE.replace("kp = 20", "kp = 99999"))
    r = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--lm629-profile", "bad.toml")
    assert r.ret == pytest.ExitCode.USAGE_ERROR
    assert re.search(r"ERROR: --lm629-profile bad.toml: .*bad.toml.*kp", r.stderr.str())


# ---------------------------------------------------------------------------- a persistent bench


STOP_FILE = '''
import pytest
from lm629_host.integrations.pytest_plugin import MotionNotAllowed


def test_an_unmarked_move_sends_nothing(lm629, request):
    if request.config.getoption("lm629_allow_motion"):
        pytest.skip("--lm629-allow-motion lets any test move")
    with pytest.raises(MotionNotAllowed, match="not marked @pytest.mark.lm629_motion"):
        lm629.move_to(5000, velocity=65536, acceleration=6554)
    lm629.clock.sleep(0.05)
    assert lm629.read_desired_position() == 0


@pytest.mark.lm629_motion
def test_fails_in_the_middle_of_a_long_move(lm629):
    lm629.load_filter(kp=20, kd=200)
    lm629.update_filter()
    lm629.move_to(400000, velocity=4 * 65536, acceleration=3277)
    lm629.clock.sleep(0.2)
    assert False, "deliberate, while the motor runs"
'''


TERM_FILE = '''
import os
import signal

import pytest


@pytest.mark.lm629_motion
def test_terminated_in_the_middle_of_a_move(lm629):
    lm629.load_filter(kp=20, kd=200)
    lm629.update_filter()
    lm629.move_to(400000, velocity=4 * 65536, acceleration=3277)
    lm629.clock.sleep(0.2)
    os.kill(os.getpid(), signal.SIGTERM)
    lm629.clock.sleep(5)  # the signal ends the test here
    pytest.fail("SIGTERM did not end the test")
'''


def _status(url: str) -> dict:
    import json
    p = subprocess.run([_console_script(), "--port", url, "status", "--json"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


# over 10 s on an idle machine: a lab's test file run twice by pytest in its own process
# against one `lm629 sim serve` in real time (a 60000-count move among them): the persistent
# bench between two processes is the subject
def test_the_same_file_on_a_persistent_bench(user_dir):
    user_dir.makepyfile(test_stop=STOP_FILE)
    with _sim_serve() as url:
        r = user_dir.runpytest_subprocess("-p", "no:cacheprovider", "-rs", "--lm629-port", url)
        # reset, free shaft, hardware, the unmarked move refused; 3 motion + 2 sim tests skip
        r.assert_outcomes(passed=4, skipped=5)
        out = r.stdout.str()
        assert out.count(f"lm629_motion: moves the motor on the real port {url}; pass "
                         "--lm629-allow-motion to run it") == 3
        assert f"lm629_sim configures a simulated chip; --lm629-port {url} is a real port" in out

        r = user_dir.runpytest_subprocess("-p", "no:cacheprovider", "-rs", "-s", "--lm629-port", url,
                                          "--lm629-allow-motion")
        r.assert_outcomes(passed=5, failed=1, skipped=3)
        out = r.stdout.str()
        assert re.search(r"60000 counts in [\d.]+ s of wall time", out)
        f = _section(out, "test_fails_in_the_middle_of_a_long_move")
        assert "after the failure: cs0: motor stopped (abrupt stop, then motor off)" in f
        # the board kept its state: the motor is off, short of the target, and stays there
        first = _status(url)
        second = _status(url)
        assert "MOTOR_OFF" in first["status_flags"]
        assert first["real_position"] < 400000 // 2
        assert abs(second["real_position"] - first["real_position"]) <= 2

        # SIGTERM in the middle of a move (a CI job's timeout): an interrupted run, motor stopped
        user_dir.makepyfile(test_term=TERM_FILE)
        r = user_dir.runpytest_subprocess("-p", "no:cacheprovider", "--lm629-port", url,
                                          "--lm629-allow-motion", "test_term.py")
        assert r.ret == pytest.ExitCode.INTERRUPTED
        assert "KeyboardInterrupt: SIGTERM: the lm629 fixtures stop the motor" in r.stdout.str()
        first = _status(url)
        second = _status(url)
    assert "MOTOR_OFF" in first["status_flags"]
    assert 0 < first["real_position"] < 400000 // 2
    assert abs(second["real_position"] - first["real_position"]) <= 2


def _run(t: float, program, words=(), statuses=()):
    from lm629_host.bus.program import ProgramResult
    from lm629_host.integrations.pytest_report import Run
    return Run(t, tuple(program.ops), ProgramResult(tuple(words), tuple(statuses), 0x80))


def test_the_report_folds_repeated_programs_and_keeps_those_that_changed_the_chip():
    """40 lines: identical programs one after the other are one line with their count; when
    the log is full the oldest program that only read the chip is dropped first, so the
    LFIL / LTRJ + STT that set up a move stay in view."""
    from lm629_host import Cmd
    from lm629_host.bus.program import Program
    from lm629_host.integrations.pytest_report import TRACE_PROGRAMS, ProgramLog
    log = ProgramLog()
    log.add(_run(0.001, Program().command(Cmd.LFIL).write(0x0008).write(30)))
    log.add(_run(0.002, Program().command(Cmd.RDRP).read(2), (0, 5)))
    log.add(_run(0.003, Program().command(Cmd.LTRJ).write(0x0002).write(0).write(9000)
                 .sync().command(Cmd.STT).sync(), statuses=(0x80, 0x80)))
    for k in range(100):  # a wait's polls: the same status each time
        log.add(_run(0.004 + k * 1e-4, Program().status(), statuses=(0x80,)))
    assert len(log.runs) == 4 and log.runs[-1].count == 100
    for k in range(TRACE_PROGRAMS):  # positions that differ: one line each
        log.add(_run(0.02 + k * 1e-3, Program().command(Cmd.RDRP).read(2), (0, 10 + k)))
    lines = log.text_lines()
    # 44 lines: the RDRP at 2 ms and the 100 polls went (101 programs), then the loop's first
    # two RDRPs
    assert lines[0] == "  (103 older program(s) not shown: those that only read the chip go first)"
    assert re.fullmatch(r" +1\.0000  cs0: LFIL 0008 001E  \[status 80 \(MOTOR_OFF\)\]", lines[1])
    assert re.fullmatch(r" +3\.0000  cs0: LTRJ 0002 0000 2328; sync 80 \(MOTOR_OFF\); STT; "
                        r"sync 80 \(MOTOR_OFF\)", lines[2])
    assert re.fullmatch(r" +22\.0000  cs0: RDRP <- 0000 000C  \[status 80 \(MOTOR_OFF\)\]",
                        lines[3])
    assert len(lines) == 1 + TRACE_PROGRAMS and len(log.runs) == TRACE_PROGRAMS


def test_a_failure_report_shows_the_move_behind_its_wait_polls(pytester, monkeypatch):
    monkeypatch.delenv("LM629_SIM_STRICT", raising=False)
    pytester.makepyfile(test_polls='''
import pytest
from lm629_host import Cmd


@pytest.mark.lm629_motion
def test_waits_then_fails(lm629):
    lm629.load_filter(kp=20)
    lm629.update_filter()
    lm629.load_trajectory(acceleration=100, velocity=65536, position=50000, start=True)
    for _ in range(60):
        lm629.read_status()
    assert False, "deliberate"
''')
    out = pytester.runpytest_subprocess("-p", "no:cacheprovider").stdout.str()
    d = _section(out, "test_waits_then_fails")
    programs = d[d.index("last bus programs on sim://?strict=1"):].splitlines()
    # acceleration 100 (0000 0064), velocity 65536 (0001 0000), position 50000 (0000 C350)
    assert re.search(r"\n +[\d.]+  cs0: LTRJ 002A 0000 0064 0001 0000 0000 C350; sync C0 "
                     r"\(BREAKPOINT\|MOTOR_OFF\); STT; sync 40 \(BREAKPOINT\)\n", d)
    polls = [p for p in programs if re.search(r"cs0: status [0-9A-F]{2} ", p)]
    # 60 status reads in a row, all the same byte while the move runs: one line
    assert len(polls) == 1 and polls[0].endswith(re.search(r"\(x60, the last at [\d.]+\)$",
                                                           polls[0]).group(0))
