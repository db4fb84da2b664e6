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
    r = _run("--port", "sim://?record=1", "selftest", "--motion", stdin="n\n")
    assert r.exit_code == 1 and "nothing moved" in r.output


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
