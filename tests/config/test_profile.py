"""Bench profiles (lm629_host.config.profile) and soft limits (lm629_host.physics.limits), in one process on
the in-process simulator: the checks of a profile, the limit words, the library's one check
point, the lost-settings signature, writing the gains back with the comments kept.

Numbers: at 8 MHz a sample is 2048 / 8e6 = 256 us, so 200000 counts/s is 51.2 counts/sample,
the velocity word 51.2 x 65536 = 3355443.2 -> 3355443; 4e6 counts/s^2 is 4e6 x 256e-6^2 =
0.262144 counts/sample^2, the word 0.262144 x 65536 = 17179.87 -> 17179.
"""

from __future__ import annotations

import dataclasses
import textwrap

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host.cli import main
from lm629_host.physics.limits import SoftLimits
from lm629_host.bus.opcodes import Signals
from lm629_host.config.profile import (
    ProfileError,
    ensure_applied,
    load_profile,
    parse_profile,
    save_gains,
    settings_lost,
    template,
)
from lm629_host.transports.ports import profile_port

GOOD = textwrap.dedent("""\
    # the X-Y stage on bench 3
    [board]
    port = "sim://"              # any port URL
    chip = "lm629"
    clock = "8MHz"

    [axis.x]                     # the long axis
    cs = 0
    kp = 20                      # hand-tuned
    kd = 0
    ds = 1
    min = -20000                 # end stop at -21000
    max = 20000
    max_velocity = 200000        # counts/s
    max_acceleration = 4000000   # counts/s^2
    following_error = 2000
    note = "belt drive"

    [axis.y]
    cs = 1
    kp = 30
    """)


#: GOOD with every gain of [axis.x] non-zero and unlike the others (kp 20, ki 4, kd 800, il
#: 500): none is the reset value 0, so a gain dropped on its way to the chip shows there
GAINED = GOOD.replace("kd = 0\n", "ki = 4\nkd = 800\nil = 500\n")


