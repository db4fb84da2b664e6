"""The wiring drawn and printed from the pin maps, miswired simulated benches
(``wiring=`` on every simulated URL), and ``lm629 wiring --check`` naming the wrong wire.

Numbers worked out from the spec: after /RST and 1.5 ms the status is 84 or C4 (the model:
C4, breakpoint latched); with D2 and D3 swapped the host reads C4 with bits 2 and 3
exchanged, C8.  With D5 stuck low a target of 1000 (03E8) reaches the chip as 03C8 = 968 (the
example the check's message is built on).  The LM629's D7..D0 are DIP pins 4..11 (D0 on pin
11) and land on the Uno's D9..D2, so a fault on LM629 D5 is "pin 6 ... Uno D7".
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import pytest

import lm629_host
from lm629_host.errors import BusyTimeout, TransportError
from lm629_host.wiring.connections import adapter_pin, connections, markdown
from lm629_host.wiring.faults import Miswiring
from lm629_host.bus.opcodes import Cmd
from lm629_host.sim.harness import toolchain_missing
from lm629_host.transports.base import Transport
from lm629_host.bench.wiring_check import check_wiring, diagnose, run_experiments, suspects_of_data_bus
from lm629_host.wiring.reference import READINGS, WHAT
from lm629_host.bench.wiring_draw import render
from sim_urls import with_params

ROOT = Path(__file__).resolve().parents[2]

#: the faults of the Done-when list, and the LM629 lines each must name
REQUIRED = ([f"d{i}-low" for i in range(8)] + [f"d{i}-high" for i in range(8)]
            + ["d3-open", "d2-d3", "d6-d7"])
#: every single swap (on sim:// in full)
SWAPS = [f"d{i}-d{j}" for i in range(8) for j in range(i + 1, 8)]
PINS = {f"D{i}": 11 - i for i in range(8)}  # D0 on pin 11 ... D7 on pin 4 (test_pinout.py)
UNO = {f"D{i}": f"D{i + 2}" for i in range(8)}


def _lines(fault: str) -> set[str]:
    return {f"D{x}" for x in re.findall(r"d(\d)", fault)}


def _check(url: str):
    with lm629_host.open(url) as chip:
        return check_wiring(chip)


# ---------------------------------------------------------------------- the bend itself
def test_bend_of_each_form():
    assert Miswiring.parse("d5-low").to_chip(0xE8) == 0xC8  # 03E8 -> 03C8: 1000 -> 968
    assert Miswiring.parse("d5-low").to_host(0xFF) == 0xDF
    assert Miswiring.parse("d0-high").to_chip(0x00) == 0x01
    assert Miswiring.parse("d3-open").to_host(0x00) == 0x08  # open reads 1 (the model choice)
    swap = Miswiring.parse("d2-d3")
    assert swap.to_chip(0x04) == 0x08 and swap.to_host(0xC4) == 0xC8
    assert swap.to_host(swap.to_chip(0x5A)) == 0x5A  # a swap reads back what it wrote
    both = Miswiring.parse("d5-low,d2-d3")
    assert both.to_chip(0xFF) == 0xDF and both.to_chip(0x04) == 0x08


@pytest.mark.parametrize("bad", ["d8-low", "d5-lo", "d2-d2", "d5-low,d5-high", "x"])
def test_unknown_wiring_lists_the_known_forms(bad):
    with pytest.raises(ValueError) as e:
        lm629_host.open(f"sim://?wiring={bad}")
    msg = str(e.value)
    assert "wiring=" in msg and "dN-low" in msg and "dN-dM" in msg


@pytest.mark.parametrize("url", ["sim://", "sim+emu://", "sim+avr://", "sim+ftdi://"])
def test_every_simulator_bends_both_ways(url):
    if url == "sim+avr://" and toolchain_missing():
        pytest.skip("AVR toolchain missing")
    with lm629_host.open(url + "?wiring=d2-d3") as chip:
        r = chip.run(chip.program().reset().wait(1500).status())
        assert r.statuses == (0xC8,)  # C4 read through the swapped wires
    with lm629_host.open(url + "?wiring=d5-low") as chip:
        # LTRJ position 03E8 (1000) reaches the chip as 03C8; RDDP reads 968 back
        # (its bytes 00 00 03 C8 have no bit 5 to lose on the way back)
        chip.run(chip.program().reset().wait(1500))
        chip.run(chip.program().command(Cmd.LTRJ).write(0x000A).write32(0x00100000)
                 .write32(1000).command(Cmd.STT))
        chip.clock.sleep(0.01)
        # the acceleration bit (5) of the control word is lost too: the velocity is loaded,
        # the acceleration stays 0 (reset), and the chip does not move: RDDP stays 0
        words = chip.run(chip.program().command(Cmd.RDDP).read(2)).words
        assert words == (0, 0)


def test_d5_low_bends_a_target_of_1000_into_968():
    with lm629_host.open("sim://?wiring=d5-low&record=1") as chip:
        # LTRJ with the position only (control word 0002: no bit 5 to lose)
        chip.run(chip.program().reset().wait(1500).command(Cmd.LTRJ).write(0x0002)
                 .write32(1000))
        assert list(chip.transport.model.history)[-1] == (int(Cmd.LTRJ), (0x0002, 0, 0x03C8))


# ---------------------------------------------------------------------- the check
@pytest.mark.parametrize("url", ["sim://", "sim+emu://", "sim+avr://"])
def test_a_correct_bench_passes(url):
    if url == "sim+avr://" and toolchain_missing():
        pytest.skip("AVR toolchain missing")
    report = _check(url)
    assert report.passed, report.lines()
    assert report.travel == 0


@pytest.mark.parametrize("fault", REQUIRED + [s for s in SWAPS if s not in REQUIRED])
def test_each_single_fault_is_named_on_sim(fault):
    report = _check(f"sim://?wiring={fault}")
    assert not report.passed
    assert {s.line for s in report.suspects} == _lines(fault), report.lines()
    for s in report.suspects:  # LM629 line, its DIP pin, the Uno pin it goes to
        assert f"LM629 {s.line} (pin {PINS[s.line]})" in s.message
        assert f"Uno {UNO[s.line]}" in s.message


def test_the_message_of_the_issue():
    report = _check("sim://?wiring=d5-low")
    assert report.lines()[0].startswith(
        "LM629 D5 (pin 6) reads 0 always: check the wire to Uno D7")


@pytest.mark.parametrize("url", ["sim+emu://", "sim+avr://",
                                 "sim+emu://?usb=uno&fast_baud=1000000"])
def test_the_fault_list_on_the_bridges(url):
    """The Done-when list on the Python bridge and the real firmware, in one process each;
    and behind the Uno's USB chip (its 4.096 ms flush tick): the waits are in the programs."""
    if url.startswith("sim+avr://") and toolchain_missing():
        pytest.skip("AVR toolchain missing")
    wrong = {}
    for fault in REQUIRED:
        report = _check(with_params(url, f"wiring={fault}"))
        if {s.line for s in report.suspects} != _lines(fault) or not all(
                f"Uno {UNO[s.line]}" in s.message for s in report.suspects):
            wrong[fault] = report.lines()
    assert not wrong


def test_the_fault_list_on_the_ft232h():
    """The same list on the emulated FT232H (not in the Done-when list): its pins named."""
    wrong = {}
    for fault in REQUIRED:
        report = _check(f"sim+ftdi://?wiring={fault}")
        if {s.line for s in report.suspects} != _lines(fault) or not all(
                f"FT232H ACBUS{s.line[1]} (breakout C{s.line[1]})" in s.message
                for s in report.suspects):
            wrong[fault] = report.lines()
    assert not wrong


def test_the_ft232h_names_its_own_pins():
    report = _check("sim+ftdi://?wiring=d5-high")
    assert report.lines() == [
        "LM629 D5 (pin 6) reads 1 always: check the wire to FT232H ACBUS5 (breakout C5) "
        "(missing or broken: the line floats high; or a short to +5 V)"]


MOTORS = [f"inertia={i}&load_torque={t}&coulomb={c}"
          for i in (2e-6, 4e-6, 2e-5, 1e-4) for t in (0.0, 0.002) for c in (0.0, 2e-4)]
MOTORS += ["stall=1", "reversed=1", "lines=2000", "friction=1e-4"]


@pytest.mark.parametrize("url", ["sim://", "sim+emu://", "sim+avr://"])
def test_no_false_suspect_over_20_motors(url):
    if url == "sim+avr://" and toolchain_missing():
        pytest.skip("AVR toolchain missing")
    assert len(MOTORS) == 20
    for m in MOTORS:
        with lm629_host.open(f"{url}?{m}") as chip:
            report = check_wiring(chip)
            assert report.passed, (m, report.lines())
            if "load_torque=0.002" not in m:  # no load to turn it: zero drive, no motion
                assert report.travel == 0, m


def test_the_shaft_does_not_move_and_the_chip_is_left_reset():
    with lm629_host.open("sim://") as chip:
        motor = chip.transport.model.motion.motor
        before = motor.angle
        report = check_wiring(chip)
        assert report.passed
        assert abs(motor.angle - before) <= 2
        assert chip.read_status() in (0x84, 0xC4)  # just reset: motor off, nothing loaded


def test_a_suspect_wire_stops_nothing_from_moving_under_a_gain():
    """Even a fault that turns LTRJ into LFIL (D0 low: 1F -> 1E) loads no gain that drives:
    UDF never reaches the chip, so the shaft stays."""
    with lm629_host.open("sim://?wiring=d0-low") as chip:
        motor = chip.transport.model.motion.motor
        before = motor.angle
        check_wiring(chip)
        assert abs(motor.angle - before) <= 2


def test_every_single_suspect_is_considered():
    """One wrong wire on D0-D7: each of the 8 lines stuck low, each stuck high (or open), and
    each of the 8 x 7 / 2 = 28 pairs swapped; each suspect does to a byte on its way to the
    chip what its name says, and nothing else."""
    suspects = dict(suspects_of_data_bus())
    assert len(suspects) == 8 + 8 + 28
    swapped = set()
    for line in range(8):
        bit = 1 << line
        low, high = suspects.pop(f"d{line}-low"), suspects.pop(f"d{line}-high")
        assert [low.to_chip(b) for b in (0x00, 0xFF, bit)] == [0x00, 0xFF ^ bit, 0x00]
        assert [high.to_chip(b) for b in (0x00, 0xFF, 0xFF ^ bit)] == [bit, 0xFF, 0xFF]
        for other in range(line + 1, 8):
            swap = suspects.pop(f"d{line}-d{other}")
            assert [swap.to_chip(b) for b in (bit, 1 << other, bit | 1 << other, 0x00)] == [
                1 << other, bit, bit | 1 << other, 0x00]
            swapped.add((line, other))
    assert suspects == {} and len(swapped) == 28


@pytest.mark.parametrize("fault", ["d0-d1", "d0-d4", "d1-d3"])
def test_diagnosis_opens_no_simulator(fault, monkeypatch):
    """Faults that the spec-based rules alone leave ambiguous (d0-d1 reads like d3-low;
    d1-d3 like d2-d6 or d2-d7) are told apart by the reference readings, which are data: with
    every transport refused, the readings of a miswired bench still name the fault, also
    without the reading a bench lacking the /RST line cannot take."""
    with lm629_host.open(f"sim://?wiring={fault}") as chip:
        readings, exps, hi, _ = run_experiments(chip)

    def refused(*args, **kw):
        raise AssertionError("the diagnosis opened a transport")
    monkeypatch.setattr(Transport, "__init__", refused)
    for rs in (readings, [r for r in readings if r.what != "status at once after /RST"]):
        report = diagnose("uno", rs, exps, hi)
        assert {s.line for s in report.suspects} == _lines(fault), report.lines()


def test_the_wiring_reference_is_current():
    """lm629_host/wiring/reference.py is what tools/gen_wiring_reference.py reads from the
    chip model today, for every single fault and both chips (run it after changing the model
    or the experiments)."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_wiring_reference.py"),
                        "--check"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    faults = {n for n, _ in suspects_of_data_bus()}
    assert set(READINGS) == {"lm628", "lm629"}
    assert all(set(READINGS[v]) == faults for v in READINGS)
    assert all(len(row) == len(WHAT) for v in READINGS for row in READINGS[v].values())


# ---------------------------------------------------------------------- table and drawing
def test_docs_tables_and_drawings_are_current():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_wiring.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert markdown("uno") in (ROOT / "docs" / "bridge.md").read_text()
    assert markdown("ft232h") in (ROOT / "docs" / "ftdi.md").read_text()


def test_table_has_the_pins_on_both_sides():
    rows = {c.chip_line: c for c in connections("uno") if c.chip == 0}
    assert (rows["D5"].adapter_pin, rows["D5"].adapter_detail, rows["D5"].chip_pin) == ("D7", "PD7", 6)
    assert (rows["/RST"].adapter_pin, rows["/RST"].chip_pin) == ("A4", 27)
    assert adapter_pin("ft232h", "/WR") == "FT232H ADBUS3 (breakout D3)"
    assert len(connections("uno", 4)) == 8 + 4 + 4 + 2  # 4 /CS, HI of chips 0 and 1
    with pytest.raises(ValueError):
        connections("ft232h", 3)


@pytest.mark.parametrize("adapter,axes", [("uno", 1), ("nano", 4), ("ft232h", 2)])
def test_the_drawing_names_every_wire_at_both_ends(adapter, axes):
    svg = render(adapter, axes)
    texts = re.findall(r">([^<]+)</text>", svg)
    for c in connections(adapter, axes):
        if c.chip == 0:
            assert f"{c.chip_line} (pin {c.chip_pin})" in texts  # next to the adapter
            assert any(t.startswith(c.adapter_pin) for t in texts)  # next to the chip
        else:
            assert any(t.startswith(f"to {c.chip_label}") for t in texts)
    assert svg.count("10k to +5 V") == 4  # /CS, /RD, /WR, /RST of chip 0


# ---------------------------------------------------------------------- the CLI
def test_cli_wiring_table_svg_and_check(tmp_path):
    from click.testing import CliRunner

    from lm629_host.cli import main
    runner = CliRunner()
    r = runner.invoke(main, ["wiring", "--svg", str(tmp_path / "w.svg")])
    assert r.exit_code == 0, r.output
    assert "D7               PD7                  D5 (pin 6)" in r.output
    assert "D0-D7 (pins 4-11)" in r.output  # the pull-ups: a range of pins, not D0 on pin 4
    assert (tmp_path / "w.svg").read_text().startswith("<svg")
    r = runner.invoke(main, ["--port", "sim+ftdi://", "wiring"])
    assert r.exit_code == 0, r.output
    # the FT232H row for LM629 D5: ACBUS5, breakout label C5, DIP pin 6 (D7..D0 are pins 4..11)
    rows = [ln.split() for ln in r.output.splitlines()]
    assert ["ACBUS5", "C5", "D5", "(pin", "6)", "in/out"] in rows
    r = runner.invoke(main, ["--port", "sim://?wiring=d6-d7", "wiring", "--check"])
    assert r.exit_code == 1
    assert "LM629 D6 (pin 5)" in r.output and "Uno D9" in r.output
    r = runner.invoke(main, ["--port", "sim://", "wiring", "--check"])
    assert r.exit_code == 0 and "every data line passed" in r.output
    r = runner.invoke(main, ["wiring", "--axes", "3", "--adapter", "ft232h"])
    assert r.exit_code == 2


def test_cli_png_without_a_renderer(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from lm629_host.bench import wiring_draw as wiring_svg
    from lm629_host.cli import main
    monkeypatch.setattr(wiring_svg, "png_renderer", lambda: None)
    r = CliRunner().invoke(main, ["wiring", "--png", str(tmp_path / "w.png")])
    assert r.exit_code == 2 and "rsvg-convert" in r.output
    assert not (tmp_path / "w.png").exists()
    r = CliRunner().invoke(main, ["--port", "sim://?wiring=d5-low", "wiring", "--check",
                                  "--png", str(tmp_path / "w.png")])
    assert r.exit_code == 2 and "rsvg-convert" in r.output and "LM629 D5" not in r.output


def test_cli_drawing_into_a_missing_directory_is_bad_usage(tmp_path):
    """An output file that cannot be written is one line and exit 2 (as ``step --csv``),
    checked before the table is printed or the chip is touched, not an internal error."""
    from click.testing import CliRunner

    from lm629_host.cli import main
    for opt in ("--svg", "--png"):
        r = CliRunner().invoke(main, ["wiring", opt, str(tmp_path / "no" / "w.svg")])
        assert r.exit_code == 2, r.output
        assert "does not exist" in r.output and "Uno pin" not in r.output


def test_cli_check_with_svg_still_draws(tmp_path):
    """``--check --svg FILE`` draws too: an option given is never dropped in silence."""
    from click.testing import CliRunner

    from lm629_host.cli import main
    out = tmp_path / "w.svg"
    r = CliRunner().invoke(main, ["--port", "sim://?wiring=d5-low", "wiring", "--check",
                                  "--svg", str(out)])
    assert r.exit_code == 1 and "LM629 D5 (pin 6)" in r.output
    assert out.read_text().startswith("<svg")


# ---------------------------------------------------------------------- a persistent bench
@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_on_a_persistent_bench_from_separate_processes(tmp_path, far_end):
    """``lm629 sim serve`` keeps one chip; the check runs in its own process, the status
    before and after in others.  The shaft does not move: each move experiment's RDRP (counts
    since its /RST) adds up to 0, and the real position after the check's last /RST reads
    within 2 counts of 0; the chip is left reset (motor off)."""
    from served import serve
    with serve(tmp_path, far_end) as bench:
        assert bench.run("reset").returncode == 0
        p = bench.run("wiring", "--check")
        assert p.returncode == 0, p.stdout + p.stderr
        assert "the shaft turned 0 count(s)" in p.stdout
        s = bench.status()
        assert abs(s["real_position"]) <= 2
        assert "MOTOR_OFF" in s["status_flags"]


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_miswired_persistent_bench(tmp_path, far_end):
    from served import serve
    with serve(tmp_path, far_end, "sim://?wiring=d6-d7") as bench:
        p = bench.run("wiring", "--check")
        assert p.returncode == 1
        assert "LM629 D6 (pin 5)" in p.stdout and "Uno D8" in p.stdout
        assert "LM629 D7 (pin 4)" in p.stdout and "Uno D9" in p.stdout


def test_doctor_suggests_the_check_when_busy_is_stuck():
    from click.testing import CliRunner

    from lm629_host.cli import main
    r = CliRunner().invoke(main, ["--port", "sim://?wiring=d0-high", "doctor"])
    assert r.exit_code == 1
    assert "lm629 wiring --check" in r.output
    stuck = r.output
    r = CliRunner().invoke(main, ["--port", "sim://", "doctor"])
    assert "lm629 wiring --check" not in r.output
    # the port's section is all [ok]; whatever else doctor finds on this machine (no FT232H
    # plugged in, say) is the same with either port, and the exit code counts exactly that
    port = r.output[r.output.index("port sim://"):].splitlines()
    assert [ln for ln in port if "[!!]" in ln] == []
    rest = r.output.count("[!!]")
    assert stuck.count("[!!]") > rest
    assert r.exit_code == (1 if rest else 0), r.output
    assert r.output.rstrip().endswith(f"{rest} problem(s) above" if rest else "no problems found")


@pytest.mark.parametrize("fault,says", [
    ("rst", "the pulse does not reach the chip: check /RST (pin 27) to Uno A4"),
    ("reset", "the chip stays in reset (status 00 1.5 ms after /RST)"),
    ("busy", "LM629 D0 (pin 11) reads 1 always"),
])
def test_control_line_faults_are_named(fault, says):
    report = _check(f"sim://?fault={fault}")
    assert not report.passed and says in " ".join(report.lines())
    if fault == "busy":
        assert "CLK pin 26" in report.lines()[0]


@pytest.mark.parametrize(("error", "busy"), [
    (BusyTimeout("RDDP", 5e-3, status=0xC5), True),
    (TransportError("Busy line from the bridge: no answer"), False),  # text says Busy, type not
])
def test_busy_that_never_clears_is_told_by_the_error_type(error, busy):
    """A program ended by a BusyTimeout (and nothing a data wire explains: the chip stays in
    reset) names the busy line too; any other error does not, whatever its text says."""
    with lm629_host.open("sim://?fault=reset") as chip:
        readings, exps, hi, _ = run_experiments(chip)
    # the /RST statuses read 00; every program with a command fails with ``error``
    readings = readings[:3] + [dataclasses.replace(r, got=None, error=str(error), exception=error)
                               for r in readings[3:]]
    report = diagnose("uno", readings, exps, hi)
    lines = " ".join(report.lines())
    assert "the chip stays in reset" in lines
    assert ("busy never clears" in lines) is busy, lines
