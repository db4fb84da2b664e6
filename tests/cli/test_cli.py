"""The ``lm629`` command line through click's runner (and once as the installed script).

Every command runs against a fresh ``sim://`` chip; the CLI resets it and loads kp = 20 first.
Numbers: 8 MHz, T = 256 us; the default motor has 500 lines = 2000 counts/rev.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import re
import sys

import pytest

from served import _console_script, err_lines
from click.testing import CliRunner

import lm629_host
from lm629_host import Cmd, TrajectoryFlags, cli
from lm629_host.cli import app as cli_app
from lm629_host.cli import motion as cli_motion

T = 2048 / 8e6


@pytest.fixture
def run():
    runner = CliRunner()

    def _run(*args: str, env: dict | None = None):
        return runner.invoke(cli.main, list(args), env=env or {"LM629_PORT": ""},
                             catch_exceptions=False)
    return _run




def test_help_documents_every_exit_code(run):
    r = run("--help")
    assert r.exit_code == 0
    for code, meaning in cli.EXIT_CODES.items():
        assert f"{code:>3}  {meaning}" in r.output
    assert "130  interrupted" in r.output and "  5  reset failure" in r.output


def test_default_port_is_the_simulator_with_a_notice(run):
    r = run("status")
    assert r.exit_code == 0
    assert len(err_lines(r)) == 1 and "simulator" in r.stderr and "sim serve" in r.stderr
    assert "for this command only" in r.stderr


def test_env_port_is_used_without_notice(run):
    r = run("status", "--json", env={"LM629_PORT": "sim://?chip=lm628"})
    assert r.exit_code == 0 and r.stderr == ""


def test_bringup_passes_every_step_on_the_simulator(run):
    r = run("--port", "sim://", "bringup", "--yes")
    assert r.exit_code == 0, r.output
    for name in ("reset", "phasing", "hold", "move", "settle"):
        assert any(ln.strip().startswith("[PASS] " + name) for ln in r.output.splitlines()), name
    assert "status bytes seen: 00 " in r.output
    assert "verdict: PASS" in r.output


def test_bringup_reports_reversed_leads(run, opened):
    r = run("--port", "sim://?reversed=1&record=1", "bringup", "--yes")
    assert r.exit_code == 1
    assert "[FAIL] phasing" in r.output and "Swap the motor leads" in r.output
    assert opened[0].transport.model.motor_off


def test_bringup_interactive_no_moves_nothing(run, opened):
    r = CliRunner().invoke(cli.main, ["--port", "sim://?record=1", "bringup"], input="n\n")
    assert "free to turn" in r.output
    assert r.exit_code == 1 and "INCOMPLETE" in r.output
    assert Cmd.STT not in [c for c, _ in opened[0].transport.model.history]


def test_chip_stuck_in_reset_gives_one_line_and_exit_5(run):
    for args in (("status",), ("bringup", "--yes"), ("reset",)):
        r = run("--port", "sim://?fault=reset", *args)
        assert r.exit_code == 5, args
        if args[0] != "bringup":
            lines = err_lines(r)
            assert len(lines) == 1 and "reset check failed" in lines[0]
            assert "Traceback" not in r.stderr
        else:
            assert "[FAIL] reset" in r.output and "00 00 00" in r.output


@pytest.mark.parametrize("port,code,words", [
    ("/dev/lm629-no-such-port", 3, "no serial port"),
    ("bogus://x", 2, "unknown port scheme"),  # bad usage, not a link fault
    ("sim://?no_such_param=1", 2, "no_such_param"),
])
def test_bad_ports_give_one_line(run, port, code, words):
    r = run("--port", port, "status")
    assert r.exit_code == code
    lines = err_lines(r)
    assert len(lines) == 1 and words in lines[0] and lines[0].startswith("lm629: ")


def test_bad_values_name_argument_and_range(run, opened):
    r = run("--port", "sim://?record=1", "filter", "--kp", "40000")
    assert r.exit_code == 2
    assert "kp=40000" in r.stderr and "0..32767" in r.stderr and len(err_lines(r)) == 1
    # nothing after the simulator's own preparation reached the chip: no second LFIL
    hist = [c for c, _ in opened[0].transport.model.history]
    assert hist.count(Cmd.LFIL) == 1
    r = run("raw", "0x1F", "0x10000")
    assert r.exit_code == 2 and "word=65536" in r.stderr
    r = run("watch", "--rate", "0")
    assert r.exit_code == 2 and "--rate: 0 must be in 0..1000" in r.stderr
    r = run("--clock", "12MHz", "status")
    assert r.exit_code == 2 and "1-8 MHz" in r.output + r.stderr


def test_verbose_error_shows_the_traceback(run):
    r = run("-v", "--port", "sim://?fault=reset", "status")
    assert r.exit_code == 5 and "Traceback" in r.stderr


def test_status_json_decodes_the_reset_state(run):
    r = run("--port", "sim://", "--lines", "500", "status", "--json")
    d = json.loads(r.output)
    assert d["real_position"] == 0 and d["desired_position"] == 0
    assert "MOTOR_OFF" in d["status_flags"]  # off until the first STT after reset
    assert "EIGHT_BIT_OUTPUT" in d["signals_flags"]
    assert d["real_position_rev"] == 0.0
    r = run("status")
    assert "status   " in r.output and "signals  " in r.output and "integration sum" in r.output


def test_move_in_revolutions_and_rpm(run):
    # 0.5 rev at 500 lines = 1000 counts; 600 rpm = 2000 * T * 10 rev/s * 65536 = 335544
    r = run("--port", "sim://", "--lines", "500", "move", "0.5", "--vel", "600", "--acc", "100")
    assert r.exit_code == 0, r.stderr
    assert "moving to 1000 counts (0.5000 rev) (velocity word 335544," in r.output
    done = r.output.splitlines()[-1]
    assert done.startswith("done: at ") and "from the target 1000 (tolerance 20)" in done
    actual = int(done.split("at ")[1].split(" ")[0])
    assert 1000 - 14 <= actual <= 1000  # kp = 20 dead band


def test_move_along_an_s_curve_in_the_units_of_lines(run):
    """2 rev at 600 rpm, 100 rev/s^2, 2000 rev/s^3 on 500 lines: 4000 counts at 20000 counts/s,
    200000 counts/s^2, 4e6 counts/s^3.  Ramps of V/A + A/J = 0.15 s covering 1500 counts each,
    1000 counts at V (0.05 s): 0.35 s, 18 pieces of 20 ms, the top one the --vel word."""
    r = run("--port", "sim://", "--lines", "500", "move", "2", "--vel", "600", "--acc", "100",
            "--shape", "s-curve", "--jerk", "2000")
    assert r.exit_code == 0, r.stderr
    assert ("moving to 4000 counts (2.0000 rev) along an S-curve: 18 pieces 20 ms apart, 0.350 s "
            "planned (top velocity word 335544,") in r.output
    assert r.output.splitlines()[-1].startswith("done: at ")
    r = run("--port", "sim://", "move", "4000", "--jerk", "5")
    assert r.exit_code == 2 and "--jerk" in r.stderr and "needs --shape s-curve" in r.stderr
    r = run("--port", "sim://", "move", "4000", "--shape", "s-curve")
    assert r.exit_code == 2 and "needs --jerk" in r.stderr
    r = run("--port", "sim://", "move", "4000", "--shape", "s-curve", "--jerk", "1e6",
            "--no-wait")
    assert r.exit_code == 2 and "--no-wait" in r.stderr


def test_move_relative_and_no_wait(run):
    r = run("--port", "sim://", "move", "-r", "500", "--no-wait")
    assert r.exit_code == 0 and "moving to 500 counts" in r.output and "done" not in r.output
    r = run("--port", "sim://", "move", "1.5")
    assert r.exit_code == 2 and "whole counts" in r.stderr


def test_move_timeout_stops_the_motor(run, opened):
    # 100000 counts at 1 count/sample takes 25.6 s: a 0.2 s wait times out
    r = run("--port", "sim://?record=1", "move", "100000", "--timeout", "0.2")
    assert r.exit_code == 9  # a move that did not get there: a motion fault
    assert "motion fault (timeout): not on target after 0.2 s" in r.stderr
    assert "motor stopped (abrupt stop, then motor off)" in r.stderr and len(err_lines(r)) == 1
    model = opened[0].transport.model
    assert model.motor_off


def test_ctrl_c_during_a_move_stops_the_motor_then_exits_130(run, monkeypatch):
    """A real SIGINT, sent from the bus trace 300 cycles after the move's STT (in the middle of
    a bus program): the CLI lets that program finish, then stops the motor (abrupt stop, motor
    off) on a clean bus -- the strict simulator would raise on a program cut in half."""
    chips = []
    real = cli_app._open

    def _open(url, chip, trace):
        state = {"after_stt": None}

        def interrupting(cycle):
            if trace is not None:  # --trace given
                trace(cycle)
            model = chips[0].transport.model if chips else None
            if state["after_stt"] is None:
                if cycle.kind == "command" and cycle.value == Cmd.STT and model.history[-2][0] \
                        == Cmd.LTRJ and model.history[-2][1][0] & TrajectoryFlags.POSITION:
                    state["after_stt"] = 0
            else:
                state["after_stt"] += 1
                if state["after_stt"] == 3000:
                    os.kill(os.getpid(), signal.SIGINT)
        c = real(url, chip, interrupting)
        chips.append(c)
        return c
    monkeypatch.setattr(cli_app, "_open", _open)
    before = signal.getsignal(signal.SIGINT)
    r = run("--port", "sim://?record=1", "move", "20000")
    assert signal.getsignal(signal.SIGINT) is before  # the CLI's handler is gone again
    assert r.exit_code == 130
    assert err_lines(r) == ["lm629: interrupted (Ctrl-C) -- motor stopped (abrupt stop, then "
                            "motor off)"]
    model = chips[0].transport.model
    assert not model.violations
    tail = [(c, w) for c, w in model.history if c in (Cmd.LTRJ, Cmd.STT)][-4:]
    assert tail == [(Cmd.LTRJ, (int(TrajectoryFlags.STOP_ABRUPT),)), (Cmd.STT, ()),
                    (Cmd.LTRJ, (int(TrajectoryFlags.MOTOR_OFF),)), (Cmd.STT, ())]
    assert model.motor_off
    assert 0 < model.motion.desired_position < 20000  # stopped on the way (the port is closed)


def test_velocity_runs_then_stops_smoothly(run):
    # 1 count/sample after a 100-sample ramp (655/65536): 0.5 s = 1953 samples -> ~1903 counts
    r = run("--port", "sim://", "velocity", "65536", "--time", "0.5")
    assert r.exit_code == 0
    line = next(ln for ln in r.output.splitlines() if ln.startswith("after 0.5 s"))
    assert "actual 1.0000 counts/sample" in line
    pos = int(line.split("position ")[1].split(" ")[0])
    assert 1953 - 50 - 100 < pos <= 1953 - 50
    # the smooth stop decelerates at 0.01 count/sample^2 from 1 count/sample: 100 samples,
    # 50 counts further; the CLI waits for it and says where the shaft rests
    rest = r.output.rstrip().splitlines()[-1]
    assert rest.startswith("smooth stop: at rest at ")
    assert pos + 40 <= int(rest.split("at rest at ")[1].split(" ")[0]) <= pos + 50 + 60
    r = run("velocity", "--", "-1")
    assert r.exit_code == 2 and "--reverse" in r.stderr


def test_stop_home_limit_breakpoint_reach_the_chip(run, opened):
    port = "sim://?record=1"
    assert run("--port", port, "stop", "--off").exit_code == 0
    assert run("--port", port, "stop").exit_code == 0
    assert run("--port", port, "home").exit_code == 0
    r = run("--port", port, "limit", "2000", "--stop")
    assert r.exit_code == 0 and "LPES 2000" in r.output
    assert run("--port", port, "limit", "300").exit_code == 0
    assert run("--port", port, "breakpoint", "0x100").exit_code == 0
    assert run("--port", port, "breakpoint", "-r", "50").exit_code == 0
    h = [m.transport.model.history for m in opened]
    assert (Cmd.LTRJ, (int(TrajectoryFlags.MOTOR_OFF),)) in h[0]
    assert (Cmd.LTRJ, (int(TrajectoryFlags.STOP_ABRUPT),)) in h[1]
    assert Cmd.DFH in [c for c, _ in h[2]]
    assert (Cmd.LPES, (2000,)) in h[3] and (Cmd.LPEI, (300,)) in h[4]
    assert (Cmd.SBPA, (0x0000, 0x0100)) in h[5] and (Cmd.SBPR, (0, 50)) in h[6]
    r = run("--port", port, "breakpoint", "5000", "--wait", "0.1")
    assert r.exit_code == 7 and "waited 0.1 s" in r.stderr


def test_index_search_latches_the_index_position(run):
    # the index is 500 counts into each revolution; a search at 1 count/sample finds it
    r = run("--port", "sim://?index_offset=500", "index", "--search", "65536", "--wait", "2")
    assert r.exit_code == 0 and r.output.strip().endswith("index at position 500 counts")
    r = run("index")
    assert r.exit_code == 0 and "armed" in r.output


def test_watch_rows_on_the_simulated_clock_and_csv(run, tmp_path):
    path = tmp_path / "w.csv"
    r = run("--port", "sim://", "watch", "--rate", "100", "--count", "4", "--csv", str(path))
    assert r.exit_code == 0
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and len(r.output.splitlines()) == 5
    times = [float(x["t_s"]) for x in rows]
    steps = [b - a for a, b in zip(times, times[1:])]
    assert all(abs(d - 0.010) < 2e-5 for d in steps)  # a fixed 10 ms cadence, simulated
    assert rows[-1]["status"] in ("80", "C0") and "motor_off" in rows[-1]["flags"]


def test_step_writes_csv_and_png(run, tmp_path):
    out = tmp_path / "s.csv"
    r = run("--port", "sim://", "step", "200", "--kp", "20", "--kd", "100", "--csv", str(out),
            "--time", "0.3")
    assert r.exit_code == 0, r.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 301  # the snapshot before STT, then one per ms up to 0.3 s
    assert int(rows[-1]["desired_position"]) == 200
    assert max(int(x["real_position"]) for x in rows) > 200  # kd = 100 still overshoots
    assert abs(int(rows[-1]["following_error"])) <= 14
    png = out.with_suffix(".png")
    pytest.importorskip("matplotlib")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_step_without_matplotlib_says_how_to_get_it(run, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    out = tmp_path / "s.csv"
    r = run("step", "100", "--csv", str(out), "--time", "0.05")
    assert r.exit_code == 0
    assert out.exists() and not out.with_suffix(".png").exists()
    assert "pip install 'lm629-host[plot]'" in r.stderr


def test_calc_words_in_decimal_and_hex(run):
    r = run("--lines", "500", "calc", "--rpm", "3000", "--rev", "2", "--accel", "10",
            "--velocity-word", "0x51EB8", "--counts", "500")
    assert r.exit_code == 0 and r.stderr == ""  # no port, no notice
    # 3000 rpm: 2000 counts x 256 us x 50 rev/s x 65536 = 1677721.6 -> 1677722 = 0x19999A
    assert "3000 rpm = velocity 1677722 (0x0019999A)" in r.output
    assert "2 rev = position 4000 (0x00000FA0)" in r.output
    # 10 rev/s^2: 2000 x (256 us)^2 x 10 x 65536 = 85.9 -> 86
    assert "10 rev/s^2 = acceleration 86 (0x00000056)" in r.output
    assert "velocity 335544 (0x00051EB8) = 599.9994 rpm" in r.output
    assert "500 counts = 0.250000 rev" in r.output
    # AN-706 5.3 shape: 10 rev in 2 s with 0.5 s ramps: cruise 20000 counts / 1.5 s / 3906.25
    # samples/s = 3.4133 counts/sample -> 223696; / 1953.125 samples of ramp -> 114.5 -> 115
    r = run("calc", "--lines", "500", "--trapezoid", "10", "2", "0.5")
    assert "position     20000 (0x00004E20)" in r.output
    assert "velocity     223696 (0x000369D0)" in r.output
    assert "acceleration 115 (0x00000073)" in r.output
    r = run("calc", "--rpm", "100")
    assert r.exit_code == 2 and "lines" in r.output + r.stderr


def test_raw_reads_and_writes(run):
    r = run("--port", "sim://", "raw", "0x0A", "--read", "2")
    assert r.exit_code == 0 and r.output.startswith("read 0000 0000")
    r = run("--port", "sim://", "raw", "1Bh", "100")  # LPEI 100, datasheet-style hex
    assert r.exit_code == 0 and "status" in r.output


def test_trace_verbose_and_stats(run):
    r = run("--trace", "--stats", "--port", "sim://", "home")
    assert "bus command 02" in r.stderr  # DFH
    assert r.stderr.splitlines()[-1].startswith("stats: programs=")
    r = run("-vv", "--port", "sim://", "home")
    assert "lm629_host.bus: sim command 02" in r.stderr


def test_list_and_doctor(run):
    r = run("list")
    assert r.exit_code == 0 and r.output.startswith("sim://")
    r = run("--port", "sim://", "doctor")
    # the exit code follows the problems shown (no FT232H on this machine's USB bus is one)
    assert r.exit_code == (1 if "[!!]" in r.output else 0)
    assert ("problem(s) above" in r.output) == (r.exit_code == 1)
    assert "pyserial" in r.output and "serial://" in r.output and "ftdi://" in r.output
    assert "round trip" in r.output


def test_bridge_groups_are_registered(run):
    r = run("sim", "--help")
    assert r.exit_code == 0 and "serve" in r.output




def test_installed_console_script_runs_bringup():
    exe = _console_script()
    p = subprocess.run([exe, "bringup", "--yes"], capture_output=True, text=True, timeout=120,
                       env={"PATH": "/usr/bin:/bin", "LM629_SIM_STRICT": "1"})
    assert p.returncode == 0, p.stderr
    assert "verdict: PASS, every step" in p.stdout
    assert p.stderr.count("\n") == 1 and "simulator" in p.stderr
    p = subprocess.run([sys.executable, "-m", "lm629_host", "--port", "sim://?fault=reset",
                        "status"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 5 and p.stderr.count("\n") == 1
    assert lm629_host.__version__


def test_chip_dying_mid_move_exits_4_and_says_the_motor_may_still_run(run, monkeypatch):
    """The busy bit sticks (sim fault=busy switched on mid-move): the move's next program times
    out (exit 4), the safety stop cannot reach the chip either, and the one error line says to
    switch off the motor supply."""
    chips = []
    real = cli_app._open

    def _open(url, chip, trace):
        n = {"cycles": 0, "started": False}

        def dying(cycle):
            if trace is not None:  # --trace given
                trace(cycle)
            history = chips[0].transport.model.history if chips else []
            n["started"] = n["started"] or bool(history and history[-1][0] == Cmd.STT)
            if n["started"]:
                n["cycles"] += 1
                if n["cycles"] == 100:
                    chips[0].transport.model.params.fault = "busy"
        c = real(url, chip, dying)
        chips.append(c)
        return c
    monkeypatch.setattr(cli_app, "_open", _open)
    r = run("--port", "sim://?record=1", "move", "20000")
    assert r.exit_code == 4
    lines = err_lines(r)
    assert len(lines) == 1 and lines[0].startswith("lm629: error: busy bit stayed set")
    assert "COULD NOT STOP THE MOTOR" in lines[0] and "switch off the motor supply" in lines[0]
    assert not chips[0].transport.model.motor_off  # indeed still driving


def test_move_progress_line_on_a_terminal(run, monkeypatch):
    """On a terminal the wait rewrites one progress line (carriage return, erase to the end);
    at 1 count/sample with 50 ms polls a 2000-count move shows ~11 updates."""
    monkeypatch.setattr(cli_motion, "_isatty", lambda: True)
    r = run("--port", "sim://", "move", "2000")
    assert r.exit_code == 0
    updates = r.stderr.count("\r")
    assert 8 <= updates <= 14
    assert "-> 2000" in r.stderr and "\x1b[K" in r.stderr


def test_ctrl_c_ends_watch_cleanly(run, signal_on_row):
    """watch moves nothing: Ctrl-C (a real SIGINT, during the 3rd row's bus program) ends it
    with exit 130 (the --help table) once that program is over; the interrupted row is not
    printed, nothing is stopped."""
    signal_on_row(signal.SIGINT)
    r = run("--port", "sim://", "watch", "--rate", "50")
    assert r.exit_code == 130
    assert len(r.stdout.splitlines()) == 1 + 2
    assert r.stderr == "(2 rows)\nlm629: interrupted (Ctrl-C)\n"


def test_out_of_range_move_sends_no_trajectory(run):
    """Exit 2 promises nothing was sent: the goal is checked before any LTRJ (the trace shows
    the simulator's preparation, MSKI included, and no LTRJ)."""
    r = run("--trace", "move", str(1 << 30))
    assert r.exit_code == 2 and "1073741824 counts, outside -1073741824..1073741823" in r.stderr
    assert "bus " not in r.stderr  # checked before the port was even opened


def test_acceleration_is_left_out_while_the_motor_moves():
    """AN-706 4.6.1: the chip refuses an STT that changes the acceleration during a move, so
    move/velocity change the target on the fly with the loaded acceleration, and --acc while
    moving is refused before the bus."""
    chip = lm629_host.open("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    assert cli_motion._acceleration_unless_moving(chip, 500, given=True) == 500  # at rest
    chip.load_trajectory(acceleration=500, velocity=65536, velocity_mode=True, start=True)
    chip.clock.sleep(0.05)
    assert chip.is_moving()
    assert cli_motion._acceleration_unless_moving(chip, 500, given=False) is None
    with pytest.raises(ValueError, match="the motor is moving"):
        cli_motion._acceleration_unless_moving(chip, 500, given=True)
    chip.load_trajectory(velocity=65536, position=chip.read_desired_position() + 300, start=True)
    chip.wait_for(lm629_host.Status.TRAJECTORY_COMPLETE, timeout=2)
    assert not chip.is_moving()


def test_step_refuses_a_moving_motor():
    from lm629_host.bench.capture import capture_move

    chip = lm629_host.open("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=500, velocity=65536, velocity_mode=True, start=True)
    with pytest.raises(ValueError, match="the motor is moving"):
        capture_move(chip, 200, duration_s=0.1, interval_s=0.01, velocity=65536,
                     acceleration=500)


def test_doctor_without_the_optional_pyftdi_or_an_ft232h_finds_no_problem(run, monkeypatch):
    """pyftdi is an extra and an FT232H one adapter of two: neither missing is a problem on a
    bench that uses a serial bridge, as a bridge not found is not one either."""
    monkeypatch.setitem(sys.modules, "pyftdi", None)  # import pyftdi -> ImportError
    r = run("doctor")
    assert "[!!]" not in r.output, r.output
    assert "[--] pyftdi: not installed, optional: only ftdi:// needs it" in r.output
    assert r.output.rstrip().endswith("no problems found") and r.exit_code == 0


def _commands(group, path=()):
    """Every command under ``group``, loaded (``main`` loads its families lazily: its
    ``commands`` holds only those loaded so far)."""
    import click
    ctx = click.Context(group, info_name=path[-1] if path else "lm629")
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        yield (*path, name), cmd
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, (*path, name))


def test_every_option_has_help_and_every_summary_ends_where_it_should(run):
    import click
    missing = [f"{' '.join(p)} {opt.opts[0]}" for p, cmd in _commands(cli.main)
               for opt in cmd.params if isinstance(opt, click.Option) and not opt.help]
    assert not missing, f"options without help: {missing}"
    out = run("--help").output
    commands = out.split("Commands:")[1]
    assert "..." not in commands  # no summary cut mid-sentence
    assert "socket://" in out and "sim+emu://" in out  # every kind of port in --port's help


@pytest.mark.parametrize("command", [["move", "100"], ["step", "100", "--no-png"]])
def test_velocity_and_acceleration_are_spelt_alike_everywhere(run, command, tmp_path):
    """--velocity/--acceleration on every command that takes them, the short forms as
    aliases: the same words in the move's line either way."""
    lines = []
    for v, a in (("--velocity", "--acceleration"), ("--vel", "--acc"), ("--vel", "--accel")):
        r = run("--port", "sim://", *command, v, "65536", a, "600",
                *(["--csv", str(tmp_path / "s.csv")] if command[0] == "step" else []))
        assert r.exit_code == 0, r.output
        lines.append(r.stdout.splitlines()[0])
    assert len(set(lines)) == 1


def test_tune_distances_are_revolutions_with_lines_as_move_s(run):
    r = run("--port", "sim://", "--lines", "500", "tune", "--travel", "0.01", "--yes")
    assert r.exit_code == 2
    assert "--travel=0.01 is 20 counts: it must be at least 100 counts" in r.stderr


def test_scope_keeps_its_key_off_the_data_and_one_time_axis_for_both_panes():
    """A 3 s ramp seen through a 2 s window: the plot shows 1.0 to 3.0 s in both panes (the
    same tick labels), no label inside either canvas (a legend there hid the ramp's start),
    and the key on a line of its own below."""
    from types import SimpleNamespace

    from lm629_host.cli.scope import render
    from lm629_host.bench.scope import ScopeWindow
    win = ScopeWindow(["x"], 2.0)
    for i in range(301):  # 10 ms apart: desired 0..30000, actual lagging 50 counts
        win.add([SimpleNamespace(time=i * 0.01, desired_position=100 * i,
                                 real_position=100 * i - 50)])
    text = click_unstyle(render(win, 90, 30, "desired / actual"))
    lines = text.splitlines()
    ticks = [ln.split() for ln in lines if re.fullmatch(r"\s*[\d.]+(\s+[\d.]+)+\s*", ln)]
    assert len(ticks) == 2 and ticks[0] == ticks[1], ticks
    assert float(ticks[0][0]) == pytest.approx(1.0, abs=0.02) and float(ticks[0][-1]) == 3.0
    canvas = [ln for ln in lines if "│" in ln]
    assert canvas and not any("desired" in ln or "error" in ln for ln in canvas)
    assert lines[-1] == "top: x desired, x actual; bottom: x error (in colour order)"


def test_scope_without_plotext_is_a_usage_error(run, monkeypatch):
    monkeypatch.setitem(sys.modules, "plotext", None)
    r = run("--port", "sim://", "scope", "--duration", "0.1")
    assert r.exit_code == 2
    assert r.stderr.startswith("lm629: the terminal plot needs plotext: pip install "
                               "'lm629-host[scope]'")


def click_unstyle(text: str) -> str:
    return re.sub(r"\x1b\[[0-9;]*m", "", text)
