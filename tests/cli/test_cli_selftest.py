"""``lm629 selftest`` from the command line: the verdict, its exit code, --report and
--compare; and on a served bench whose crystal is not the profile's (6 MHz chip, 8 MHz
profile: 6e6 / 2048 = 2929.7 samples/s where 3906.25 were expected)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from lm629_host import cli
from lm629_host.bench.selftest import validate
from served import _console_script, _env, serve


def _run(*args: str, stdin: str | None = None):
    return CliRunner().invoke(cli.main, list(args), env={"LM629_PORT": ""}, input=stdin,
                              catch_exceptions=False)


def test_passes_on_the_simulator_and_writes_a_report(tmp_path):
    path = tmp_path / "bench.json"
    r = _run("--port", "sim://", "selftest", "--report", str(path))
    assert r.exit_code == 0, r.output
    assert "verdict: PASS\n" in r.output
    assert "[ok] core" in r.output and "measured 8.00" in r.output
    assert validate(json.loads(path.read_text())) == []
    assert (tmp_path / "bench.md").read_text().startswith("## lm629 selftest: PASS")
    c = _run("selftest", "--compare", str(path))
    assert c.exit_code == 0 and c.output.rstrip().endswith("no differences")


def test_compare_names_a_hand_edited_value(tmp_path):
    path = tmp_path / "bench.json"
    assert _run("--port", "sim://", "selftest", "--report", str(path)).exit_code == 0
    data = json.loads(path.read_text())
    m = next(m for m in data["measurements"] if m["name"] == "velocity past the breakpoint: RDDV")
    m["measured"] = 0x2000
    path.write_text(json.dumps(data))
    c = _run("selftest", "--compare", str(path))
    assert c.exit_code == 1
    assert ("velocity past the breakpoint: RDDV: the chip read 2000, today's model gives 1000"
            in c.output)


def test_compare_of_a_file_that_is_no_report_is_bad_usage(tmp_path):
    path = tmp_path / "x.json"
    path.write_text('{"schema": 1}')
    r = CliRunner().invoke(cli.main, ["selftest", "--compare", str(path)])
    assert r.exit_code == 2 and "not a selftest report: missing key" in r.output


def test_hi_not_wired_names_the_line(tmp_path):
    r = _run("--port", "sim+emu://?wiring=hi-open", "selftest")
    assert r.exit_code == 1
    assert "HI: HI (pin 17) stayed low" in r.output and "verdict: DIFFERS" in r.output


def test_motion_asks_first_and_moves_nothing_on_no():
    """A prompt answered no is the table's 130 (cli.EXIT_CODES), not 1 (a check's verdict)."""
    r = _run("--port", "sim://?record=1", "selftest", "--motion", stdin="n\n")
    assert r.exit_code == 130 and "nothing moved" in r.output
    assert "a prompt before the motor turns answered no" in cli.EXIT_CODES[130]


def test_a_selftest_that_cannot_finish_exits_with_its_own_code():
    """FAIL (a chip that never leaves reset) is 10, its own row of the table, not 2 (bad
    usage) nor 5 (the reset failure of a command that stops there: the selftest reports)."""
    r = _run("--port", "sim://?fault=reset", "selftest")
    assert r.exit_code == 10 and "verdict: FAIL" in r.output, r.output
    assert cli.EXIT_CODES[10].startswith("selftest FAIL")


PROFILE_XY = """\
[board]
chip = "lm629"
clock = "8MHz"

[axis.x]
cs = 0
kp = 20

[axis.y]
cs = 1
kp = 30
"""


def test_a_profiles_several_axes_are_each_tested(tmp_path: Path):
    """A profile with axes x and y: both tested, in turn, each with its own report
    (bench-x.json, bench-y.json); exit the worst verdict.  --axis y: y alone."""
    profile = tmp_path / "bench.toml"
    profile.write_text(PROFILE_XY)
    path = tmp_path / "bench.json"
    r = _run("--port", "sim://?axes=2", "--profile", str(profile), "selftest", "--report",
             str(path))
    assert r.exit_code == 0, r.output
    assert "selftest of axis x (cs 0)" in r.output and "selftest of axis y (cs 1)" in r.output
    assert r.output.count("verdict: PASS") == 2
    for name, cs in (("x", 0), ("y", 1)):
        data = json.loads((tmp_path / f"bench-{name}.json").read_text())
        assert validate(data) == [] and data["profile"]["cs"] == cs
    one = _run("--port", "sim://?axes=2", "--profile", str(profile), "--axis", "y", "selftest")
    assert one.exit_code == 0 and "axis y (cs 1)" in one.output and "axis x" not in one.output
    # chips that never leave reset: a FAIL on each axis, and the exit code of the whole
    bad = _run("--port", "sim://?axes=2&fault=reset", "--profile", str(profile), "selftest")
    assert bad.exit_code == 10 and bad.output.count("verdict: FAIL") == 2


def test_no_index_with_motion_names_the_index():
    r = _run("--port", "sim://?wiring=index-open", "selftest", "--motion", "--yes")
    assert r.exit_code == 1
    assert "index: no index pulse" in r.output and "pin 1 (IN)" in r.output


PROFILE = """\
[board]
chip = "lm629"
clock = "8MHz"

[axis.x]
cs = 0
kp = 20
"""


@pytest.mark.slow
def test_a_served_6mhz_bench_with_an_8mhz_profile_names_the_measured_clock(tmp_path: Path):
    import subprocess
    profile = tmp_path / "bench.toml"
    profile.write_text(PROFILE)
    with serve(tmp_path, "python", url="sim://?clock=6MHz") as bench:
        p = subprocess.run([_console_script(), "--port", f"serial://{bench.link}", "--profile",
                            str(profile), "selftest"], capture_output=True, text=True,
                           timeout=120, env=_env())
    assert p.returncode == 1, p.stdout + p.stderr
    assert "clock: the chip's clock measures 6.00 MHz" in p.stdout
    assert "the profile says 8 MHz" in p.stdout and "verdict: DIFFERS" in p.stdout


@pytest.mark.slow
def test_a_served_bench_parked_on_its_index_passes_and_compares_clean(tmp_path: Path):
    """The issue's bench: `lm629 sim serve`, `filter --kp 3415 --kd 26219`, `move 1000` (the
    default encoder's index is 2 x 500 counts from power-up: the shaft rests on it), then
    `selftest --report`, each a process of its own: PASS (it was DIFFERS, "home: status: chip
    000C, model 0004 after DFH"), and the report compares clean."""
    import subprocess
    report = tmp_path / "r.json"
    with serve(tmp_path, "python") as bench:
        for args in (("filter", "--kp", "3415", "--kd", "26219"), ("move", "1000"),
                     ("selftest", "--report", str(report))):
            p = subprocess.run(bench.argv(*args), capture_output=True, text=True,
                               timeout=120, env=_env())
            assert p.returncode == 0, (args, p.stdout + p.stderr)
    assert "[--] index    the shaft rests on the index" in p.stdout
    assert "verdict: PASS" in p.stdout
    c = _run("selftest", "--compare", str(report))
    assert c.exit_code == 0 and c.output.rstrip().endswith("no differences"), c.output