def _write(tmp_path, text: str = GOOD, name: str = "bench.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_good_profile_reads_back_every_key(tmp_path):
    prof = load_profile(_write(tmp_path))
    x, y = prof.axis("x"), prof.axis("y")
    assert (prof.port, prof.chip, prof.clock_hz) == ("sim://", "lm629", 8e6)
    assert (x.cs, x.kp, x.kd, x.ds, x.min, x.max, x.following_error, x.note) == (
        0, 20, 0, 1, -20000, 20000, 2000, "belt drive")
    assert (y.cs, y.kp, y.ds, y.min, y.threshold) == (1, 30, 1, None, 0x7FFF)
    assert x.key_lines["max"] == 13 and x.key_lines["kp"] == 9
    # the URL opened: the simulator gets the chip, clock and a chip per chip select, and the
    # profile, whose axes' plants it builds the motors from (a twin: tests/test_twin.py)
    assert profile_port(prof).text == f"sim://?chip=lm629&clock=8000000&axes=2&profile={prof.path}"


@pytest.mark.parametrize("edit, line, words", [
    (("kd = 0", "kd = 0\nkq = 3"), 11, "[axis.x] kq: unknown key"),
    (("kp = 20 ", "kp = \"20\" "), 9, "[axis.x] kp: '20' must be a whole number"),
    (("max = 20000", "max = 20000.5"), 13, "[axis.x] max: 20000.5 must be a whole number"),
    (("min = -20000", "min = 30000"), 12, "[axis.x] min: 30000 is above max = 20000"),
    (("cs = 1", "cs = 0"), 20, "[axis.y] cs: 0 is also the chip select of [axis.x]"),
    (("kp = 30", "kp = 40000"), 21, "[axis.y] kp: 40000 is outside 0..32767"),
    (("ds = 1", "ds = 0"), 11, "[axis.x] ds: 0 is outside 1..256"),
    (("following_error = 2000", "following_error = -1"), 16,
     "[axis.x] following_error: -1 is outside 0..32767"),
    (("chip = \"lm629\"", "chip = \"lm630\""), 4, "[board] chip: 'lm630' must be one of"),
    (("clock = \"8MHz\"", "clock = \"12MHz\""), 5, "[board] clock: '12MHz' is outside"),
    (("[axis.y]\ncs = 1\n", "[axis.y]\n"), 19, "[axis.y]: has no cs"),
    (("[board]", "[boards]"), 2, "[boards]: unknown table"),
    (("note = \"belt drive\"", "note = \"belt drive"), 17, "not TOML"),
    # a value nested 5000 deep (tomllib: a RecursionError), an array left open at the end, a
    # table declared twice (tomlkit would place it at the table's end), a TOML 1.1 escape
    # (tomlkit takes it, tomllib does not): each placed where tomllib stops taking the text
    (("kd = 0", "kd = 0\nstop = " + "[" * 5000), 11, "not TOML: a value nested too deep"),
    (("kp = 30", "kp = [30,"), 21, "not TOML"),
    (("[axis.y]", "[axis.x]"), 19, "not TOML"),
    (("note = \"belt drive\"", "note = \"belt\\edrive\""), 17, "not TOML"),
    # a valid multi-line string does not hide an error after it
    (("note = \"belt drive\"", 'note = """belt\n\ndrive"""\nkq = =1'), 20, "not TOML"),
    # tables made by a key, not a header: the key's line
    (("[axis.y]\ncs = 1\nkp = 30\n", "[axis]\ny = 1\n"), 20, "[axis.y]: must be a table"),
    (("kd = 0", "kd = 0\nlimits.min = 1"), 11, "[axis.x] limits: unknown key"),
])
def test_a_bad_profile_is_one_line_naming_the_file_the_line_and_the_key(tmp_path, edit, line,
                                                                           words):
    old, new = edit
    assert old in GOOD
    p = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(ProfileError) as err:
        load_profile(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}:{line}: "), msg
    assert words in msg and "\n" not in msg


def test_limit_words_at_the_chips_clock():
    lim = SoftLimits(-20000, 20000, 200000, 4e6, 8e6)
    assert lim.velocity_word == 3355443
    assert lim.acceleration_word == 17179
    lim.check_velocity(3355443)
    with pytest.raises(ValueError, match="max_velocity = 200000 counts/s"):
        lim.check_velocity(3355444)
    with pytest.raises(ValueError, match="max_acceleration"):
        lim.check_acceleration(17180)
    # at 6 MHz a sample is longer, 2048 / 6e6 = 341.33 us: 200000 counts/s are 68.267
    # counts/sample, the word 68.267 x 65536 = 4473924.27 -> 4473924
    assert SoftLimits(max_velocity=200000, clock_hz=6e6).velocity_word == 4473924


@pytest.mark.parametrize("target, refused", [
    (-20001, "target -20001 is below the soft limit min = -20000 counts"),
    (-20000, None), (20000, None),
    (20001, "target 20001 is above the soft limit max = 20000 counts"),
])
def test_travel_limits_hold_at_exactly_min_and_max_and_refuse_one_count_past(target, refused):
    """min and max are the last counts allowed: the limit itself is inside, one count past
    it is refused, on either side."""
    lim = SoftLimits(-20000, 20000, where="bench.toml", table="axis.x",
                     lines=(("min", 12), ("max", 13)))
    if refused is None:
        lim.check_position(target)
        lim.check_trajectory(None, None, target)
        return
    key, line = ("min", 12) if target < 0 else ("max", 13)
    for call in (lambda: lim.check_position(target),
                 lambda: lim.check_trajectory(None, None, target)):
        with pytest.raises(ValueError) as err:
            call()
        assert str(err.value) == f"{refused} (bench.toml:{line}: [axis.x] {key})"


@pytest.mark.parametrize("target, inside", [(-20001, False), (-20000, True), (20000, True),
                                            (20001, False)])
def test_a_profiles_axis_moves_to_its_limits_and_not_one_count_past(tmp_path, target, inside):
    """The same boundaries through open_board(profile=...): a move to the limit runs, one
    count past it is refused before any exchange."""
    with lm629_host.open_board(profile=_write(tmp_path, GAINED)) as board:
        x = board["x"]
        x.define_home()
        stats = x.transport.stats
        before = (stats.programs, stats.bus_cycles)
        if not inside:
            with pytest.raises(ValueError, match=f"target {target} is (above|below)"):
                x.move_to(target, velocity=3355443, acceleration=17179)
            assert (stats.programs, stats.bus_cycles) == before
            return
        r = x.move_to(target, velocity=8 * 65536, acceleration=6553).wait()
        assert abs(r.position - target) <= 20


def test_open_board_with_a_profile_refuses_a_move_outside_before_any_exchange(tmp_path):
    """Each refusal ends naming the line of the limit it hit in GOOD: min on 12, max on 13,
    max_velocity on 14, max_acceleration on 15."""
    path = _write(tmp_path)
    with lm629_host.open_board(profile=path) as board:
        x = board["x"]
        assert x is board.axes[0] and board["y"] is board.axes[1]
        stats = x.transport.stats
        before = (stats.programs, stats.bus_cycles)
        for call, words, where in [
            (lambda: x.move_to(45000, velocity=65536, acceleration=655),
             "target 45000 is above the soft limit max = 20000 counts", "13: [axis.x] max"),
            (lambda: x.move_to(-20001, velocity=65536),
             "target -20001 is below the soft limit min = -20000", "12: [axis.x] min"),
            (lambda: x.move_to(1000, velocity=3355444, acceleration=655),
             "velocity word 3355444 is 200000 counts/s, above max_velocity = 200000 counts/s "
             "(word 3355443)", "14: [axis.x] max_velocity"),
            (lambda: x.move_to(1000, velocity=65536, acceleration=17180),
             "above max_acceleration = 4e+06 counts/s^2 (word 17179)",
             "15: [axis.x] max_acceleration"),
            (lambda: x.load_trajectory(velocity=100, velocity_mode=True, start=True),
             "velocity mode runs until it is stopped", "12: [axis.x] min"),
            (lambda: x.load_trajectory(position=10, position_relative=True, start=True),
             "a relative position cannot be checked", "12: [axis.x] min"),
            (lambda: board.move({x: 30000}, velocity=65536, acceleration=655), "max = 20000",
             "13: [axis.x] max"),
            (lambda: board.move_linear({0: 25000}, velocity=65536, acceleration=655),
             "max = 20000", "13: [axis.x] max"),
        ]:
            with pytest.raises(ValueError) as err:
                call()
            assert words in str(err.value)
            assert str(err.value).endswith(f" ({path}:{where})"), str(err.value)
        assert (stats.programs, stats.bus_cycles) == before  # not one exchange
        # inside the limits it moves, and a stop is never refused
        r = x.move_to(1000, velocity=65536, acceleration=655).wait()
        assert abs(r.position - 1000) <= 20
        x.load_trajectory(stop="abrupt", start=True)
        # axis y has no limits: anything the chip takes
        board["y"].trajectory_program(acceleration=655, velocity=100, velocity_mode=True)
        with pytest.raises(KeyError, match="'z'"):
            board["z"]


def _working_filter(chip) -> tuple[int, int, int, int, int]:
    """The filter the chip's model runs: kp, ki, kd, il, ds (a sample later, when a UDF
    just sent has taken effect)."""
    chip.clock.sleep(1e-3)
    f = chip.transport.models[chip.chip_select].filter
    return (f.kp, f.ki, f.kd, f.il, f.ds)


def test_the_profile_is_applied_and_a_reset_reads_as_lost(tmp_path):
    """Every gain of [axis.x] (kp 20, ki 4, kd 800, il 500: none the reset value 0) is in the
    chip's working filter after open and again after a reset; a reset clears them all."""
    prof = load_profile(_write(tmp_path, GAINED))
    with lm629_host.open_board(profile=prof) as board:
        x = board["x"]
        sig = x.read_signals()
        assert sig & Signals.STOP_ON_ERROR  # applied at open: LPES armed
        assert _working_filter(x) == (20, 4, 800, 500, 1)
        assert settings_lost(x) is None
        said: list[str] = []
        assert ensure_applied({"x": x}, prof, said.append) == [] and said == []
        board.reset()  # as after a power cycle: LPES's bit cleared with everything else
        assert settings_lost(x) is not None
        assert _working_filter(x) == (0, 0, 0, 0, 1)
        assert ensure_applied({"x": x, "y": board["y"]}, prof, said.append) == ["x", "y"]
        assert len(said) == 2 and "axis x (cs 0) had lost its settings" in said[0]
        assert "LPES 2000" in said[0] and "kp=20 ki=4 kd=800 il=500 ds=1" in said[0]
        assert settings_lost(x) is None
        assert _working_filter(x) == (20, 4, 800, 500, 1)
        assert _working_filter(board["y"]) == (30, 0, 0, 0, 1)
        x.load_position_error(100)  # LPEI by another program: reads as lost too
        assert settings_lost(x) is not None


def test_save_gains_keeps_the_comments_and_everything_else(tmp_path):
    p = _write(tmp_path)
    save_gains(p, "x", {"kp": 231, "ki": 0, "kd": 773, "il": 0, "ds": 8})
    text = p.read_text()
    old = GOOD.splitlines()
    new = [ln for ln in text.splitlines() if ln not in ("ki = 0", "il = 0")]
    changed = [(a, b) for a, b in zip(old, new) if a != b]
    assert changed == [("kp = 20                      # hand-tuned",
                        "kp = 231                     # hand-tuned"),
                       ("kd = 0", "kd = 773"), ("ds = 1", "ds = 8")]
    assert "ki = 0" in text and "il = 0" in text  # keys the table lacked, added to it
    x = load_profile(p).axis("x")
    assert (x.kp, x.ki, x.kd, x.il, x.ds) == (231, 0, 773, 0, 8)
    assert load_profile(p).axis("y").kp == 30
    with pytest.raises(ValueError, match="no axis 'w'"):
        save_gains(p, "w", {"kp": 1})
    with pytest.raises(ProfileError, match="kp: 40000 is outside"):
        save_gains(p, "x", {"kp": 40000})
    assert load_profile(p).axis("x").kp == 231  # a refused write left the file as it was


def test_the_template_is_a_profile():
    prof = parse_profile(template(port="serial:///dev/ttyACM0", lines=500, axes=(0, 1)))
    assert list(prof.axes) == ["x", "y"] and prof.axis("y").cs == 1
    assert prof.axis("x").lines == 500 and prof.axis("x").following_error == 2000


def test_cli_bad_profile_and_unknown_axis_exit_2_in_one_line(tmp_path):
    runner = CliRunner()
    bad = _write(tmp_path, GOOD.replace("kp = 30", "kp = 40000"), "bad.toml")
    r = runner.invoke(main, ["--profile", str(bad), "status"])
    assert r.exit_code == 2
    assert r.stderr.strip().splitlines() == [
        f"lm629: bad value: {bad}:21: [axis.y] kp: 40000 is outside 0..32767"]
    good = _write(tmp_path)
    r = runner.invoke(main, ["--profile", str(good), "--axis", "w", "status"])
    assert r.exit_code == 2 and "'w' is no axis of" in r.stderr
    r = runner.invoke(main, ["--profile", str(good), "--axis", "x", "move", "25000"])
    assert r.exit_code == 2 and r.stdout == ""
    assert r.stderr.strip() == (f"lm629: bad value: target 25000 is above the soft limit max = "
                                f"20000 counts ({good}:13: [axis.x] max)")


def test_cli_a_profile_nested_too_deep_is_one_line_and_exit_2(tmp_path):
    deep = _write(tmp_path, "a = " + "[" * 5000 + "\n", "deep.toml")
    r = CliRunner().invoke(main, ["--profile", str(deep), "status"])
    assert r.exit_code == 2
    assert r.stderr.strip().splitlines() == [
        f"lm629: bad value: {deep}:1: not TOML: a value nested too deep (arrays or inline tables)"]


def test_cli_profile_init_writes_a_template_from_the_options(tmp_path):
    runner = CliRunner()
    path = tmp_path / "new.toml"
    r = runner.invoke(main, ["--port", "sim://", "--lines", "500", "--axis", "0,1",
                             "--profile", str(path), "profile", "init"])
    assert r.exit_code == 0, r.output
    prof = load_profile(path)
    assert prof.port == "sim://" and list(prof.axes) == ["x", "y"]
    assert prof.axis("x").lines == 500
    r = runner.invoke(main, ["--profile", str(path), "profile", "init"])
    assert r.exit_code == 2 and "exists (--force" in r.stderr


CAPPED = textwrap.dedent("""\
    [board]
    port = "sim://"
    [axis.x]
    cs = 0
    kp = 20
    min = -20000
    max = 20000
    max_velocity = 200000        # word 3355443: 51.2 counts/sample
    max_acceleration = 4000000   # word 17179: 0.262 counts/sample^2
    following_error = 2000
    """)


def test_tuning_on_a_capped_axis_ramps_within_the_caps_and_predicts_the_ramp(tmp_path):
    """The tuner's steps are the fastest trapezoid the caps allow (a step's words would be
    refused); the fit and the design follow that trapezoid, so the model fits the
    identification as well as a step's (within 2 counts rms) and the prediction matches the
    measured test move."""
    from lm629_host.bench.tuning import autotune
    with lm629_host.open_board(profile=_write(tmp_path, CAPPED)) as board:
        x = board["x"]
        words = []

        class Spy(SoftLimits):  # the same limits, every trajectory's words written down
            def check_trajectory(self, acceleration, velocity, position, **kw):
                words.append((velocity, acceleration))
                super().check_trajectory(acceleration, velocity, position, **kw)

        x.limits = Spy(**dataclasses.asdict(x.limits))
        result = autotune(x, travel=2000)
    assert result.ok
    steps = [w for w in words if w[0] is not None and w[1] is not None]
    # the experiments' steps at the caps; the trapezoid test move at its own words,
    # inside the caps (0x40000 and 0x2000 on this axis)
    move = (result.profile.velocity, result.profile.acceleration)
    assert move == (0x40000, 0x2000) and move[0] <= 3355443 and move[1] <= 17179
    assert steps and all(w in ((3355443, 17179), move) for w in steps)
    assert (3355443, 17179) in steps and move in steps
    assert result.fit_rms < 2.0
    assert result.measured.settle_s is not None and result.predicted.settle_s is not None
    assert abs(result.measured.settle_s - result.predicted.settle_s) < 0.005
    assert abs(result.measured.overshoot - result.predicted.overshoot) <= 3


def test_cli_step_tune_and_index_search_stay_inside_the_limits(tmp_path):
    runner = CliRunner()
    prof = _write(tmp_path, CAPPED)
    # step: without --vel/--acc the step is brought down to the caps, and says so in its words
    csv = tmp_path / "step.csv"
    r = runner.invoke(main, ["--profile", str(prof), "step", "1000", "--csv", str(csv),
                             "--no-png"])
    assert r.exit_code == 0, r.output
    assert ("a step brought down to the soft caps: velocity word 3355443, acceleration word "
            "17179") in r.output
    rows = [ln.split(",") for ln in csv.read_text().splitlines()]
    desired = [int(row[rows[0].index("desired_position")]) for row in rows[1:]]
    assert 0 < desired[2] < 1000 and desired[-1] == 1000  # a ramp, not a jump
    # tune: a band that leaves min..max is refused before anything moves
    r = runner.invoke(main, ["--profile", str(prof), "tune", "--travel", "25000", "--yes"])
    assert r.exit_code == 2
    assert "--travel 25000 from 0: the band reaches -25000 is below the soft limit min" in r.stderr
    # index --search: a move towards max (not velocity mode); the default simulated index is
    # 1000 counts away (half a revolution of 500 lines), inside the limits
    r = runner.invoke(main, ["--profile", str(prof), "index", "--search", "6553"])
    assert r.exit_code == 0, r.output
    assert "index at position 1000 counts" in r.output
    narrow = _write(tmp_path, CAPPED.replace("max = 20000", "max = 600"), "narrow.toml")
    r = runner.invoke(main, ["--profile", str(narrow), "index", "--search", "6553"])
    assert r.exit_code == 7
    assert "no index pulse on the way to the soft limit 600 (the move reached it" in r.stderr
    assert "motor stopped" in r.stderr
    r = runner.invoke(main, ["--profile", str(narrow), "index", "--search"])
    assert r.exit_code == 2 and "no index_velocity" in r.stderr
    back = _write(tmp_path, CAPPED.replace("min = -20000", "min = -1500")
                  + "index_velocity = -2000\n", "back.toml")
    r = runner.invoke(main, ["--profile", str(back), "index", "--search"])
    assert r.exit_code == 0, r.output
    assert "index at position -1000 counts" in r.output


def test_a_straight_line_is_held_to_each_axis_share_of_the_path_words(tmp_path):
    """x's cap is the word 3355443; a path velocity word of 4000000 gives x the share
    1000 / sqrt(1000^2 + 3000^2) = 0.316 of it, 1264911: inside.  The same word on x alone is
    above the cap (exit 2, nothing moved)."""
    two = _write(tmp_path, CAPPED + "[axis.y]\ncs = 1\nkp = 20\n", "two.toml")
    runner = CliRunner()
    r = runner.invoke(main, ["--profile", str(two), "--axis", "x,y", "move", "1000", "3000",
                             "--linear", "--vel", "4000000", "--acc", "10000"])
    assert r.exit_code == 0, r.output
    assert "done: axis x at" in r.output and "done: axis y at" in r.output  # the names
    r = runner.invoke(main, ["--profile", str(two), "--axis", "x,y", "move", "1000", "3000",
                             "--vel", "4000000", "--acc", "10000"])
    assert r.exit_code == 2 and r.stdout == ""
    assert "velocity word 4000000" in r.stderr and "[axis.x] max_velocity" in r.stderr


def test_shell_runs_a_piped_script_and_a_failing_one_stops_what_moves(tmp_path):
    runner = CliRunner()
    prof = _write(tmp_path)
    r = runner.invoke(main, ["--profile", str(prof), "shell"],
                      input="print(sorted(k for k in dir() if not k.startswith('_')))\n"
                            "print(board['x'] is x, chip is x, y.chip_select)\n")
    assert r.exit_code == 0, r.output
    assert r.stdout.splitlines() == [
        "['Signals', 'Status', 'board', 'chip', 'lm629_host', 'x', 'y']", "True True 1"]
    # a soft limit in a script: its traceback, the ValueError's exit code, y holding is left on
    r = runner.invoke(main, ["--profile", str(prof), "shell"],
                      input="x.move_to(45000, velocity=65536)\n")
    assert r.exit_code == 2
    assert "ValueError: target 45000 is above the soft limit max = 20000" in r.stderr
    assert "was moving" not in r.stderr
    # an error of the script's own while x moves: x stopped, exit 1
    r = runner.invoke(main, ["--profile", str(prof), "shell"],
                      input="x.move_to(15000, velocity=65536, acceleration=655)\n"
                            "raise RuntimeError('boom')\n")
    assert r.exit_code == 1
    assert "RuntimeError: boom" in r.stderr
    assert "lm629: x was moving: motor stopped (abrupt stop, then motor off)" in r.stderr
    assert "lm629: y was moving" not in r.stderr


def test_a_chip_that_lost_its_settings_while_moving_is_not_applied_mid_move(tmp_path):
    prof = load_profile(_write(tmp_path))
    with lm629_host.open_board(profile=prof) as board:
        x = board["x"]
        x.move_to(15000, velocity=65536, acceleration=655)  # 3.8 s at 1 count/sample
        x.clock.sleep(0.2)
        x.load_position_error(0x7FFF)  # LPEI by another program, mid-move: bit 9 clear
        said: list[str] = []
        assert ensure_applied({"x": x}, prof, said.append) == []
        assert len(said) == 1 and "is moving" in said[0] and "not applied" in said[0]
        assert x.is_moving() and not x.read_signals() & Signals.STOP_ON_ERROR


def test_the_profiles_port_is_settled_by_the_one_resolver(tmp_path):
    """[board] chip and clock go into the URL (ports.resolve_port splits them off a hardware
    URL and builds a simulator from them); a URL that says otherwise is one ProfileError."""
    hw = parse_profile(GOOD.replace('port = "sim://"', 'port = "serial:///dev/ttyACM0"')
                       .replace('chip = "lm629"', 'chip = "lm628"'), tmp_path / "hw.toml")
    assert profile_port(hw).text == "serial:///dev/ttyACM0?chip=lm628&clock=8000000"
    assert lm629_host.transports.ports.resolve_port(profile_port(hw)).chip == "lm628"
    bad = parse_profile(GOOD.replace('port = "sim://"', 'port = "sim://?chip=lm628"'),
                        tmp_path / "bad.toml")
    with pytest.raises(ProfileError) as err:
        profile_port(bad)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'bad.toml'}:3: [board] port: ") and "lm628" in msg
    assert "lm629" in msg and "\n" not in msg


