"""The persistent bench: one ``lm629 sim serve`` and the CLI as separate processes against it.

A real board keeps its flags, positions and trajectory between commands and processes; every
other CLI test opens a fresh chip.  Here a server process serves one simulated chip on a
pseudo-terminal (the Python bridge, and the compiled firmware in simavr where the AVR
toolchain is present) and each ``lm629 --port serial://LINK ...`` is its own process, as at a
shell on the bench.  The server runs in real time, so the moves are kept short.

Numbers: kp = 20 leaves a P-only dead band of 256 / 20 = 12.8 counts (AN-706 5.2.4), inside
the default tolerance of 20 counts.
"""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from served import FAR_ENDS, _console_script, _env, serve


FAST = ["--vel", "655360", "--acc", "65536"]  # 10 counts/sample after a 10-sample ramp








@pytest.fixture(params=FAR_ENDS)
def far_end(request) -> str:
    return request.param


def test_moves_on_a_board_that_keeps_its_state(tmp_path, far_end):
    with serve(tmp_path, far_end) as b:
        b.ready()
        p = b.run("move", "1000")
        assert p.returncode == 0, p.stderr
        # the second move starts with TRAJECTORY_COMPLETE still set by the first: it must wait
        # for its own completion and the shaft, not return at once
        assert "TRAJECTORY_COMPLETE" in b.status()["status_flags"]
        p = b.run("move", "20000", *FAST)
        assert p.returncode == 0, p.stderr
        s = b.status()
        assert s["desired_position"] == 20000
        assert abs(20000 - s["real_position"]) <= 20
        done = p.stdout.strip().splitlines()[-1]
        assert done.startswith("done: at ") and "from the target 20000" in done
        # negative positions as typed, on the same chip
        p = b.run("move", "-3000", *FAST)
        assert p.returncode == 0, p.stderr
        s = b.status()
        assert s["desired_position"] == -3000 and abs(-3000 - s["real_position"]) <= 20
        assert "MOTOR_OFF" not in s["status_flags"]  # holding position


@pytest.mark.parametrize("fault, reason", [("stall=1", "stall"), ("reversed=1", "runaway")])
def test_stalled_or_reversed_motor_is_a_motion_fault(tmp_path, far_end, fault, reason):
    with serve(tmp_path, far_end, f"sim://?{fault}") as b:
        b.ready()
        p = b.run("move", "5000")
        assert p.returncode == 9, p.stdout + p.stderr
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and f"motion fault ({reason})" in lines[0]
        assert "motor stopped (abrupt stop, then motor off)" in lines[0]
        s = b.status()
        assert "MOTOR_OFF" in s["status_flags"] and s["desired_velocity"] == 0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_during_a_move_stops_the_motor(tmp_path, far_end, sig):
    with serve(tmp_path, far_end) as b:
        b.ready()
        # 200000 counts at 1 count/sample: 51 s, far longer than the test
        proc = subprocess.Popen(b.argv("move", "200000"), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=_env())
        line = proc.stdout.readline()  # printed right after the STT: the motor is moving
        assert line.startswith("moving to 200000"), line + proc.stderr.read()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 128 + sig
        name = "terminated (SIGTERM)" if sig == signal.SIGTERM else "hang-up (SIGHUP)"
        assert err.strip() == f"lm629: {name} -- motor stopped (abrupt stop, then motor off)"
        s = b.status()
        assert "MOTOR_OFF" in s["status_flags"] and s["desired_velocity"] == 0


@pytest.mark.parametrize("far_end", ["python", "python+uno"])
def test_closed_stdout_during_a_move_stops_the_motor(tmp_path, far_end):
    with serve(tmp_path, far_end) as b:
        b.ready()
        proc = subprocess.Popen(b.argv("move", "200000"), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=_env())
        proc.stdout.close()  # the reader went away: the first line after the STT fails
        err = proc.stderr.read()
        assert proc.wait(timeout=30) == 141
        assert err.strip() == ("lm629: output closed (broken pipe) during a move -- motor "
                               "stopped (abrupt stop, then motor off)")
        s = b.status()
        assert "MOTOR_OFF" in s["status_flags"] and s["desired_velocity"] == 0


