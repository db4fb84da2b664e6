"""Input checked before anything moves, and the exit code of every way a command ends.

Every bad input: exit 2, one line on stderr naming the option, no traceback, and no LTRJ
(1Fh) or STT (01h) reached the simulated chip (its own record of the commands at its pins).
Numbers: 8 MHz unless said, 500 lines = 2000 counts/rev.
"""

from __future__ import annotations

import subprocess

import pytest
from click.testing import CliRunner

from lm629_host import Cmd, cli
from lm629_host.cli import app as cli_app
from served import _console_script, err_lines


@pytest.fixture
def run():
    runner = CliRunner()

    def _run(*args: str, input: str | None = None):
        return runner.invoke(cli.main, list(args), env={"LM629_PORT": ""},
                             catch_exceptions=False, input=input)
    return _run


def _moved(chips) -> bool:
    return any(c in (Cmd.LTRJ, Cmd.STT) for chip in chips
               for c, _ in chip.transport.model.history)


BAD = [
    (["filter", "--ds", "0"], "--ds"),  # the library's derivative_interval, named as typed
    (["filter", "--kp", "70000"], "--kp"),
    (["step", "200", "--kp", "99999"], "Invalid value for --kp"),  # the option, not kp=
    (["limit", "99999", "--stop"], "Invalid value for THRESHOLD"),
    (["move", "inf"], "TARGET"),
    (["move", "nan"], "TARGET"),
    (["move", "1.5"], "whole counts"),
    (["move", "100", "--vel", "inf"], "--vel"),
    (["move", "100", "--vel", "0"], "--vel: gives the word 0"),
    (["move", "100", "--acc", "1e-9"], "--acc: 1e-09 must be a whole raw word"),
    (["--lines", "500", "move", "1", "--acc", "1e-9"], "--acc: gives the word 0"),
    (["move", "100", "--vel", "0", "--timeout", "nan"], "--timeout"),
    (["move", "100", "--timeout", "nan"], "--timeout"),
    (["move", "100", "--timeout", "0"], "--timeout"),
    (["move", "100", "--tolerance", "-1"], "--tolerance"),
    (["move", str(1 << 30)], "outside -1073741824..1073741823"),
    (["move", "2000000000"], "TARGET: 2000000000 counts, outside"),  # as typed, not 2e+09
    (["move", "0x7FFFFFFF"], "TARGET: 0x7FFFFFFF (2147483647 counts), outside"),
    (["move", "--vell", "5"], "--vell"),
    (["--lines", "500", "move", "1e9"], "outside"),
    (["--lines", "500", "move", "1", "--vel", "1e9"], "--vel"),
    (["velocity", "65536", "--time", "inf"], "--time"),
    (["velocity", "-5"], "--reverse"),
    (["velocity", "0"], "--vel: gives the word 0"),
    (["limit", "-1"], "Invalid value for THRESHOLD: -1 counts"),
    (["breakpoint", "inf"], "POSITION"),
    (["index", "--search", "0"], "--search"),
    (["index", "--wait", "nan"], "--wait"),
    (["watch", "--rate", "inf"], "--rate"),
    (["watch", "--csv", "/missing/dir/x.csv", "--count", "1"], "does not exist"),
    (["step", "200", "--csv", "/missing/dir/x.csv"], "does not exist"),
    (["step", "200", "--png", "/missing/dir/x.png"], "does not exist"),
    (["step", "200", "--time", "inf"], "--time"),
    (["step", "200", "--vel", "0"], "--vel"),
    (["--lines", "500", "calc", "--rpm", "inf"], "--rpm"),
    (["--clock", "inf", "status"], "--clock"),
    (["--port", "sim://?chip=lm629", "--chip", "lm628", "status"], "conflicts with chip=lm629"),
    (["--port", "sim://?clock=8000000", "--clock", "6MHz", "status"],
     "conflicts with clock=8000000"),
    (["--port", "sim://?clock=fast", "status"], "not a frequency"),
]