def _lfil_words(recorder):
    """Each LFIL on the bus: its control word and the coefficient words after it."""
    data = recorder.data()
    out = []
    for i, (kind, value) in enumerate(data):
        if kind == "command" and value == 0x1E:
            words = []
            for k, v in data[i + 1:]:
                if k != "write":
                    break
                words.append(v)
            out.append(words)
    return out


def test_ds_is_the_interval_from_tune_to_the_lfil_word(tmp_path, open_chip, recorder):
    """ds = 7 samples everywhere -- the tuner's gains, their CLI line, a TuneResult, the profile
    saved after `tune`, the profile applied -- and only on the bus the LFIL control word's
    high byte holds 7 - 1 = 6 (AN-706 4.5.1: the derivative is sampled every byte + 1
    samples); kp 231 and kd 773 differ from the reset values (0)."""
    from lm629_host.cli.profile import after_tune
    from lm629_host.cli.tune import parse_gains
    from lm629_host.bench.tuning import TuneResult
    from lm629_host.physics.axis import Gains

    g = Gains(kp=231, kd=773, ds=7)
    assert parse_gains("kp=231,kd=773,ds=7") == g
    assert "--ds 7" in g.cli() and str(g).endswith("ds=7")
    result = TuneResult(g.kp, g.ki, g.kd, g.il, g.ds, *([None] * 9))
    assert result.gains == g
    # the tuner loads its gains as the session does
    chip = open_chip("sim://")
    chip.reset()
    recorder.clear()
    chip.load_filter(**result.gains.as_filter())
    chip.update_filter()
    assert _lfil_words(recorder) == [[0x060F, 231, 0, 773, 0]]
    assert chip.derivative_interval == 7
    model = chip.transport.model
    chip.clock.sleep(1e-3)
    assert model.filter.ds == 7 and model.filter.kd == 773
    # saved by `tune --save`, read back, applied to a fresh chip
    path = _write(tmp_path)  # x: kp 20, kd 0, ds 1
    after_tune(None, None, result.gains, (path, "x"), True)
    prof = load_profile(path)
    assert (prof.axes["x"].kp, prof.axes["x"].kd, prof.axes["x"].ds) == (231, 773, 7)
    other = open_chip("sim://")
    other.reset()
    recorder.clear()
    ensure_applied({"x": other}, prof, lambda text: None)
    assert _lfil_words(recorder) == [[0x060F, 231, 0, 773, 0]]
    assert other.derivative_interval == 7
    # a later LFIL without an interval sends the same byte again
    recorder.clear()
    other.load_filter(kp=232)
    assert _lfil_words(recorder) == [[0x0608, 232]]
