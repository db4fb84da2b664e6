"""``lm629 --profile bench.toml panel`` with two named axes, as docs/panel.md shows it: the
page's forms on the second axis speak that axis's units, as ``lm629 --profile bench.toml
--axis y ...`` does, and a refused step leaves the axis as it was.

The numbers: axis y has ``lines = 500``, 4 x 500 = 2000 counts a revolution (docs/profile.md:
"the CLI speaks revolutions and rpm"), so a 0.1-revolution step is 200 counts and a move to 2
revolutions ends at 4000 counts; axis x has no lines and speaks counts.  y's soft limit is
max = 20000 counts (10 revolutions).  Only y has a plant (what `tune --save` keeps): its
step's prediction is the twin's, x's the simulated motor's numbers (sim:// builds each chip's
motor from its axis's plant), each within 3 counts of the measured response
(test_panel_api.py's twin test says why 3).  During an S-curve (the host times its pieces, 20 ms
apart) the plots go on at the panel's 50 rows a second, read between the move's programs."""

from __future__ import annotations

import subprocess
import time

import pytest

from lm629_host.panel.bench import SAMPLE_HZ
from panel_helpers import command, events, panel_on_profile
from served import _console_script, _env

PROFILE = """\
[board]
port = "sim://?axes=2"

[axis.x]
cs = 0
kp = 20
ds = 1

[axis.y]
cs = 1
lines = 500
kp = 30
ki = 5
il = 2000
ds = 1
min = -20000
max = 20000

[axis.y.plant]
accel = 595730
tau = 0.2676
dry = 0.0086
"""

MOTOR_OFF = 0x80


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    with panel_on_profile(tmp_path_factory.mktemp("panel-profile"), PROFILE) as bench:
        yield bench


def _cli(path, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([_console_script(), "--profile", str(path), *argv],
                          capture_output=True, text=True, timeout=60, env=_env())


def _rows(stream, seconds: float) -> list:
    end = time.monotonic() + seconds
    rows: list = []
    for m in stream:
        if m["type"] == "rows":
            rows += m["rows"]
        if time.monotonic() > end and rows:
            return rows
    raise AssertionError("the event stream ended")


def test_the_second_axis_speaks_its_own_lines(bench):
    p, token, path = bench
    cli = _cli(path, "--axis", "y", "step", "0.1", "--time", "0.3", "--no-png",
               "--csv", str(path.parent / "step.csv"))
    assert cli.returncode == 0, cli.stderr
    assert cli.stdout.startswith("target 200 counts")
    with events(p, token) as stream:
        client = next(stream)["client"]
        status, step = command(p, token, {"cmd": "step", "axis": "y", "distance": "0.1",
                                          "time": "0.3", "client": client})
        assert step["ok"], step
        # the command line's lines, in the same units (the response's own counts may differ
        # by one: the rows' 1 ms grid meets the chip's samples at another phase)
        lines = step["text"].splitlines()
        assert lines[0] == cli.stdout.splitlines()[0] == "target 200 counts, 301 samples over 300.0 ms"
        assert lines[-1].startswith("in revolutions: target 0.1000, largest following error "
                                    "+0.1000, overshoot ")
        d = step["data"]
        assert d["desired"][-1] == 200  # the plotted step, in counts
        assert d["basis"] == "the twin: [axis.y.plant]"
        assert max(abs(m - q) for m, q in zip(d["actual"], d["predicted"])) <= 3
        status, move = command(p, token, {"cmd": "move", "axis": "y", "target": "2",
                                          "shape": "s-curve", "jerk": "300", "client": client})
        assert move["ok"], move
        assert move["text"].startswith("moving to 4000 counts (2.0000 rev) along an S-curve")
        rows = _rows(stream, 0.2)
        assert rows[-1][7] == 4000  # y's desired position (columns 7-12), counts
        # plotted during the S-curve (rows read between its programs) at the panel's rate
        during = [r[0] for r in rows if 200 < r[7] < 4000]
        rate = (len(during) - 1) / (during[-1] - during[0])
        assert 0.8 * SAMPLE_HZ <= rate <= 1.2 * SAMPLE_HZ, rate
        # axis x (no lines) speaks counts, as `--axis x` does
        status, step = command(p, token, {"cmd": "step", "axis": "x", "distance": "200",
                                          "time": "0.3", "client": client})
        assert step["ok"] and step["text"].startswith("target 200 counts"), step
        assert "in revolutions" not in step["text"]
        d = step["data"]
        assert d["basis"] == "the simulated motor's numbers"
        assert max(abs(m - q) for m, q in zip(d["actual"], d["predicted"])) <= 3


def test_a_step_past_the_soft_limit_leaves_the_axis_holding(bench):
    """10.5 revolutions from about 4000 counts is past max = 20000: refused with the command
    line's line and exit code, before anything is sent: the axis still holds (motor on)."""
    p, token, path = bench
    cli = _cli(path, "--axis", "y", "step", "10.5", "--no-png",
               "--csv", str(path.parent / "step.csv"))
    assert cli.returncode == 2
    line = cli.stderr.strip().splitlines()[-1]
    assert line.startswith("lm629: bad value: target 21000 is above the soft limit max = 20000")
    assert "motor stopped" not in line  # nothing was sent, nothing to stop
    with events(p, token) as stream:
        client = next(stream)["client"]
        before = _rows(stream, 0.1)[-1]
        assert not before[11] & MOTOR_OFF
        status, step = command(p, token, {"cmd": "step", "axis": "y", "distance": "10.5",
                                          "client": client})
        assert (step["ok"], step["code"]) == (False, 2)
        assert step["text"].startswith("bad value: target "), step
        assert "above the soft limit max = 20000" in step["text"]
        assert "motor stopped" not in step["text"]
        after = _rows(stream, 0.2)[-1]
        assert not after[11] & MOTOR_OFF  # still holding, motor on
        assert after[7] == before[7]  # the desired position where it was