@pytest.mark.parametrize("args, words", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_input_is_one_line_and_moves_nothing(run, opened, args, words):
    if not any(a.startswith("--port") for a in args):
        args = ["--port", "sim://?record=1", *args]
    r = run(*args)
    assert r.exit_code == 2, r.output
    assert len(err_lines(r)) == 1 and words in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert not _moved(opened)


@pytest.mark.parametrize("scheme", ["sim", "sim+emu", "sim+ftdi"])
@pytest.mark.parametrize("path, why", [("/proc/x.vcd", "cannot create it"),
                                       ("/proc", "that is a directory")])
def test_an_unwritable_vcd_path_is_one_line_before_anything_opens(run, opened, scheme, path,
                                                                   why):
    """vcd= naming a file that cannot be made (/proc takes no new file, even for root) was a
    39-line traceback, "internal error (FileNotFoundError)", exit 8, from the writer: it is
    bad usage, said in one line before the simulator is built."""
    r = run("--port", f"{scheme}://?vcd={path}", "status")
    assert r.exit_code == 2, r.output
    assert len(err_lines(r)) == 1 and f"vcd={path}: {why}" in r.stderr, r.stderr
    assert opened == []


def test_empty_port_is_an_error_not_the_simulator(run, opened):
    r = run("--port", "", "status")
    assert r.exit_code == 2 and "--port" in r.stderr and "is empty" in r.stderr
    assert opened == []


def test_negative_numbers_as_typed(run, opened):
    r = run("--port", "sim://?record=1", "move", "-500")
    assert r.exit_code == 0, r.stderr
    assert opened[-1].transport.model.motion.desired_position == -500  # the port is closed
    r = run("--port", "sim://", "breakpoint", "-100")
    assert r.exit_code == 0 and "breakpoint -100 counts set" in r.output
    r = run("--port", "sim://", "--lines", "500", "move", "-0.25")  # -500 counts
    assert r.exit_code == 0 and "moving to -500 counts (-0.2500 rev)" in r.output


def test_url_chip_and_clock_are_used_when_the_options_are_not_given(run, opened):
    r = run("--port", "sim://?chip=lm628", "status")
    assert r.exit_code == 0 and opened[-1].variant == "lm628"
    # clock=6MHz written like --clock: 600 rpm at 6 MHz (T = 341.33 us) is
    # 10 rev/s * 2000 counts * T = 6.8267 counts/sample = word 447392
    r = run("--port", "sim://?clock=6MHz", "--lines", "500", "move", "0.5", "--vel", "600",
            "--no-wait")
    assert r.exit_code == 0, r.stderr
    assert "velocity word 447392" in r.output
    assert opened[-1].transport.model.clock_hz == 6e6
    r = run("--port", "sim://?clock=8MHz", "--clock", "8MHz", "status")  # agreeing: fine
    assert r.exit_code == 0


def test_prompt_aborted_exits_130_and_nothing_moves(run, opened):
    r = run("--port", "sim://?record=1", "bringup", input="")  # end of input at the prompt
    assert r.exit_code == 130
    assert err_lines(r)[-1] == "lm629: interrupted (Ctrl-C)"
    assert not _moved(opened)


def test_raw_that_sets_command_error_exits_6(run):
    r = run("--port", "sim://?strict=0", "raw", "0x99")  # an unknown command on purpose
    assert r.exit_code == 6
    # after the CLI's reset the status reads C0 (motor off, breakpoint level-held: model
    # choice 19); the unknown command adds the command-error bit (01h << 1)
    assert "status C2" in r.output and "rejected command 99h" in r.stderr
    assert run("--port", "sim://", "raw", "0x1F", "0").exit_code == 0  # LTRJ, control word 0


def test_doctor_with_a_stuck_busy_chip_is_a_problem(run):
    r = run("--port", "sim://?fault=busy", "doctor")
    assert r.exit_code == 1
    line = next(ln for ln in r.output.splitlines() if "status read" in ln)
    assert "[!!]" in line and "stuck busy" in line


def test_step_motion_fault_still_writes_the_files(run, tmp_path):
    csv_path = tmp_path / "s.csv"
    r = run("--port", "sim://?stall=1", "step", "200", "--csv", str(csv_path), "--no-png")
    assert r.exit_code == 9 and "motion fault (stall)" in r.stderr
    assert csv_path.read_text().startswith("t_s,")


def test_step_with_lines_takes_revolutions(run, tmp_path):
    r = run("--port", "sim://", "--lines", "500", "step", "0.1", "--csv",
            str(tmp_path / "s.csv"), "--no-png")
    assert r.exit_code == 0, r.stderr
    assert r.output.startswith("target 200 counts")  # 0.1 rev = 200 counts
    assert "at rest" in r.output


def test_closed_stdout_exit_status_is_lm629s_own():
    """`lm629 calc | head` with the reader gone before lm629 writes: the output was lost, so
    lm629 itself exits 141 (128 + SIGPIPE, as a Unix tool ended by the signal; not Python's
    120 from a failed flush at exit), silently (nothing moved), without a traceback; the pipe
    is closed before anything is written."""
    p = subprocess.Popen([_console_script(), "--lines", "500", "calc", "--rev", "2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    p.stdout.close()
    err = p.stderr.read()
    assert p.wait(timeout=60) == 141, err
    assert err == ""


@pytest.mark.parametrize("fault, reason", [("stall=1", "stall"), ("reversed=1", "runaway")])
def test_velocity_checks_the_shaft_turns(run, opened, fault, reason):
    r = run("--port", f"sim://?{fault}&record=1", "velocity", "65536", "--time", "0.3")
    assert r.exit_code == 9, r.output
    assert f"motion fault ({reason})" in r.stderr and len(err_lines(r)) == 1
    assert opened[-1].transport.model.motor_off


def test_sigterm_during_watch_exits_143_and_stops_nothing(run, signal_on_row):
    import signal
    chips = signal_on_row(signal.SIGTERM)
    before = signal.getsignal(signal.SIGTERM)
    r = run("--port", "sim://?record=1", "watch", "--rate", "50")
    assert signal.getsignal(signal.SIGTERM) is before  # restored
    assert r.exit_code == 143
    assert r.stderr == "(2 rows)\nlm629: terminated (SIGTERM)\n"
    assert not _moved(chips)  # the simulator's preparation has no LTRJ/STT; nothing stopped


def test_the_readme_exit_code_table_lists_every_code_of_the_cli():
    """README.md's exit-code table and ``EXIT_CODES`` (what ``lm629 --help`` prints) name the
    same codes: one list, checked, not two hand-kept copies that drift."""
    import re
    from pathlib import Path
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    table = readme[readme.index("Exit codes (also in `lm629 --help`)"):]
    table = table[table.index("\n|"):].strip()
    table = table[:table.index("\n\n")]
    codes = {int(c) for row in table.splitlines()[2:]
             for cell in row.split("|")[1::2] for c in re.findall(r"\d+", cell)}
    assert codes == set(cli_app.EXIT_CODES)


def test_docs_cli_exit_code_table_lists_every_code_of_the_cli():
    """docs/cli.md's exit-code table names the codes of ``EXIT_CODES`` too (a row may name
    several: ``3 / 4 / 5``)."""
    import re
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[2] / "docs" / "cli.md").read_text()
    table = doc[doc.index("**Exit codes**"):]
    table = table[table.index("\n  |"):].strip()
    table = table[:table.index("\n\n")]
    codes = {int(c) for row in table.splitlines()[2:] for c in re.findall(r"\d+", row.split("|")[1])}
    assert codes == set(cli_app.EXIT_CODES)


def test_no_two_meanings_share_an_exit_code():
    """One table, one meaning per code: every exit code a command gives (the error classes',
    the selftest's verdicts, a check's "found a problem", a prompt answered no, the stop
    signals) is grouped by what it means, and no two meanings share a code (a selftest FAIL
    was 2, bad usage's; a declined prompt 1, a check's), each code a row of EXIT_CODES."""
    import signal

    from lm629_host.bench import selftest
    from lm629_host.cli import tune, twin
    from lm629_host.errors import (BusyTimeout, CommandError, LM629Error, MotionError,
                                   ResetError, TransportError, WaitTimeout)
    error_code = dict(cli_app._ERROR_EXITS)
    meanings: dict[str, set[int]] = {
        "success": {0, selftest.EXIT["PASS"]},
        "a check found a problem": {selftest.EXIT["DIFFERS"], tune.EXIT_NOT_MET,
                                    twin.EXIT_DIFFERS},
        "bad usage or value": {2, error_code[ValueError]},
        "transport error": {error_code[TransportError]},
        "busy timeout": {error_code[BusyTimeout]},
        "reset failure": {error_code[ResetError]},
        "command error": {error_code[CommandError]},
        "wait timeout": {error_code[WaitTimeout]},
        "other driver error": {error_code[LM629Error]},
        "motion fault": {error_code[MotionError]},
        "the selftest could not finish": {selftest.EXIT["FAIL"]},
        "interrupted, or a prompt answered no": {cli_app.EXIT_DECLINED, 128 + signal.SIGINT},
        "hang-up": {128 + signal.SIGHUP},
        "terminated": {128 + signal.SIGTERM},
        "output closed": {141},
    }
    assert {m: len(c) for m, c in meanings.items()} == {m: 1 for m in meanings}
    codes = [c for cs in meanings.values() for c in cs]
    assert len(codes) == len(set(codes)), meanings
    assert set(codes) == set(cli_app.EXIT_CODES)
    assert "selftest FAIL" in cli_app.EXIT_CODES[selftest.EXIT["FAIL"]]
    assert "selftest DIFFERS" in cli_app.EXIT_CODES[selftest.EXIT["DIFFERS"]]


def test_status_into_a_closed_pipe_exits_141_as_the_docs_say():
    """docs/cli.md: stdout closed (`lm629 status | head -3`) is 141, output lost, as any Unix
    tool that SIGPIPE ends.  The pipe's read end is closed before the command starts, so its
    first write fails whatever the timing of a real `head`."""
    import os

    read, write = os.pipe()
    os.close(read)
    try:
        p = subprocess.run([_console_script(), "--port", "sim://", "status"], stdout=write,
                           stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(write)
    assert p.returncode == 141, p.stderr
