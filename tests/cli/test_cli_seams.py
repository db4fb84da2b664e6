"""What a new user trips on between the README and the bench: a missing optional extra, a
misspelt option or URL key, an error that is not the ``lm629:`` line, a check that compares
the twin with itself.  Each is one clear line and the exit code of its kind."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host import cli

ROOT = Path(__file__).resolve().parents[2]

#: the extras' modules, as a fresh ``pip install -e .`` (no extras) lacks them (pyvcd's is vcd)
EXTRA_MODULES = ("pyftdi", "matplotlib", "plotext", "vcd", "labgrid")


@pytest.fixture
def run():
    runner = CliRunner()

    def _run(*args: str):
        return runner.invoke(cli.main, list(args), env={"LM629_PORT": "", "LM629_PROFILE": ""},
                             catch_exceptions=False)
    return _run


@pytest.fixture
def fresh_install(monkeypatch):
    """Every optional extra's modules unimportable, as on the README's ``pip install -e .``."""
    for name in EXTRA_MODULES:
        monkeypatch.setitem(sys.modules, name, None)  # import and find_spec: not there


def _one_line(r) -> str:
    """The whole of stderr, which must be one ``lm629:`` line (no traceback)."""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lm629: "), r.stderr
    return lines[0]


# ---------------------------------------------------------------------------- optional extras
def test_vcd_without_pyvcd_is_one_line_naming_the_extra_before_anything_opens(run, fresh_install,
                                                                              tmp_path):
    vcd = tmp_path / "s.vcd"
    r = run("--vcd", str(vcd), "bringup", "--yes")
    assert r.exit_code == 2
    line = _one_line(r)
    assert "--vcd" in line and "pip install 'lm629-host[vcd]'" in line
    assert not vcd.exists()
    r = run("--port", f"sim://?vcd={vcd}", "status")  # the URL's vcd= likewise
    assert r.exit_code == 2 and "--port" in _one_line(r) and "lm629-host[vcd]" in r.stderr


def test_vcd_with_pyvcd_writes_the_bus(run, tmp_path):
    vcd = tmp_path / "s.vcd"
    r = run("--vcd", str(vcd), "status")
    assert r.exit_code == 0, r.output
    assert vcd.read_text().startswith("$")  # a VCD header


def test_doctor_on_a_fresh_install_lists_the_missing_extras_as_optional(run, fresh_install):
    from lm629_host.cli.bench import OPTIONAL_EXTRAS
    r = run("doctor")
    assert r.exit_code == 0, r.output
    assert "[!!]" not in r.output and r.output.rstrip().endswith("no problems found")
    for extra in OPTIONAL_EXTRAS:
        assert f"[--] {extra}: not installed" in r.output
        assert f"pip install 'lm629-host[{extra}]'" in r.output
    # the FT232H's own note of the missing pyftdi is marked the same way, not "[ok]"
    assert "[--] pyftdi: not installed, optional" in r.output
    assert "[ok] pyftdi" not in r.output


def test_doctor_with_the_extras_shows_them_installed(run):
    r = run("doctor")
    for extra in ("ftdi", "plot", "scope", "vcd"):  # the test extra brings these
        assert f"[ok] {extra}: " in r.output, r.output


def test_the_extras_doctor_lists_are_the_packages(run):
    """One list in the code, one in pyproject.toml: every extra a user installs is listed (an
    extra that installs nothing, `panel`, names a feature that needs nothing beyond the
    package: doctor has nothing to look for)."""
    from lm629_host.cli.bench import OPTIONAL_EXTRAS
    tomllib = pytest.importorskip("tomllib" if sys.version_info >= (3, 11) else "tomli")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(OPTIONAL_EXTRAS) == {e for e, reqs in extras.items() if reqs} - {"test", "lint"}
    for extra, (modules, _needs) in OPTIONAL_EXTRAS.items():
        named = {req.split(">")[0].split("=")[0].strip() for req in extras[extra]}
        assert {dist for _m, dist in modules} == named, extra
        assert {m for m, _dist in modules} <= set(EXTRA_MODULES), extra


# ---------------------------------------------------------------------------- misspellings
def test_a_misspelt_option_of_a_command_with_signed_arguments_gets_a_suggestion(run):
    r = run("move", "100", "--velo", "5")
    assert r.exit_code == 2
    line = _one_line(r)
    assert "No such option '--velo'" in line and "'--vel'" in line and "--help'" not in line
    r = run("velocity", "--acce", "3", "100")
    assert r.exit_code == 2 and "'--acc'" in _one_line(r)


def test_sim_axis_suggests_axes(run):
    r = run("--port", "sim://?axis=2", "status")
    assert r.exit_code == 2
    line = _one_line(r)
    assert "--port" in line and "did you mean axes=2" in line
    with pytest.raises(lm629_host.ArgumentError) as info:  # the library says the same
        lm629_host.open("sim+emu://?axis=2")
    assert info.value.argument == "axis" and "axes=2" in str(info.value)


# ---------------------------------------------------------------------------- the lm629: line
def test_sigrok_install_into_a_bad_directory_is_the_usual_line_and_exit_2(run, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    r = run("sigrok", "install", "--dir", str(blocker / "decoders"))
    assert r.exit_code == 2
    line = _one_line(r)
    assert "--dir" in line and str(blocker) in line and "Error:" not in r.output
    r = run("sigrok", "install", "--dir", str(tmp_path / "decoders"))
    assert r.exit_code == 0 and (tmp_path / "decoders" / "lm629" / "pd.py").is_file()


def test_a_commands_own_refusal_is_the_lm629_line(run, tmp_path):
    """A command's click.ClickException (bridge flash without its image) keeps its exit code
    and is printed as every other error, not click's ``Error:``."""
    r = run("bridge", "flash", "--port", "/dev/ttyACM0", "--hex", str(tmp_path / "none.hex"))
    assert r.exit_code == 1
    line = _one_line(r)
    assert "no firmware image at" in line


