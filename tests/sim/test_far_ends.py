"""The simulated far ends behave as hardware does: the firmware release both report, a board
with chips on chip selects that are not contiguous, the STT spacing of a far-side shaped move,
and a firmware that a wait for a status bit that never comes cannot leave deaf."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

import lm629_host
from lm629_host.bridge.protocol import (
    FIRMWARE_VERSION,
    Frame,
    FrameReader,
    FrameType,
    encode_frame,
)
from lm629_host.bus.opcodes import Cmd
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.shapes import SCurve, ShapedMove
from lm629_host.chip.shapes import plan as plan_shape
from lm629_host.physics.pid import sample_period_s
from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
from lm629_host.sim.build import build_bus
from lm629_host.transports.link import LinkTransport
from lm629_host.transports import open_transport

from served import serve


def test_the_python_far_end_reports_the_firmware_release_it_emulates():
    """HELLO_REPLY of the Python far end and of the compiled firmware carry the one version
    kept in bridge/protocol/constants.py (the docs tie FAILSAFE and PROFILE to firmware 1.4)."""
    assert FIRMWARE_VERSION >= (1, 4, 0)
    emu = open_transport("sim+emu://")
    try:
        assert emu.info is not None and emu.info.firmware == FIRMWARE_VERSION
    finally:
        emu.close()


@pytest.mark.usefixtures("firmware_built")
def test_the_firmware_reports_the_same_release():
    avr = open_transport("sim+avr://")
    try:
        assert avr.info is not None and avr.info.firmware == FIRMWARE_VERSION
    finally:
        avr.close()


# ---------------------------------------------------------------------------------- cs 0 and cs 2
def _gapped_board() -> tuple[LinkTransport, BridgeEmulator, list[LM629]]:
    """Two chips on chip selects 0 and 2 of the Python far end, nothing on 1; failsafe 0.5 s."""
    model = build_bus("sim://?axes=2")
    emu = BridgeEmulator(model, selects=(0, 2))
    t = LinkTransport(EmuPipe(emu), "sim+emu://?failsafe=0.5")
    axes = [LM629(t, axis=k) for k in (0, 2)]
    for ax in axes:
        ax.reset()
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
    return t, emu, axes


def test_a_trip_stops_the_chips_on_both_sides_of_an_empty_chip_select():
    """The failsafe's scan reads every chip select's status and stops those that answer: cs 1
    floats (FF), cs 2 still has a chip and must be stopped (the scan goes past the gap)."""
    t, emu, axes = _gapped_board()
    for ax in axes:  # 2 counts/sample after a 51 ms ramp
        ax.load_trajectory(acceleration=655, velocity=131072, velocity_mode=True, start=True)
    t.clock.sleep(0.3)
    assert [ax.read_real_velocity() for ax in axes] == [2, 2]
    chips = lm629_host.sim.model.chips_of(emu.model)
    t.pipe.read(2.0)  # the host goes silent: the far end runs on alone
    fs = emu.failsafe
    assert fs.tripped and fs.chips == 0b101 and fs.silent_ms == 500
    for c in chips:  # both shafts at rest, held by the PID (abrupt stop)
        before = c.motion.real_position
        emu.model.advance(0.05)
        assert c.motion.real_position == before
    t.close()


def test_a_far_end_refuses_selects_it_cannot_wire():
    model = build_bus("sim://?axes=2")
    with pytest.raises(ValueError, match="selects=\\(0, 4\\)"):
        BridgeEmulator(model, selects=(0, 4))
    with pytest.raises(ValueError, match="selects=\\(1, 1\\)"):
        BridgeEmulator(model, selects=(1, 1))


# ---------------------------------------------------------------------------------- shaped moves
def _stt_log(chip: LM629) -> list[int]:
    """Model ticks of every STT the chip executes from now on."""
    model = chip.transport.model
    stts: list[int] = []
    write = model.write_command

    def logged(byte: int) -> None:
        if byte == Cmd.STT:
            stts.append(model.tick)
        write(byte)

    model.write_command = logged  # type: ignore[method-assign]  # a spy on the chip's command strobe
    return stts


def _far_shaped_move_handed_over_late(url: str, late_s: float):
    """A 20000-count S-curve in 50 ms pieces whose STT went out, the host then ``late_s`` late
    before it hands the rest to the bridge (what ``move_profile`` does, split here to put the
    pause between): (chip, plan, move, the chip's STT ticks)."""
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    stts = _stt_log(chip)
    plan = plan_shape(SCurve(100000, 1e6, 3e7), 20000, sample_period_s(chip.clock_hz), 0.05)
    move = ShapedMove(chip.move_to(20000, velocity=plan.pieces[0].velocity,
                                   acceleration=plan.acceleration), plan, far=True)
    chip.clock.sleep(late_s)
    move.schedule_far(chip.axis, chip.update_interval)
    return chip, plan, move, stts


@pytest.mark.parametrize("url", ["sim+emu://", "sim+emu://?baud=0"])
def test_a_far_side_shaped_move_survives_a_host_late_past_its_first_piece(url):
    """Pieces 50 ms apart; the host is 55 ms late (a GC pause, a busy machine) between the
    move's STT and handing the rest to the bridge (what ``move_profile`` does, split here to
    put the pause between), so the first piece's time has passed: it goes out 10 ms after the
    schedule starts (never at once, nor at a negative time), the others at their times, every
    STT at least 10 ms after the one before, and the move lands on its target."""
    chip, plan, move, stts = _far_shaped_move_handed_over_late(url, 0.055)
    result = move.wait()
    assert chip.read_desired_position() == 20000 and abs(result.error) <= chip.move_rules.tolerance
    gaps = [(b - a) / chip.transport.model.clock_hz for a, b in zip(stts, stts[1:])]
    assert len(gaps) == len(plan.pieces) - 1 and min(gaps) >= 0.010, gaps
    assert 0.055 + 0.010 <= gaps[0] < 0.055 + 0.010 + 0.010  # 10 ms after PROFILE came
    assert abs(gaps[1] - 0.050) < 1e-3  # the rest keep their spacing: the shape delayed whole
    chip.close()


@pytest.mark.parametrize("late_s", [0.13, 0.175])
def test_a_far_side_shaped_move_survives_a_host_late_past_several_pieces(late_s):
    """Pieces 50 ms apart and the host late past two or three of them before it hands the rest
    to the bridge: the schedule moves later as a whole (the chip ran the first piece's slow
    velocity meanwhile), its first piece 10 ms after it arrives and every piece at its planned
    spacing, never several at the same time (the bridge refuses pieces closer than 10 ms:
    BAD_PROFILE) nor the plan's slow end while the chip is still far from its target (a
    crawl that never lands in time); the move lands."""
    chip, plan, move, stts = _far_shaped_move_handed_over_late("sim+emu://", late_s)
    result = move.wait()
    assert chip.read_desired_position() == 20000 and abs(result.error) <= chip.move_rules.tolerance
    gaps = [(b - a) / chip.transport.model.clock_hz for a, b in zip(stts, stts[1:])]
    assert sum(1 for p in plan.pieces[1:] if p.t < late_s) >= 2  # late past two pieces or more
    assert len(gaps) == len(plan.pieces) - 1, gaps  # every piece went out
    assert late_s + 0.010 <= gaps[0] < late_s + 0.020, gaps  # 10 ms after PROFILE came
    assert all(abs(g - 0.050) < 1e-3 for g in gaps[1:]), gaps  # the plan's spacing
    chip.close()


def test_a_piece_that_went_out_late_pushes_the_next_to_10_ms_after_it():
    """Pieces 10 ms apart (the least AN-706 4.6.2 allows) while the host polls the move: a
    piece the bridge issues late (it was running the host's program) must not bring the next
    STT within 10 ms of its own (the chip would abort its trajectory calculation)."""
    chip = lm629_host.open("sim+emu://")
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    stts = _stt_log(chip)
    move = chip.move_profile(20000, SCurve(200000, 2e6, 1e8), piece_s=0.01)
    assert move.far
    move.wait()
    gaps = [(b - a) / chip.transport.model.clock_hz for a, b in zip(stts, stts[1:])]
    assert len(gaps) == len(move.plan.pieces) - 1
    assert min(gaps) >= 0.010, gaps
    assert move.far_state is not None and move.far_state.late_max_s > 0  # one did go out late
    chip.close()


# ---------------------------------------------------------------------------------- deaf firmware
@pytest.mark.usefixtures("firmware_built")
def test_a_host_byte_ends_a_wait_that_can_never_match():
    """A RUN whose WAIT_STATUS waits 65.5 s for mask 0 (no status matches it) from a host that
    then gave up: the next HELLO is answered at once, not after the wait (the firmware's deaf
    spell after random frames; "is the firmware flashed?" to the next client)."""
    from lm629_host.sim.avr import AvrPipe, AvrSim

    sim = AvrSim(build_bus("sim://"))
    pipe = AvrPipe(sim)
    wait = bytes((0, 0, 0, 0x08, 0x00, 0xFF, 0xFF))  # cs 0, default busy timeout, WAIT_STATUS
    pipe.write(encode_frame(FrameType.RUN, 1, wait))
    sim.run_for(0.02)
    assert pipe.read(0.0) == b""  # still waiting
    t0 = sim.now
    pipe.write(encode_frame(FrameType.HELLO, 2))
    reader, got = FrameReader(), []
    while sim.now - t0 < 0.1 and not any(f.type == FrameType.HELLO_REPLY for f in got):
        got += [f for f in reader.feed(pipe.read(0.01)) if isinstance(f, Frame)]
    assert [f.type for f in got] == [FrameType.RUN_REPLY, FrameType.HELLO_REPLY]
    assert sim.now - t0 < 0.01
    pipe.close()


def test_a_host_byte_ends_a_wait_on_the_python_far_end_in_process():
    """The same on sim+emu://'s in-process line: a RUN whose WAIT_STATUS waits 65.5 s for
    mask 0, and a HELLO right behind it (a script killed after its far-side wait, the next
    process opening the line): the HELLO's byte ends the wait, as the firmware's UART byte
    does; both replies come within the two frames' wire time at 1 Mbaud, not after the wait
    (found by the crossings machine: the next open took the whole 0.25 s wait it interrupted)."""
    emu = BridgeEmulator(build_bus("sim://"))
    pipe = EmuPipe(emu, baud=1_000_000)
    wait = bytes((0, 0, 0, 0x08, 0x00, 0xFF, 0xFF))  # cs 0, default busy timeout, WAIT_STATUS
    t0 = pipe.clock.now()
    pipe.write(encode_frame(FrameType.RUN, 1, wait))
    pipe.write(encode_frame(FrameType.HELLO, 2))
    reader, got = FrameReader(), []
    while pipe.clock.now() - t0 < 0.1 and not any(f.type == FrameType.HELLO_REPLY for f in got):
        got += [f for f in reader.feed(pipe.read(0.01)) if isinstance(f, Frame)]
    assert [f.type for f in got] == [FrameType.RUN_REPLY, FrameType.HELLO_REPLY]
    assert pipe.clock.now() - t0 < 0.005, pipe.clock.now() - t0


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_host_byte_ends_a_long_wait_on_a_served_far_end(tmp_path, far_end):
    """Served (``lm629 sim serve --pty``, in real time), both far ends: a client's RUN waits
    65.5 s for mask 0 and the client gives up; 0.3 s later the next client's HELLO ends the
    wait and is answered at once (the RUN's reply first), as the firmware does (PROTOCOL.md,
    WAIT_STATUS).  The Python far end used to run the whole wait before it read a byte."""
    import serial

    wait = bytes((0, 0, 0, 0x08, 0x00, 0xFF, 0xFF))  # cs 0, default busy timeout, WAIT_STATUS
    with serve(tmp_path, far_end) as bench, serial.Serial(str(bench.link), 115200,
                                                          timeout=0.05) as port:
        port.write(encode_frame(FrameType.HELLO, 1))  # a far end up and answering first
        reader, got = FrameReader(), []
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not got:
            got += [f for f in reader.feed(port.read(64)) if isinstance(f, Frame)]
        assert [f.type for f in got] == [FrameType.HELLO_REPLY]
        port.write(encode_frame(FrameType.RUN, 2, wait))
        time.sleep(0.3)
        assert port.read(64) == b""  # still waiting
        t0 = time.monotonic()
        port.write(encode_frame(FrameType.HELLO, 3))
        got = []
        while time.monotonic() - t0 < 10 and len(got) < 2:
            got += [f for f in reader.feed(port.read(64)) if isinstance(f, Frame)]
        heard_s = time.monotonic() - t0
        assert [(f.type, f.seq) for f in got] == [(FrameType.RUN_REPLY, 2),
                                                  (FrameType.HELLO_REPLY, 3)]
        # answered within the far end's look at the line and the round trip, not 65 s later
        assert heard_s < 2.0


# ---------------------------------------------------------------------------------- sim+avr://
_RSS_LOOP = """
import gc
from lm629_host.transports import open_transport
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * 4096
for _ in range(20):  # the allocator's pools settle
    open_transport("sim+avr://").close()
gc.collect()
before = rss()
for _ in range(300):
    open_transport("sim+avr://").close()
gc.collect()
print(rss() - before)
"""


@pytest.mark.usefixtures("firmware_built")
def test_300_opens_of_sim_avr_grow_the_process_by_less_than_a_megabyte():
    """Each open made a simavr AVR and each close freed it: the harness first leaked the
    sections simavr's ELF loader read (6 MB over 300), then simavr 1.6's own, about 5 KB an
    AVR that ``avr_terminate`` never frees (IRQ names and pools, valgrind): 1.2 MB over 300.
    Now a closed sim's AVR is powered on again by the next open of the same image, and what
    300 open/close cycles add (about 280 KiB measured, most of it the link's Python side, as
    on ``sim+emu://``) stays under 1 MB.  Memory, not time: a busy machine does not change it."""
    out = subprocess.run([sys.executable, "-c", _RSS_LOOP], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    assert int(out) < 1 << 20, f"RSS grew by {int(out) / 1024:.0f} KiB over 300 cycles"


def _not_avr_images(tmp_path: Path) -> list[Path]:
    text = tmp_path / "notes.txt"
    text.write_text("not firmware\n" * 100)
    return [Path("/etc/passwd"), text, Path(lm629_host.__file__).parent / "data" / "lm629_bridge.hex",
            Path(sys.executable).resolve()]  # an ELF, for this machine's CPU


def test_sim_avr_refuses_what_is_not_an_avr_elf_before_simavr_starts(tmp_path):
    """simavr's loader spun at 100 % CPU on a text file or the shipped .hex, deaf to Ctrl-C:
    each is refused with a ValueError naming the file and why, before anything is built."""
    for path in _not_avr_images(tmp_path):
        with pytest.raises(ValueError, match=f"firmware={path}: .*give the .elf"):
            open_transport(f"sim+avr://?firmware={path}")



def _crashing_image(tmp_path: Path) -> Path:
    """The bridge's ELF with every instruction 0xFFFF (SBRS r31, 7): the AVR runs off the end
    of its flash, which simavr calls a crash, before the UART is ever on."""
    from lm629_host.sim.harness import firmware_path

    elf = bytearray(firmware_path().read_bytes())
    shoff = int.from_bytes(elf[0x20:0x24], "little")
    size, count, names = (int.from_bytes(elf[a:a + 2], "little") for a in (0x2E, 0x30, 0x32))
    headers = [elf[shoff + i * size:shoff + (i + 1) * size] for i in range(count)]
    strtab = int.from_bytes(headers[names][16:20], "little")
    for h in headers:
        name_at = strtab + int.from_bytes(h[0:4], "little")
        if elf[name_at:name_at + 6] == b".text\0":
            offset, length = int.from_bytes(h[16:20], "little"), int.from_bytes(h[20:24], "little")
            elf[offset:offset + length] = b"\xff" * length
    path = tmp_path / "crashes.elf"
    path.write_bytes(elf)
    return path


@pytest.mark.usefixtures("firmware_built")
def test_a_firmware_that_crashes_before_its_uart_is_on_is_refused_not_spun_on(tmp_path):
    """The harness ran the AVR until the firmware enabled its receiver or a million cycles had
    passed; a crashed AVR's cycle count stands still, so an image that crashed at boot (or an
    AVR powered on again with a broken flash) spun at 100 % CPU for ever.  Now the open fails
    at once, naming the file and the cycle of the crash."""
    path = _crashing_image(tmp_path)
    code = ("from lm629_host.transports import open_transport\n"
            f"try:\n    open_transport('sim+avr://?firmware={path}')\n"
            "except Exception as exc:\n    print(type(exc).__name__, exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60).stdout
    assert out.startswith("HarnessError") and f"{path} crashed at AVR cycle" in out, out
    assert "before it enabled its UART receiver" in out

@pytest.mark.usefixtures("firmware_built")
def test_the_command_line_refuses_a_firmware_that_is_not_an_avr_elf_in_one_line(tmp_path):
    exe = Path(sys.executable).parent / "lm629"
    for path in _not_avr_images(tmp_path)[1:3]:
        started = time.monotonic()
        p = subprocess.run([str(exe), "--port", f"sim+avr://?firmware={path}", "status"],
                           capture_output=True, text=True, timeout=30)
        took = time.monotonic() - started
        assert p.returncode == 2, p.stderr
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and f"firmware={path}" in lines[0], p.stderr
        assert took < 10, took  # an interpreter's start on a busy machine; it hung before
