"""``lm629 move`` near the position register's wrap: a target as typed is a register value,
reached the short way round, and a move planned longer than ``--max-duration`` (10 minutes,
or the profile's ``max_move_s``) is refused before anything moves (exit 2).

From ``reset_position=0x3FFFF000`` (4096 counts below 3FFFFFFF) the register value 20000 is
2^30 - 4096 - 20000 = 1073717728 counts away: at the default words (1 count/sample, 655/65536
count/sample^2) 1073717728 + 100 samples of 256 us, 274872 s.  c351da8 printed "moving to
20000 counts" and started it.
"""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from lm629_host import Cmd, cli

URL = "sim://?reset_position=0x3FFFF000&record=1"  # record: the commands the chip got


@pytest.fixture
def run():
    runner = CliRunner()

    def _run(*args: str):
        return runner.invoke(cli.main, list(args), env={"LM629_PORT": ""},
                             catch_exceptions=False)
    return _run


def _sent(chip) -> set[int]:
    return {c for c, _ in chip.transport.model.history}


def test_a_target_past_the_wrap_is_refused_before_it_starts(run, opened):
    r = run("--port", URL, "move", "20000", "--timeout", "1")  # (c351da8 would wait 76 h)
    assert r.exit_code == 2, r.output
    assert "1073717728 counts" in r.output and "274872 s" in r.output
    assert "--max-duration 274872" in r.output and "moving to" not in r.output
    assert "motor stopped" not in r.output  # it never started: nothing to stop
    assert not {Cmd.LTRJ, Cmd.STT} & _sent(opened[0])


def test_the_same_move_as_a_distance_crosses_the_wrap_and_lands(run, opened):
    r = run("--port", URL, "move", "--relative", "20000")
    assert r.exit_code == 0, r.output
    assert "target 1073757728" in r.output  # 0x3FFFF000 + 20000, extended past 3FFFFFFF


def test_max_duration_allows_a_long_move(run, opened):
    r = run("--port", URL, "move", "20000", "--max-duration", "3e5", "--no-wait")
    assert r.exit_code == 0, r.output
    assert "moving to" in r.output and Cmd.STT in _sent(opened[0])


def test_a_profile_sets_the_limit_per_axis(run, opened, tmp_path):
    profile = tmp_path / "bench.toml"
    profile.write_text(f'[board]\nport = "{URL}"\n\n[axis.x]\ncs = 0\nkp = 20\nmax_move_s = 1\n')
    # 2000 counts at 1 count/sample: 2100 samples, 0.54 s; 8000: 2.07 s, above 1 s
    ok = run("--profile", str(profile), "--axis", "x", "move", "--relative", "2000")
    assert ok.exit_code == 0, ok.output
    r = run("--profile", str(profile), "--axis", "x", "move", "--relative", "8000")
    assert r.exit_code == 2 and "--max-duration 1 s" in r.output, r.output
