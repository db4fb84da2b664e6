"""The command line on a multi-axis board: --axis N, a list, status/watch of every
axis, move with one target per axis (--linear), bringup per axis, clear errors."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from lm629_host import cli


@pytest.fixture
def run():
    def _run(*args: str):
        return CliRunner().invoke(cli.main, list(args), env={"LM629_PORT": ""})
    return _run


def test_status_shows_every_axis_of_the_url(run):
    r = run("--port", "sim://?axes=2", "status", "--json")
    assert r.exit_code == 0, r.output
    rows = json.loads(r.output)["axes"]
    assert [row["axis"] for row in rows] == [0, 1]
    assert all(row["status"] == "C0" for row in rows)  # reset, masked: 80 + breakpoint
    r = run("--axis", "0,1", "status")
    assert r.exit_code == 0 and "axis 0:" in r.output and "axis 1:" in r.output


def test_move_one_target_per_axis_in_a_straight_line(run):
    r = run("--axis", "0,1", "move", "3000", "-1700", "--linear", "--vel", "196608",
            "--acc", "2000")
    assert r.exit_code == 0, r.output
    assert "straight line to [3000, -1700]" in r.output
    assert "done: axis 0" in r.output and "done: axis 1" in r.output
    # the words: the path's, scaled by each axis's share (3000 and 1700 of 3448.2)
    line = r.output.splitlines()[0]
    assert "axis 0: v 1710" in line and "axis 1: v 969" in line


def test_watch_every_axis_with_a_csv(run, tmp_path):
    out = tmp_path / "w.csv"
    r = run("--axis", "0,1", "watch", "--count", "3", "--rate", "100", "--csv", str(out))
    assert r.exit_code == 0, r.output
    rows = out.read_text().splitlines()
    assert rows[0].startswith("t_s,axis,") and len(rows) == 1 + 3 * 2
    assert [row.split(",")[1] for row in rows[1:]] == ["0", "1"] * 3
    # the two axes of a tick are read in one program: the same time stamp
    assert rows[1].split(",")[0] == rows[2].split(",")[0]


def test_one_axis_of_a_board(run):
    r = run("--axis", "1", "move", "500")
    assert r.exit_code == 0, r.output
    assert "from the target 500" in r.output


def test_bringup_per_axis(run):
    r = run("--axis", "0,1", "bringup", "--yes")
    assert r.exit_code == 0, r.output
    assert r.output.count("verdict: PASS") == 2


def test_axis_errors_are_one_line(run):
    r = run("--port", "sim+emu://?bridge=1", "--axis", "1", "status")
    assert r.exit_code == 2 and "axis 1 does not exist" in r.output
    r = run("--axis", "0,1", "filter", "--kp", "3")
    assert r.exit_code == 2 and "drives one" in r.output
    r = run("--axis", "0,1", "move", "100")
    assert r.exit_code == 2 and "1 target(s) for 2 axis" in r.output
    r = run("--axis", "x", "status")
    assert r.exit_code == 2 and "--axis" in r.output
    # a simulator builds the chips --axis names only when the URL does not say how many:
    # sim://?axes=2 is a two-chip board, as a bridge with two chip selects would be
    r = run("--port", "sim://?axes=2", "--axis", "3", "status")
    assert r.exit_code == 2 and "axis 3 does not exist" in r.output
    r = run("--port", "sim://", "--axis", "3", "status")
    assert r.exit_code == 0, r.output


def test_a_two_chip_bench_keeps_its_state_between_processes(tmp_path):
    """`lm629 sim serve --url 'sim://?axes=2'` is a two-chip bridge on a pty: separate lm629
    processes reset it, tune both axes, move both together, then read both back."""
    import subprocess
    import sys

    from lm629_host.sim.serve import SimServer

    with SimServer(tmp_path / "lm629", "sim://?axes=2").start() as srv:
        port = f"serial://{srv.link}?axes=2"

        def lm629(*args: str) -> subprocess.CompletedProcess:
            return subprocess.run([sys.executable, "-m", "lm629_host", "--port", port, *args],
                                  capture_output=True, text=True, timeout=60)

        assert lm629("--axis", "0", "reset").returncode == 0
        for k in ("0", "1"):
            r = lm629("--axis", k, "filter", "--kp", "20")
            assert r.returncode == 0, r.stderr
        r = lm629("move", "400", "-300", "--vel", "131072", "--acc", "3000")
        assert r.returncode == 0, r.stdout + r.stderr
        r = lm629("status", "--json")
        rows = json.loads(r.stdout)["axes"]
        assert [row["desired_position"] for row in rows] == [400, -300]
        chips = srv.model.chips
        assert [c.motion.desired_position for c in chips] == [400, -300]
        # a wrong number of targets is bad usage: exit 2, and nothing moved or stopped (both
        # servos still hold, motor on; before the fix the usage error stopped axis 0)
        r = lm629("move", "100")
        assert r.returncode == 2 and "1 target(s) for 2 axis" in r.stderr
        assert "motor stopped" not in r.stderr
        rows = json.loads(lm629("status", "--json").stdout)["axes"]
        assert [row["desired_position"] for row in rows] == [400, -300]
        assert not any(int(row["status"], 16) & 0x80 for row in rows), rows


def test_a_straight_line_of_length_zero_says_so(run):
    """Sent again to where it already is, a linear move moves nothing and says so."""
    r = run("--port", "sim://?axes=2", "move", "0", "0", "--linear")
    assert r.exit_code == 0, r.output
    assert "already at [0, 0], nothing moved" in r.output and "straight line" not in r.output
