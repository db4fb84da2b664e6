"""Bench profiles on the persistent bench: one ``lm629 sim serve`` (restarted for a power cycle),
each ``lm629 --profile FILE ...`` a process of its own, the profile's port that server.

Numbers: the profile's travel is -20000..20000 counts, max_velocity 200000 counts/s (word
3355443 at 8 MHz: 51.2 counts/sample), following_error 2000 counts (armed as LPES when the
profile is applied).  A restarted server is a chip that powered up: filter 0, LPES not armed
(signals bit 9 clear), position 0.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest

import lm629_host
from served import FAR_ENDS, _env, serve
from served import _console_script

PROFILE = """\
# the X stage on bench 3: every comment here must survive tune --save
[board]
port = "serial://{link}"     # the sim serve of the test
chip = "lm629"
clock = "8MHz"

[axis.x]                     # the long axis
cs = 0
kp = 20                      # hand-tuned, to be replaced by tune --save
ki = 0
kd = 0                       # no damping yet
il = 0
ds = 1
min = -20000                 # end stop at -21000
max = 20000
max_velocity = 200000        # counts/s
max_acceleration = 4000000   # counts/s^2
following_error = 2000       # counts
"""


class ProfileBench:
    def __init__(self, profile: Path) -> None:
        self.profile = profile
        self.exe = _console_script()

    def run(self, *args: str, stdin: str | None = None,
            timeout: float = 60) -> subprocess.CompletedProcess:
        return subprocess.run([self.exe, "--profile", str(self.profile), *args],
                              capture_output=True, text=True, timeout=timeout, env=_env(),
                              input=stdin)

    def status(self) -> dict:
        p = self.run("--axis", "x", "status", "--json")
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout)


@pytest.fixture
def bench_profile(tmp_path) -> ProfileBench:
    path = tmp_path / "bench.toml"
    path.write_text(PROFILE.format(link=tmp_path / "bench"))
    return ProfileBench(path)


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


# the firmware behind an Uno's USB chip only: the same firmware without the USB chip in between
# proves nothing more here (no assertion on timing), and each far end costs a served bench
# (11-14 s each with -n 2 on a busy 2-core machine: two served benches, the second a power
# cycle, and a dozen processes that each import the package)
@pytest.mark.parametrize("far_end", [f for f in FAR_ENDS if f != "firmware"])
def test_profile_apply_limits_and_power_cycles(tmp_path, bench_profile, far_end):
    b = bench_profile
    with serve(tmp_path, far_end):
        p = b.run("profile", "apply")
        assert p.returncode == 0, p.stderr
        assert "axis x (cs 0): kp=20 ki=0 kd=0 il=0 ds=1, LPES 2000" in p.stdout
        p = b.run("--axis", "x", "move", "1000")
        assert p.returncode == 0, p.stderr
        assert p.stderr == ""  # applied already: nothing re-applied
        s = b.status()
        assert s["desired_position"] == 1000 and abs(1000 - s["real_position"]) <= 20
        assert "STOP_ON_ERROR" in s["signals_flags"]  # LPES armed by the profile
        # past min / max, above max_velocity: exit 2, one line naming the limit and the file,
        # and nothing moved
        for args, words in [(("move", "25000"), "above the soft limit max = 20000 counts"),
                            (("move", "-20001"), "below the soft limit min = -20000 counts"),
                            (("move", "5000", "--vel", "3355444"),
                             "above max_velocity = 200000 counts/s"),
                            (("velocity", "1000"), "velocity mode runs until it is stopped")]:
            p = b.run("--axis", "x", *args)
            assert p.returncode == 2, p.stdout + p.stderr
            assert p.stdout == ""
            err = _lines(p.stderr)
            assert len(err) == 1 and words in err[0] and str(b.profile) in err[0], err
        after = b.status()
        assert after["desired_position"] == 1000 and after["desired_velocity"] == 0
        assert after["real_position"] == s["real_position"]
        # the library: open_board(profile=...)["x"] refuses with no exchange at all
        with lm629_host.open_board(profile=b.profile) as board:
            stats = board.transport.stats
            before = (stats.programs, stats.round_trips, stats.bytes_out)
            with pytest.raises(ValueError, match=r"target 45000 is above the soft limit max"):
                board["x"].move_to(45000, velocity=65536, acceleration=655)
            assert (stats.programs, stats.round_trips, stats.bytes_out) == before
        # the shell: a piped script, the axis bound by its name
        p = b.run("shell", stdin="print(x.read_real_position())\n")
        assert p.returncode == 0, p.stderr
        assert p.stdout.strip() == str(s["real_position"])
    # a power cycle: a new server is a chip that has lost everything
    with serve(tmp_path, far_end):
        p = b.run("profile", "show")  # reads only: says so, applies nothing
        assert p.returncode == 0 and p.stderr == "", p.stderr
        assert "settings LOST (signals bit 9 clear" in p.stdout
        p = b.run("--axis", "x", "move", "1500")
        assert p.returncode == 0, p.stderr
        err = _lines(p.stderr)
        assert len(err) == 1 and err[0].startswith("lm629: axis x (cs 0) had lost its settings")
        assert "applied" in err[0] and "LPES 2000" in err[0]
        s = b.status()
        assert s["desired_position"] == 1500 and abs(1500 - s["real_position"]) <= 20
        assert "STOP_ON_ERROR" in s["signals_flags"]


# tune --save on the served bench (the gains written back with every comment kept, only the
# gain lines changed, LPES left armed, the saved gains applied after a power cycle) is asserted
# in the journey, tests/cli/test_journey.py, on both far ends: one served tune instead of two


def test_scope_reads_a_moving_axis_and_saves_the_window(tmp_path, bench_profile):
    b = bench_profile
    png = tmp_path / "scope.png"
    with serve(tmp_path, "python"):
        assert b.run("profile", "apply").returncode == 0
        # 15000 counts at 1 count/sample: 3.8 s, the scope's second inside it
        p = b.run("--axis", "x", "move", "15000", "--no-wait")
        assert p.returncode == 0, p.stderr
        p = b.run("scope", "--duration", "1", "--png", str(png), "--rate", "50")
        assert p.returncode == 0, p.stderr
        assert "following error, counts" in p.stdout and f"wrote {png}" in p.stdout
        # one axis on a bridge that records: 50 rows a second for one second, timed on the
        # bridge (a loaded host receives them late, never fewer), the last 49 x 20 ms after
        # the first
        assert "50 samples of 1 axis/axes in 0.98 s" in _lines(p.stderr), p.stderr
        # a PNG of the figure's 9 x 6 inches at 100 dpi: IHDR says 900 x 600 pixels
        head = png.read_bytes()[:24]
        assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
        assert (int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")) == (900, 600)
        s = b.status()
        assert "MOTOR_OFF" not in s["status_flags"]  # still moving or holding: untouched
        p = b.run("--axis", "x", "profile", "show")
        assert p.returncode == 0, p.stderr
        assert "settings applied (LPES armed)" in p.stdout
        assert "travel -20000..20000 counts" in p.stdout


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux not installed")
def test_scope_draws_live_in_a_terminal(tmp_path, bench_profile):
    """In a real terminal (tmux): the plot is redrawn in place and the last window stays."""
    b = bench_profile
    png = tmp_path / "scope.png"
    done = tmp_path / "done"
    name = f"lm629scope{time.monotonic_ns()}"
    with serve(tmp_path, "python"):
        cmd = (f"{b.exe} --profile {b.profile} scope --duration 1 --png {png}; "
               f"echo rc=$? > {done}; sleep 30")
        subprocess.run(["tmux", "new-session", "-d", "-s", name, "-x", "100", "-y", "30", cmd],
                       check=True, env=_env())
        try:
            deadline = time.monotonic() + 30
            while not done.exists() and time.monotonic() < deadline:
                time.sleep(0.2)
            assert done.read_text().strip() == "rc=0"
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", name],
                                    capture_output=True, text=True, check=True).stdout
        finally:
            subprocess.run(["tmux", "kill-session", "-t", name], capture_output=True)
    assert "desired / actual" in screen and "following error, counts" in screen
    assert f"wrote {png}" in screen and png.exists()