# ---------------------------------------------------------------------------- twin check
TWIN_PROFILE = """\
[board]
chip = "lm629"
clock = "8MHz"

[axis.x]
cs = 0
kp = 30
kd = 200

[axis.x.plant]
accel = 595730.0
tau = 0.26757
dry = 0.00855
load = -0.00135
reversed = false
"""


def test_twin_check_refuses_to_compare_the_twin_with_itself(run, tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text(TWIN_PROFILE)
    r = run("--profile", str(path), "--port", "sim://", "twin", "check", "--travel", "4000",
            "--yes")
    assert r.exit_code == 2
    assert "is the twin itself" in _one_line(r) and r.stdout == ""
    # the twin of another profile is a bench of its own (here the same plant: it matches)
    other = tmp_path / "other.toml"
    other.write_text(TWIN_PROFILE)
    r = run("--profile", str(path), "--port", f"sim://?profile={other}", "twin", "check",
            "--travel", "4000", "--yes")
    assert r.exit_code == 0 and r.stdout.splitlines()[-1] == "matches", r.output


def test_twin_check_says_its_verdict_once(run, tmp_path):
    """A simulated bench of its own (its motor in the URL: the plant's own keys, so the same
    axis as the twin): the table, then "matches" once, as the last line."""
    path = tmp_path / "bench.toml"
    path.write_text(TWIN_PROFILE)
    bench = "sim://?accel=595730&tau=0.26757&dry=0.00855&load=-0.00135"
    r = run("--profile", str(path), "--port", bench, "twin", "check", "--travel", "4000",
            "--yes")
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert lines[-1] == "matches" and sum("matches" in ln for ln in lines) == 1, r.stdout


def test_a_misspelt_global_option_is_the_same_line_with_the_suggestion(run):
    r = run("--prot", "sim://", "status")
    assert r.exit_code == 2
    line = _one_line(r)
    assert "No such option '--prot'" in line and "'--port'" in line and "Usage:" not in r.output
    r = run("--chip", "lm627", "status")
    assert r.exit_code == 2 and "'lm627' is not one of" in _one_line(r)
    r = run()  # bare lm629: the help, as click gives it
    assert "[OPTIONS] COMMAND" in r.output and "lm629: " not in r.stderr


def test_sim_serve_suggests_axes_too(run, tmp_path):
    r = run("sim", "serve", "--pty", str(tmp_path / "bench"), "--url", "sim://?axis=2")
    assert r.exit_code == 2
    assert "--url" in _one_line(r) and "did you mean axes=2" in r.stderr
    assert not (tmp_path / "bench").exists()