@pytest.mark.under_load  # rows 10 ms apart within 2 ms, on a busy host too
def test_watch_times_rows_from_the_first_on_a_served_bench(tmp_path, far_end):
    """The served bench's clock (like a bridge's timer) has run long before the command: t_s
    counts from the first row, in the table and in the CSV, on one axis and on several."""
    import csv
    with serve(tmp_path, far_end, "sim://?axes=2") as b:
        out = tmp_path / "w.csv"
        p = b.run("watch", "--rate", "100", "--count", "3", "--csv", str(out))
        assert p.returncode == 0, p.stderr
        table = [float(ln.split()[0]) for ln in p.stdout.splitlines()[1:]]
        logged = [float(r["t_s"]) for r in csv.DictReader(out.open())]
        for times in (table, logged):
            assert times[0] == 0.0 and len(times) == 3
            assert all(abs(t - 0.010 * k) < 2e-3 for k, t in enumerate(times))  # 10 ms apart
        p = b.run("--axis", "0,1", "watch", "--rate", "100", "--count", "2", "--csv", str(out))
        assert p.returncode == 0, p.stderr
        rows = list(csv.DictReader(out.open()))
        assert [r["axis"] for r in rows] == ["0", "1", "0", "1"]
        assert float(rows[0]["t_s"]) == 0.0 and all(0 <= float(r["t_s"]) < 0.1 for r in rows)
        assert float(p.stdout.splitlines()[1].split()[0]) == 0.0


def test_closed_stdout_after_a_move_is_exit_141_and_the_motor_holds(tmp_path, far_end):
    """The reader goes away after the move's first line (`lm629 move N | head -1`): the last
    line ("done: ...") is lost, so the command did not succeed, but the move itself ended
    where it was sent and the servo holds there."""
    with serve(tmp_path, far_end) as b:
        b.ready()
        proc = subprocess.Popen(b.argv("move", "300"), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=_env())
        assert proc.stdout.readline().startswith("moving to 300")
        proc.stdout.close()  # the "done" line, written after the move, fails
        err = proc.stderr.read()
        assert proc.wait(timeout=30) == 141, err
        assert "Traceback" not in err and "Exception ignored" not in err
        s = b.status()
        assert s["desired_position"] == 300 and abs(300 - s["real_position"]) <= 20
        assert "MOTOR_OFF" not in s["status_flags"]  # holding, not stopped


@pytest.mark.parametrize("far_end", ["python", "python+uno"])
def test_index_wait_timeout_leaves_a_holding_servo_on(tmp_path, far_end):
    with serve(tmp_path, far_end, "sim://?index_offset=500") as b:
        b.ready()
        assert b.run("move", "100").returncode == 0
        p = b.run("index", "--wait", "0.2")
        assert p.returncode == 7
        assert "waited 0.2 s for the index pulse (status bit 3)" in p.stderr
        assert "MOTOR_OFF" not in b.status()["status_flags"]  # still holding


def test_sim_serve_refuses_a_path_in_use_and_keeps_files_it_did_not_make(tmp_path):
    exe = _console_script()
    with serve(tmp_path, "python") as b:
        p = subprocess.run([exe, "sim", "serve", "--pty", str(b.link)], capture_output=True,
                           text=True, timeout=30, env=_env())
        assert p.returncode == 2 and "in use" in p.stderr
        assert b.link.is_symlink() and b.status()["status"]  # the first server still answers
    mine = tmp_path / "notes.txt"
    mine.write_text("keep me")
    p = subprocess.run([exe, "sim", "serve", "--pty", str(mine)], capture_output=True,
                       text=True, timeout=30, env=_env())
    assert p.returncode == 2 and "exists" in p.stderr and mine.read_text() == "keep me"
    p = subprocess.run([exe, "sim", "serve", "--pty", str(tmp_path / "missing" / "p")],
                       capture_output=True, text=True, timeout=30, env=_env())
    assert p.returncode == 2 and "does not exist" in p.stderr and "Traceback" not in p.stderr


def test_a_move_on_a_chip_without_gains_says_so(tmp_path):
    """A served bench as from power-up has kp = 0: `move 2000` stalls with the shaft at 0, and
    the line names the cause and the fix, not the amplifier (exit 9, the motor off)."""
    with serve(tmp_path, "python") as b:
        p = b.run("move", "2000")
        assert p.returncode == 9, p.stderr
        assert "no gains loaded: run `lm629 profile apply` or `lm629 filter --kp N`" in p.stderr
        b.ready()  # kp = 20: the same move then ends on its target
        p = b.run("move", "2000")
        assert p.returncode == 0, p.stderr


@pytest.mark.skipif(os.geteuid() != 0, reason="only root may raise a process's priority")
def test_the_served_bench_runs_ahead_of_the_host_s_load(tmp_path):
    """The served far end stands for the bridge's own microcontroller, which CPU hogs on the
    host PC do not slow: every thread of `lm629 sim serve` runs at nice -10 (where allowed),
    so the load makes the host late, not the board."""
    from lm629_host.cli.sim import SERVER_NICE

    with serve(tmp_path, "firmware") as b:
        b.ready()
        tasks = list(Path(f"/proc/{b.server.pid}/task").iterdir())
        nice = {int(Path(t, "stat").read_text().rsplit(")", 1)[1].split()[16]) for t in tasks}
        assert nice == {SERVER_NICE}, nice
