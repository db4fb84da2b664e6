"""A new user's first hour, as the docs tell it, on one persistent two-axis ``lm629 sim serve``
with every step a process of its own: profile init -> an edit (names, soft limits, caps) ->
profile apply -> bringup -> wiring --check -> tune --save -> a power cycle (SIGUSR1 to the
server) -> move by name -> status and watch by name -> scope --png -> a piped shell script ->
the user's own pytest file with --lm629-profile.  Each feature has its own tests; this one
holds the seams between them.  The Python far end, and the firmware behind an Uno's USB chip.

Numbers: the edited profile's axis ``table`` (cs 0) has min = -3000, max = 6000 counts; the
bring-up's test move is 1000 counts from 0 (inside), the tuner's band +/-2000 around 0
(inside).  After the power cycle the chip reads kp = 0 with LPES disarmed (signals bit 9
clear), so the next command says it applied the profile again before it moves.
"""

from __future__ import annotations

import difflib
import json
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from lm629_host.config.profile import load_profile
from served import _env, serve
from served import _console_script

PROFILE_EDIT = {
    "[axis.x]": "[axis.table]",
    "[axis.y]": "[axis.lift]",
    "# min = -20000 ": "min = -3000 ",
    "# max = 20000": "max = 6000",
    "# max_velocity = 200000 ": "max_velocity = 400000 ",
    "# max_acceleration = 4000000": "max_acceleration = 8000000",
}

USER_TEST = textwrap.dedent("""\
    import pytest

    @pytest.mark.lm629_motion
    def test_the_table_moves_by_name_inside_its_limits(lm629_board):
        table = lm629_board["table"]  # the fixture applied the profile: the tuned gains
        assert abs(table.move_to(500, velocity=4 * 65536, acceleration=3277).wait().error) <= 20
        with pytest.raises(ValueError, match="soft limit max = 6000"):
            table.move_to(7000, velocity=65536)
    """)


# each journey takes 15-20 s on an idle machine: a dozen CLI processes (each imports the
# package) on a bench in real time, a tune among them; the two far ends run on separate
# workers (one xdist group per parameter, tests/selection.py)
@pytest.fixture(scope="module", params=["python", "firmware+uno"])
def bench(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("journey")
    with serve(tmp, request.param, "sim://?axes=2") as b:
        yield b, tmp


def _run(tmp: Path, *args: str, stdin: str | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    env = _env()
    env.pop("LM629_SIM_STRICT", None)
    return subprocess.run([_console_script(), "--profile", str(tmp / "bench.toml"), *args],
                          capture_output=True, text=True, timeout=timeout, env=env, cwd=tmp,
                          input=stdin)


def _ok(p: subprocess.CompletedProcess) -> str:
    assert p.returncode == 0, f"{p.args}: exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    assert "Traceback" not in p.stderr, p.stderr
    return p.stdout


# over 10 s on an idle machine: a dozen `lm629` processes in a row (profile, bringup, wiring,
# tune, moves by name, scope) against one served bench in real time, the firmware behind an
# Uno's USB in one parameter: the crossings of the features, as a user makes them, are the subject
def test_a_new_users_first_hour(bench):
    b, tmp = bench
    port = f"serial://{b.link}"
    # profile init, from the served board's two axes
    _ok(_run(tmp, "--port", port, "--axis", "0,1", "profile", "init"))
    text = (tmp / "bench.toml").read_text()
    for old, new in PROFILE_EDIT.items():
        assert old in text, old
        text = text.replace(old, new, 1)
    (tmp / "bench.toml").write_text(text)
    out = _ok(_run(tmp, "profile", "apply"))
    assert "table" in out and "lift" in out and "axis 0" not in out
    _ok(_run(tmp, "--axis", "table", "bringup", "--yes"))
    _ok(_run(tmp, "--axis", "table", "wiring", "--check"))
    # tune --save: the gains written into [axis.table], every comment and the edit kept, only
    # the gain lines changed (the one served tune of the CLI tests: the profile's own seams
    # are asserted here rather than in a second served tune, tests/cli/test_served_bench_profile.py)
    before = (tmp / "bench.toml").read_text()
    tune = _run(tmp, "--axis", "table", "tune", "--travel", "2000", "--yes", "--save")
    _ok(tune)
    m = re.search(r"saved kp=(\d+) ki=(\d+) kd=(\d+) il=(\d+) ds=(\d+) into \[axis\.table\]",
                  tune.stdout)
    assert m, tune.stdout
    kp, ki, kd, il, ds = map(int, m.groups())
    assert f"gains: kp={kp} ki={ki} kd={kd} il={il} ds={ds - 1}" not in tune.stdout  # ds: samples
    text = (tmp / "bench.toml").read_text()
    for line in before.splitlines():
        if "#" in line:
            assert line[line.index("#"):] in text, line
    # the lines that went (the plant's table is added beside the gains: docs/twin.md)
    changed = {a[1:].split("=")[0].strip() for a in difflib.ndiff(before.splitlines(),
                                                                  text.splitlines())
               if a.startswith("- ")}
    assert changed <= {"kp", "ki", "kd", "il", "ds"} and {"kp", "kd"} <= changed, changed
    table = load_profile(tmp / "bench.toml").axis("table")
    assert (table.kp, table.ki, table.kd, table.il, table.ds) == (kp, ki, kd, il, ds)
    assert (table.kp, table.kd) != (20, 0) and table.max == 6000  # the tuned gains, the edit kept
    # tuning left the profile's LPES armed: the next command applies nothing again
    after = _run(tmp, "--axis", "table", "status")
    assert _ok(after) and after.stderr == "" and "STOP_ON_ERROR" in after.stdout, after.stderr

    b.server.send_signal(signal.SIGUSR1)  # the board's supply off and on: the chips forget
    first = _run(tmp, "--axis", "table", "status", "--json")  # the first command after it
    status = json.loads(_ok(first))
    assert "axis table (cs 0) had lost its settings" in first.stderr
    assert f"kp={kp} ki={ki} kd={kd} il={il} ds={ds}, LPES" in first.stderr  # the saved gains
    assert "STOP_ON_ERROR" in status["signals_flags"]
    assert status["real_position"] == 0  # power-on: the counters start again
    moved = _run(tmp, "--axis", "table", "move", "1500")
    _ok(moved)
    assert "done: at" in moved.stdout
    out = _ok(_run(tmp, "--axis", "table", "status"))
    assert "table" in out
    watch = _ok(_run(tmp, "watch", "--count", "3", "--rate", "20"))
    assert "table" in watch and "lift" in watch
    _ok(_run(tmp, "--axis", "table", "scope", "--duration", "0.5", "--png", "scope.png"))
    assert (tmp / "scope.png").stat().st_size > 1000
    script = "print(table.read_real_position(), sorted(k for k in dir() if k[0] != '_'))\n"
    shell = _run(tmp, "shell", stdin=script)
    assert shell.returncode == 0, shell.stderr
    assert re.fullmatch(r"-?\d+ \['Signals', 'Status', 'board', 'chip', 'lift', 'lm629_host', "
                        r"'table'\]\n", shell.stdout), shell.stdout
    (tmp / "test_my_rig.py").write_text(USER_TEST)
    env = _env()
    env.pop("LM629_SIM_STRICT", None)
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "--lm629-profile", str(tmp / "bench.toml"), "--lm629-allow-motion",
                        "test_my_rig.py"], capture_output=True, text=True, cwd=tmp, env=env,
                       timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr
