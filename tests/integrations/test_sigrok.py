"""The ``lm629`` sigrok protocol decoder, run by sigrok's own tool (``sigrok-cli``) over the VCDs
the simulators write (``vcd=FILE``): on ``sim://`` (the model's strobes), ``sim+avr://`` (the
compiled firmware's port pins in simavr) and ``sim+ftdi://`` (the emulated FT232H's pins), the
decoder's command list equals the host's own program log (its trace), command for command and
word for word; injected protocol violations are each annotated, and a clean run has none.

The decoder's chip facts are checked against ``lm629_host.bus.opcodes``, the one definition.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
from pathlib import Path
from types import ModuleType

import pytest
from sim_urls import available

import lm629_host
from lm629_host.transports.base import BusObserver
from lm629_host.bus import opcodes
from lm629_host.bus.opcodes import Cmd, Status
from lm629_host.bus.program import BusCycle
from lm629_host.sigrok import (
    BUG_1671,
    DECODER,
    Annotation,
    SigrokError,
    commands,
    decode,
    failed,
    vcd_signals,
    warnings,
)

if shutil.which("sigrok-cli") is None:  # pragma: no cover - .ci/run installs it
    if os.environ.get("CI"):
        pytest.fail("sigrok-cli is missing: .ci/run installs Debian's sigrok-cli",
                    pytrace=False)
    pytest.skip("sigrok-cli is not installed (apt-get install sigrok-cli)",
                allow_module_level=True)

#: the simulators, whose bus is drawn three ways: the model's strobes (sim://, and sim+emu://,
#: the Python bridge), the firmware's pins in simavr, the emulated FT232H's pins (the serial
#: links at 1 Mbaud: the link's speed is not the subject)
SIMS = ["sim://", "sim+emu://?baud=1000000", "sim+avr://?baud=1000000", "sim+ftdi://"]
#: a short move: 4 counts/sample at most, 0.03 counts/sample^2 (16.16 words), 300 counts
MOVE = {"velocity": 4 * 65536, "acceleration": 2000}


def _tables() -> ModuleType:
    """The decoder's tables.py, loaded by path (the decoder package imports sigrokdecode,
    which only exists inside sigrok)."""
    spec = importlib.util.spec_from_file_location("lm629_decoder_tables", DECODER / "tables.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_decoder_tables_are_the_opcodes_module():
    t = _tables()
    assert t.COMMANDS == {int(c): (c.name, info.direction.value, info.words)
                          for c, info in opcodes.COMMANDS.items()}
    assert t.STATUS_BITS == tuple((int(f), f.name) for f in Status)
    assert t.SIGNALS_BITS == tuple((int(f), f.name) for f in opcodes.Signals)
    assert t.TRAJECTORY_BITS == tuple((int(f), f.name) for f in opcodes.TrajectoryFlags)
    assert t.FILTER_BITS == tuple((int(f), f.name) for f in opcodes.FILTER_ORDER)
    assert t.INTERRUPTS == int(opcodes.INTERRUPTS)
    # the LTRJ words follow in the chip's order, each parameter's relative flag one bit below
    order = (opcodes.TrajectoryFlags.ACCELERATION, opcodes.TrajectoryFlags.VELOCITY,
             opcodes.TrajectoryFlags.POSITION)
    assert t.TRAJECTORY_ORDER == tuple((int(f), int(f) >> 1, (f.name or "").lower())
                                       for f in order)
    # the word counts the decoder derives equal the host's (every control word)
    for control in range(0x40):
        assert 1 + 2 * sum(1 for bit, _, _ in t.TRAJECTORY_ORDER if control & bit) == \
            1 + opcodes.ltrj_word_count(control)
    for control in range(0x10):
        assert len([b for b, _ in t.FILTER_BITS if control & b]) == opcodes.lfil_word_count(control)


# ---------------------------------------------------------------------------- the host's log
def host_commands(cycles: list[BusCycle], chip: int = 0) -> list[str]:
    """The host's program log (its trace) as ``NAME WORD...`` per command, for one chip."""
    out: dict[int, list[list[str]]] = {}
    current = 0
    for c in cycles:
        if c.kind == "select":
            current = c.value
        elif c.kind == "command":
            try:
                name = Cmd(c.value).name
            except ValueError:
                name = f"{c.value:02X}"
            out.setdefault(current, []).append([name])
        elif c.kind in ("write", "read"):
            out[current][-1].append(f"{c.value:04X}")
    return [" ".join(cmd) for cmd in out.get(chip, [])]


def after_first_reset(annotations: list[Annotation]) -> list[Annotation]:
    """What the bus carried from the script's first /RST on (the FT232H transport measures
    the chip's busy time at open, before the script, with RDSIGS: not the script's)."""
    rst = next(a for a in annotations if a.text.startswith("/RST pulse"))
    return [a for a in annotations if a.start_us >= rst.start_us]