def test_a_profile_from_init_drives_one_named_axis_and_decides_the_simulators_chips(tmp_path):
    """`profile init --axis 0,1` on the default simulator, then `--axis x`: the default
    simulator has the profile's two chips, and a command that drives x checks x alone (a
    one-chip bench is enough for it)."""
    runner = CliRunner()
    path = tmp_path / "p.toml"
    r = runner.invoke(main, ["--axis", "0,1", "--profile", str(path), "profile", "init"])
    assert r.exit_code == 0, r.output
    for args in (["move", "1000"], ["status"]):
        r = runner.invoke(main, ["--profile", str(path), "--axis", "x", *args])
        assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["--profile", str(path), "status", "--json"])
    assert r.exit_code == 0, r.output
    assert r.stdout.count('"status"') == 2  # both axes of the profile: two simulated chips
    one_chip = "sim://?axes=1"
    r = runner.invoke(main, ["--profile", str(path), "--port", one_chip, "--axis", "x", "status"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["--profile", str(path), "--port", one_chip, "--axis", "y", "status"])
    assert r.exit_code == 2 and "axis 1 does not exist" in r.stderr


def test_output_names_the_profiles_axes_where_it_printed_numbers(tmp_path):
    prof = _write(tmp_path)
    runner = CliRunner()
    r = runner.invoke(main, ["--profile", str(prof), "status"])
    assert r.exit_code == 0, r.output
    assert [ln.split(":")[0] for ln in r.stdout.splitlines() if ln.startswith("axis")] == \
        ["axis x", "axis y"]
    r = runner.invoke(main, ["--profile", str(prof), "--axis", "y", "status"])
    assert r.stdout.splitlines()[0] == "axis     y (cs 1)"
    r = runner.invoke(main, ["--profile", str(prof), "move", "1000", "-1000"])
    assert r.exit_code == 0, r.output
    assert r.stdout.startswith("moving axes x, y to [1000, -1000]")
    assert "done: axis y at" in r.stdout
    r = runner.invoke(main, ["--profile", str(prof), "move", "1000"])
    assert r.exit_code == 2 and "1 target(s) for 2 axis/axes (x, y)" in r.stderr
    r = runner.invoke(main, ["--profile", str(prof), "watch", "--count", "1"])
    assert [ln.split()[1] for ln in r.stdout.splitlines()[1:]] == ["x", "y"]


def test_the_shell_touches_only_the_boards_own_axes_and_refuses_a_shadowing_name(tmp_path):
    """A two-axis profile on a bench whose bridge has four chip selects (the Python bridge
    over two chips): a failing script stops x and says nothing of chip selects 2 and 3."""
    from lm629_host.sim.serve import SimServer
    with SimServer(tmp_path / "bench", "sim://?axes=2").start() as srv:
        prof = _write(tmp_path, GOOD.replace('port = "sim://"', f'port = "{srv.client_url}"'))
        r = CliRunner().invoke(main, ["--profile", str(prof), "shell"],
                               input="x.move_to(15000, velocity=65536, acceleration=655)\n"
                                     "raise RuntimeError('boom')\n")
    assert r.exit_code == 1, r.output
    assert "lm629: x was moving: motor stopped" in r.stderr
    assert "axis2" not in r.stderr and "axis3" not in r.stderr and "busy" not in r.stderr
    bad = _write(tmp_path, GOOD.replace("[axis.y]", "[axis.board]"), "bad.toml")
    r = CliRunner().invoke(main, ["--profile", str(bad), "shell"], input="print(1)\n")
    assert r.exit_code == 2 and r.stdout == ""
    assert "axis 'board' of" in r.stderr and "would hide the shell's own `board`" in r.stderr


def test_a_port_that_writes_a_file_is_taken_from_the_command_line_only(tmp_path):
    """`port = "spy://loop://?file=..."` in a profile would truncate that file on any
    command, `status` included: refused (exit 2, the file untouched); the same URL typed
    with --port is honoured."""
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    prof = _write(tmp_path, f'[board]\nport = "spy://loop://?file={victim}"\n[axis.x]\ncs = 0\n')
    runner = CliRunner()
    r = runner.invoke(main, ["--profile", str(prof), "status"])
    assert r.exit_code == 2 and victim.read_text() == "keep me\n"
    assert r.stderr.startswith(f"lm629: bad value: {prof}:2: [board] port:")
    assert "give that port with --port on the command line" in r.stderr
    with pytest.raises(ValueError, match="a profile never names a file to write"):
        lm629_host.open_board(profile=str(prof))
    log = tmp_path / "spy.txt"
    r = runner.invoke(main, ["--profile", str(prof), "--port", f"spy://loop://?file={log}",
                             "status"])
    assert log.exists()  # typed on the command line: pyserial's spy writes it


def test_a_profile_axis_without_a_chip_names_the_axis_the_cs_and_the_fix(tmp_path):
    """A two-axis profile on a served bench of one chip (the bridge has four chip selects,
    nothing answers on cs 1): one line naming axis y, cs 1 and the fix, exit 4."""
    from lm629_host.sim.serve import SimServer
    with SimServer(tmp_path / "bench", "sim://").start() as srv:
        prof = _write(tmp_path, GOOD.replace('port = "sim://"', f'port = "{srv.client_url}"'))
        r = CliRunner().invoke(main, ["--profile", str(prof), "status"])
    assert r.exit_code == 4, r.output
    line = r.stderr.strip().splitlines()[-1]  # after x's "had lost its settings" line
    assert line.startswith(f"lm629: error: axis y (cs 1) of {prof} does not answer: ")
    assert "--url 'sim://?axes=2'" in line and "the /CS wire of that chip" in line


def test_profile_show_reads_the_status_as_status_does_and_says_which_port(tmp_path):
    prof = _write(tmp_path, '[axis.x]\ncs = 0\nkp = 20\n')
    runner = CliRunner()
    show = runner.invoke(main, ["--port", "sim://", "--profile", str(prof), "profile", "show"])
    assert show.exit_code == 0, show.output
    assert show.stdout.splitlines()[0].startswith(
        f"profile {prof}: port none in the file (this command: sim://")
    assert "status C0 breakpoint,motor_off" in show.stdout  # as `status` reads it: not busy


def test_tune_save_keeps_the_comment_column_and_says_saved_last(tmp_path):
    """`tune --save` on a profile whose [axis.x] lines carry comments: each comment stays in the
    column the user put it in whatever the width of the new value (the template's column 30),
    and the line that says the profile was written is the last one tune prints, under the
    gains, not buried between the tuner's progress lines."""
    runner = CliRunner()
    path = tmp_path / "p.toml"
    r = runner.invoke(main, ["--port", "sim://", "--axis", "0", "--profile", str(path),
                             "profile", "init"])
    assert r.exit_code == 0, r.output
    before = {ln.split("=")[0].strip(): ln.index("#") for ln in path.read_text().splitlines()
              if "#" in ln and "=" in ln.split("#")[0] and not ln.startswith("#")}
    r = runner.invoke(main, ["--profile", str(path), "tune", "--travel", "2000", "--yes",
                             "--save"])
    assert r.exit_code == 0, r.output
    text = path.read_text()
    kp = int(next(ln for ln in text.splitlines() if ln.startswith("kp")).split("=")[1].split("#")[0])
    assert kp != 20 and len(str(kp)) > 2  # a wider value than the template's kp = 20
    after = {ln.split("=")[0].strip(): ln.index("#") for ln in text.splitlines()
             if "#" in ln and "=" in ln.split("#")[0] and not ln.startswith("#")}
    assert {k: after[k] for k in before} == before
    out = r.stdout.strip().splitlines()
    assert f"set them again with:  lm629 --axis x filter --kp {kp} " in r.stdout  # this axis
    assert out[-2].startswith(f"saved kp={kp} ") and out[-2].endswith(f"into [axis.x] of {path}")
    assert out[-1] == f"saved the plant into [axis.x.plant] of {path}"


def test_one_axis_commands_name_the_profiles_axis_and_ask_for_one(tmp_path):
    """A two-axis profile: `tune` without --axis is told which axes it chose and how to pick
    one (not an --axis the user never typed), and a one-axis bring-up says which axis it is."""
    prof = _write(tmp_path)
    runner = CliRunner()
    r = runner.invoke(main, ["--profile", str(prof), "tune", "--travel", "1000", "--yes"])
    assert r.exit_code == 2
    assert "axes x, y are chosen" in r.stderr and "give --axis NAME" in r.stderr
    r = runner.invoke(main, ["--profile", str(prof), "--axis", "y", "bringup", "--yes"])
    assert r.stdout.startswith("bring-up of axis y (cs 1), LM629 on "), r.stdout[:200]
    r = runner.invoke(main, ["--profile", str(prof), "--axis", "y", "filter", "--kp", "30"])
    assert r.exit_code == 0 and "filter loaded and updated on axis y: kp=30" in r.stdout


def test_open_takes_a_profile_as_open_board_does(tmp_path, caplog):
    """``lm629_host.open(profile=...)``: the port, chip and clock from the profile; the chip on
    chip select 0 is axis x, with its soft limits and its gains applied at open (the fresh
    simulated chip lost them at power-up: one warning says so); ``?cs=1`` opens axis y."""
    import logging
    path = _write(tmp_path, GAINED)
    with caplog.at_level(logging.WARNING, logger="lm629_host"):
        chip = lm629_host.open(profile=path)
    with chip:
        assert chip.profile_axis == "x" and "axis x (cs 0) had lost its settings" in caplog.text
        f = chip.transport.models[0].filter_buffer  # the profile's port: sim://?axes=2
        assert (f.kp, f.ki, f.kd, f.il) == (20, 4, 800, 500)
        before = chip.transport.stats.programs
        with pytest.raises(ValueError, match="target 20001 is above the soft limit max = 20000"):
            chip.move_to(20001, velocity=65536, acceleration=655)
        assert chip.transport.stats.programs == before
    with lm629_host.open("sim://?axes=2&cs=1", profile=path, apply=False) as y:
        assert y.profile_axis == "y" and y.transport.models[1].filter_buffer.kp == 0
    with pytest.raises(ValueError, match="apply='sometimes'"):
        lm629_host.open(profile=path, apply="sometimes")