def flow_reset(chip: lm629_host.LM629) -> None:
    chip.reset()


def flow_filter(chip: lm629_host.LM629) -> None:
    chip.reset()
    chip.load_filter(kp=20, ki=2, kd=100, il=50, derivative_interval=2)
    chip.update_filter()


def flow_move(chip: lm629_host.LM629) -> None:
    flow_filter(chip)
    result = chip.move_to(300, **MOVE).wait(timeout=5)
    assert abs(result.position - 300) < 20


def flow_recording(chip: lm629_host.LM629) -> None:
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    trace = chip.record(1e-3, 0.01)
    assert len(list(trace)) >= 9


FLOWS = {"reset": flow_reset, "filter": flow_filter, "move": flow_move,
         "recording": flow_recording}


def _url(base: str, vcd: Path) -> str:
    return f"{base}{'&' if '?' in base else '?'}vcd={vcd}"


@pytest.mark.parametrize("flow", list(FLOWS))
@pytest.mark.parametrize("base", SIMS)
def test_decoder_command_list_is_the_hosts_program_log(base, flow, tmp_path):
    if not available(base):
        pytest.skip(f"{base} is not available here")
    vcd = tmp_path / "bus.vcd"
    cycles: list[BusCycle] = []
    with lm629_host.open(_url(base, vcd), trace=cycles.append) as chip:
        FLOWS[flow](chip)
    assert {"d0", "d7", "cs", "rd", "wr", "ps", "rst", "hi"} <= set(vcd_signals(vcd))
    annotations = decode(vcd)
    got = commands(after_first_reset(annotations))
    want = host_commands(cycles)
    assert want[:2] == ["MSKI 0000", "RSTI 0000"]  # the reset's (AN-706 4.4.1)
    assert got == want
    assert warnings(annotations) == []
    # every command and word of the script went through a busy check the decoder saw
    busy = [a for a in annotations if a.row == "Busy checks"]
    assert busy and all(a.text.startswith(("ready", "busy")) for a in busy)


@pytest.mark.parametrize("base", SIMS)
def test_two_axes_each_chip_decoded_on_its_own_chip_select(base, tmp_path):
    if not available(base):
        pytest.skip(f"{base} is not available here")
    vcd = tmp_path / "bus.vcd"
    cycles: list[BusCycle] = []
    url = _url(base, vcd) + "&axes=2"
    with lm629_host.open_board(url, trace=cycles.append) as board:
        # a bus program starts on chip 0 (Op.SELECT) without a select in the trace: mark it
        class ProgramStarts(BusObserver):
            def program_starting(self, transport, program):
                cycles.append(BusCycle("select", 0))
        board.transport.add_observer(ProgramStarts())
        board.reset()
        x, y = board.axes
        for axis in (x, y):
            axis.load_filter(kp=20)
            axis.update_filter()
        board.move_linear({x: 300, y: -150}, velocity=4 * 65536, acceleration=2000).wait(timeout=5)
    signals = vcd_signals(vcd)
    assert {"cs", "cs1"} <= set(signals)
    for chip in (0, 1):
        annotations = decode(vcd, chip=chip)
        want = host_commands(cycles, chip)
        assert any(w.startswith("LTRJ") for w in want)
        assert commands(after_first_reset(annotations)) == want
        assert warnings(annotations) == []


# ---------------------------------------------------------------------------- violations
def test_injected_violations_each_annotated_and_seen_by_the_chip_too(tmp_path):
    """On ``sim://?strict=0`` the bus-program layer (``LM629.raw``, ``Program``) and the
    transport's own strobes make what a correct host never does; the decoder names each one,
    in order, where the chip model records the ones a chip can notice."""
    vcd = tmp_path / "bus.vcd"
    with lm629_host.open(_url("sim://?strict=0", vcd)) as chip:
        chip.reset()
        t = chip.transport
        model = t.model
        mark = len(model.violations)
        # 1. a write while busy: the LFIL word leaves the chip busy; read the status (busy), then
        #    write the UDF command byte anyway: the chip ignores it
        chip.load_filter(kp=20)
        status = t._read_status()
        assert status & Status.BUSY
        t._write_command(Cmd.UDF)
        # 2. a missing busy check: well after busy cleared, a command byte with no status read
        chip.clock.sleep(200e-6)
        t._write_command(Cmd.UDF)
        # 3. a short LTRJ: its control word announces position, velocity and acceleration (six
        #    words), two follow, then STT (each with its busy check: the bus-program layer)
        chip.raw(Cmd.LTRJ, [0x002A, 0x0000, 0x0064])
        chip.raw(Cmd.STT)
        # 4. a long LTRJ: control word 0002 (position: two words), then a third word
        chip.raw(Cmd.LTRJ, [0x0002, 0x0000, 0x03E8, 0x0005])
        # 5. a data read on a write-only command (its word then written), 6. a read with no
        #    command (LPES has had its word)
        chip.run(chip.program().command(Cmd.LPES).read(1).write(100))
        chip.run(chip.program().read(1))
        seen = list(model.violations[mark:])
    got = warnings(decode(vcd))
    assert len(got) == 6, got
    assert got[0].startswith("command 04 (UDF) while busy")
    assert got[1].startswith("command 04 (UDF) without a busy check")
    assert got[2].startswith("short LTRJ: 3 of 7 words (its control word 002A announces 6)")
    assert got[3].startswith("long LTRJ: a word after the 3 its control word 0002 announces")
    assert got[4].startswith("data read on LPES, a write-only command")
    assert got[5].startswith("read with no command")
    # the chip model saw the ones a chip can: the ignored UDF, the aborted LTRJ, the stray
    # word, the reads in the wrong direction (the missing busy check it cannot see)
    assert any("command 04 written while busy" in v for v in seen)
    assert any("aborts command 1F with 4 word(s) still expected" in v for v in seen)
    assert any("data byte 00 written with no command" in v for v in seen)
    assert any("data read with a write command" in v for v in seen)
    assert any("data read with no command to read" in v for v in seen)


def test_a_vcd_costs_nothing_unless_asked_for(tmp_path):
    """Without vcd= the simulators carry no probe: the model is the plain one and sim:// keeps
    its busy skip; with it, every poll is made (the bus as a bench host makes it)."""
    from lm629_host.sim.model import ChipModel
    from lm629_host.sim.vcd import ProbedBus

    with lm629_host.open("sim://") as chip:
        assert type(chip.transport.model) is ChipModel
        assert chip.transport.skip_known_busy
    with lm629_host.open(f"sim://?vcd={tmp_path / 'bus.vcd'}") as chip:
        assert isinstance(chip.transport.model, ProbedBus)
        assert not chip.transport.skip_known_busy


def test_vcd_option_checked_before_anything_runs(tmp_path):
    with pytest.raises(ValueError, match="vcd_timescale"):
        lm629_host.open(f"sim://?vcd={tmp_path / 'x.vcd'}&vcd_timescale=7")
    with pytest.raises(ValueError, match="vcd_timescale= without vcd"):
        lm629_host.open("sim://?vcd_timescale=10")
    for base in ("sim://", "sim+emu://", "sim+ftdi://"):
        with pytest.raises(ValueError, match="the directory .* does not exist"):
            lm629_host.open(f"{base}?vcd={tmp_path / 'missing' / 'bus.vcd'}")


def test_only_sigrok_bug_1671_abort_is_forgiven(tmp_path):
    """Debian 12's libsigrokdecode aborts at finalization after a decoder ran (sigrok bug 1671):
    sigrok's own ``parallel`` decoder shows it here, after printing its whole decode.  That
    abort, exactly, is the tool's; a missing file or a decoder error is a failure."""
    import subprocess

    vcd = tmp_path / "bus.vcd"
    with lm629_host.open(f"sim://?vcd={vcd}") as chip:
        chip.reset()
    r = subprocess.run(["sigrok-cli", "-I", "vcd", "-i", str(vcd), "-P", "parallel:clk=wr:d0=d0"],
                       capture_output=True, text=True, timeout=120)
    if r.returncode:  # the bug, where the installed libsigrokdecode has it: SIGABRT
        assert r.returncode == -6 and BUG_1671 in r.stderr
    # the decode was printed whole before the abort: D0 at the reset's six /WR strobes (1C,
    # 00 00, 1D, 00 00), each item printed at the next edge, so the last one never
    assert [line.split()[-1] for line in r.stdout.splitlines()] == ["0", "0", "0", "1", "0"]
    assert not failed(r.returncode, r.stderr)
    assert not failed(134, BUG_1671)  # the same abort seen through a shell
    assert failed(-6, "Fatal Python error: Segmentation fault")
    assert failed(1, BUG_1671)
    with pytest.raises(SigrokError):
        decode(vcd, decoders=tmp_path)  # no lm629 decoder there: sigrok-cli fails


def test_each_data_word_needs_its_own_busy_check(tmp_path):
    """A status read clears the way for one transfer only: LFIL's control word written after a
    status read, then its kp word with no status read between, is a word written without a
    busy check (a decoder that kept the last status for every later transfer would pass it)."""
    vcd = tmp_path / "bus.vcd"
    with lm629_host.open(_url("sim://?strict=0", vcd)) as chip:
        chip.reset()
        t = chip.transport
        chip.clock.sleep(200e-6)
        assert not t._read_status() & Status.BUSY
        t._write_command(Cmd.LFIL)
        chip.clock.sleep(200e-6)
        assert not t._read_status() & Status.BUSY
        t._write_word(0x0008)  # control word: kp follows
        chip.clock.sleep(200e-6)  # busy long over, but nothing read it
        t._write_word(20)
    got = warnings(decode(vcd))
    assert len(got) == 1 and got[0].startswith("data word without a busy check before it"), got
