"""The compiled bridge firmware in simavr, driven with raw link frames (the golden vectors of
firmware_bridge/golden_frames.txt) and through ``sim+avr://``: what reaches the chip model,
the bus timing the harness checks, /RST, WAIT, busy timeout, HI, resynchronisation, 1 Mbaud."""

from __future__ import annotations

import random

import gc
import os
from pathlib import Path

import pytest

import lm629_host

from lm629_host import LM629, BusyTimeout
from lm629_host.sim.avr import CPU_HZ, STATUS, AvrPipe, AvrSim
from lm629_host.sim.harness import IDLE_AVRS
from lm629_host.bridge.protocol import FrameReader, FrameType, Result, RunReply, encode_frame
from lm629_host.transports.link import LinkTransport
from lm629_host.bus.opcodes import Cmd, Status
from lm629_host.bus.program import Program
from lm629_host.transports import open_transport
from lm629_host.sim.build import build_model


pytestmark = pytest.mark.usefixtures("firmware_built")

#: the baud rate the AVR really runs at (16 MHz / 8 / (UBRR + 1) with U2X); simavr sends 11
#: bit times per byte
WIRE_BAUD = {115200: 16e6 / 8 / 17, 1_000_000: 1e6}
GOLDEN = Path(__file__).resolve().parents[2] / "firmware_bridge" / "golden_frames.txt"


def golden() -> dict[str, bytes]:
    out = {}
    for line in GOLDEN.read_text().splitlines():
        if line and not line.startswith("#"):
            name, _dec, enc = line.split("\t")
            out[name] = bytes.fromhex(enc)
    return out


def sim(url: str = "sim://?record=1", **kw) -> AvrSim:
    return AvrSim(build_model(url), **kw)


def exchange(s: AvrSim, wire: bytes, timeout_s: float = 0.05) -> bytes:
    """Write ``wire``, run until a reply frame is out (or the timeout); the bytes sent."""
    pipe = AvrPipe(s)
    pipe.write(wire)
    return pipe.read(timeout_s)


def test_golden_hello_answered_byte_for_byte():
    g = golden()
    s = sim()
    assert exchange(s, g["hello"]) == g["hello_reply"]
    assert exchange(s, g["ping"]) == g["pong"]
    s.close()


def test_golden_an693_filter_program_reaches_the_chip_once():
    """AN-693 table 4's filter module as the golden raw RUN frame: the firmware answers OK with
    the model's own last status and HI line, and the model saw LFIL 0008 000A, UDF exactly
    once, although the same frame was sent twice (the second answer comes from the cache)."""
    g = golden()
    s = sim()
    first = exchange(s, g["run_an693_filter"])
    frames = list(FrameReader().feed(first))
    assert len(frames) == 1 and (frames[0].type, frames[0].seq) == (FrameType.RUN_REPLY, 0x2A)
    r = RunReply.decode(frames[0].payload)
    assert (r.result, r.index, r.statuses, r.words) == (Result.OK, 0xFF, (), ())
    assert (r.last_status, r.hi) == (s.model.status, int(s.model.hi))
    assert exchange(s, g["run_an693_filter"]) == first
    assert s.model.history == [(Cmd.LFIL, (0x0008, 0x000A)), (Cmd.UDF, ())]
    assert s.violations() == (0, "")


def test_golden_zero_bytes_and_unknown_request():
    g = golden()
    s = sim()
    reply = FrameReader()
    frames = list(reply.feed(exchange(s, g["run_zero_bytes"])))
    assert len(frames) == 1 and frames[0].type == FrameType.RUN_REPLY
    r = RunReply.decode(frames[0].payload)
    assert r.result == Result.OK and len(r.words) == 1  # RDSIGS after LPEI 0000 and WAIT 256 us
    assert s.model.history == [(Cmd.LPEI, (0,)), (Cmd.RDSIGS, ())]
    assert exchange(s, encode_frame(0x70, 0x33)) == g["error_reply"]  # no such request type


def test_no_host_byte_lost_when_the_uart_fifo_fills():
    """Every host byte reaches the simulated UART, none dropped although the largest RUN sent
    twice back to back (2 x 254 bytes) overflows simavr's 64-byte FIFO: the harness raises
    bytes only while the UART says XON.  The program (81 words, no command) reached the chip
    once: 162 data bytes refused by the model; the repeat was answered from the cache."""
    g = golden()
    s = sim("sim://?strict=0")
    pipe = AvrPipe(s)
    pipe.write(g["run_max_frame"] * 2)
    reader, replies = FrameReader(), []
    while len(replies) < 2:
        chunk = pipe.read(0.1)
        assert chunk, "no reply"
        replies += list(reader.feed(chunk))
    assert replies[0] == replies[1] and replies[0].seq == 0xFE
    n, _xon, _xoff = s.uart_counts()
    assert n == 2 * len(g["run_max_frame"])
    assert len(s.model.violations) == 162 and s.model.history == []


def test_firmware_resynchronises_after_garbage_and_ignores_bad_crc():
    g = golden()
    s = sim()
    bad = bytearray(g["hello"])
    bad[2] ^= 0x10
    assert exchange(s, bytes(bad), 0.01) == b""  # never answered: the host retries
    t0 = s.now
    junk = bytes(range(1, 256)) * 2 + b"\x00\x00\x07\x00"  # overlong, empty, short frames
    assert exchange(s, junk + g["hello"], 0.2) == g["hello_reply"]
    # the reply counts from when its last byte enters the transmitter: one byte less on the wire
    wire = (len(junk) + len(g["hello"]) + len(g["hello_reply"]) - 1) * 11 / WIRE_BAUD[115200]
    assert wire <= s.now - t0 < wire + 1e-3


def test_reads_need_the_access_time_the_firmware_waits():
    """The harness drives a read byte only after the chip's access time (4 AVR cycles: 180 ns
    rounded up plus the PINx synchroniser); the firmware samples 8 cycles after /RD falls, so
    reads stay right up to an access time of 8 cycles, and go wrong beyond: the harness does
    model the access time, and the firmware has twice the margin it needs."""
    def rdsigs(access: int) -> tuple[int, int]:
        s = sim("sim://?strict=0", strict=False)
        s.set_access_cycles(access)
        chip = LM629(LinkTransport(AvrPipe(s), "sim+avr://", baud=115200))
        try:
            chip.transport.execute(Program().command(Cmd.RDSIGS).read(1))
            word = chip.transport.execute(Program().command(Cmd.RDSIGS).read(1)).words[0]
        except BusyTimeout:
            word = -1  # a status byte read wrong looks busy
        return word, s.model.signals

    for access in (4, 8):
        word, signals = rdsigs(access)
        assert word == signals
    word, signals = rdsigs(9)
    assert word != signals


def test_bus_timing_clean_over_a_whole_scenario():
    """Strict harness (any chip timing minimum broken raises): reset, filter, trajectory,
    start, position reads; nothing reported."""
    t = open_transport("sim+avr://?record=1")
    chip = LM629(t)
    chip.reset()
    chip.load_filter(kp=30, kd=200, il=100)
    chip.update_filter()
    chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
    chip.load_trajectory(acceleration=0x2000, velocity=4 << 16, position=2000, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=2.0)
    assert chip.read_desired_position() == 2000
    chip.clock.sleep(0.2)  # let the servo settle on the target (sim:// reads 1998 then)
    assert abs(chip.read_real_position() - 2000) <= 5
    assert t.sim.violations() == (0, "")
    t.close()


@pytest.mark.parametrize("clock", [1_000_000, 8_000_000])
def test_reset_pulse_long_enough_at_any_chip_clock(clock):
    """/RST is held 10 us: at least 8 chip clocks from 1 MHz (10 clocks) up."""
    t = open_transport(f"sim+avr://?clock={clock}")
    LM629(t).reset()
    low = t.sim.reset_low_clocks
    assert low and min(low) >= 8 and min(low) >= 10e-6 * clock - 1
    t.close()


def test_wait_and_busy_timeout_timed_by_the_firmware():
    """WAIT 1500 us lasts 1.5 ms of AVR time between its neighbouring strobes (timer with
    4 us ticks, never shorter); a chip
    stuck busy is given up after busy_timeout_us (1000 us here) plus at most one tick."""
    s = sim()
    pipe = AvrPipe(s)
    t = LinkTransport(pipe, "sim+avr://", baud=115200)
    s.bus_log = []
    t.execute(Program().status().wait(1500).status())
    (k0, _, c0), (k1, _, c1) = s.bus_log
    assert k0 == k1 == STATUS
    # never shorter; longer by at most two 4 us timer ticks and the interpreter (~10 us)
    assert 1500e-6 <= (c1 - c0) / CPU_HZ < 1500e-6 + 25e-6
    wire = (4 + 4 + 9 + 2) * 11 / WIRE_BAUD[115200]  # request and reply bytes

    s2 = sim("sim://?fault=busy")
    t2 = LinkTransport(AvrPipe(s2), "sim+avr://", baud=115200)
    p = Program(busy_timeout_s=1e-3).command(Cmd.STT)
    t0 = s2.now
    with pytest.raises(BusyTimeout):
        t2.execute(p)
    assert 1e-3 <= s2.now - t0 < 1e-3 + 2 * wire + 200e-6


def test_hi_line_is_reported():
    """HI follows the model: a command error with its interrupt unmasked raises HI."""
    t = open_transport("sim+avr://?strict=0")
    chip = LM629(t)
    chip.reset()
    assert t.execute(Program().status()).hi is False
    t.execute(Program().command(Cmd.MSKI).write(int(Status.COMMAND_ERROR)))
    t.execute(Program().command(0x3F))  # not an LM629 command: sets the command-error bit
    assert t.model.hi
    assert t.execute(Program().status()).hi is True
    t.close()


def test_one_megabaud_is_faster_per_poll():
    """The 1,000,000 baud image (U2X, UBRR 1) works and polls faster than 115200."""
    per = {}
    for baud in (115200, 1_000_000):
        t = open_transport(f"sim+avr://?baud={baud}")
        chip = LM629(t)
        chip.reset()
        t0 = t.clock.now()
        for _ in range(20):
            chip.read_real_position()
        per[baud] = (t.clock.now() - t0) / 20
        t.close()
    assert per[1_000_000] < per[115200] / 4


def test_bad_url_values():
    with pytest.raises(ValueError, match="baud=9600"):
        open_transport("sim+avr://?baud=9600")
    with pytest.raises(ValueError, match="not a number"):
        open_transport("sim+avr://?baud=fast")
    with pytest.raises(ValueError, match="unknown simulator parameter"):
        open_transport("sim+avr://?bogus=1")
    with pytest.raises(Exception, match="not found"):
        open_transport("sim+avr://?firmware=/nonexistent.elf")
    assert CPU_HZ == 16_000_000


def test_firmware_switches_its_uart_on_set_baud_and_goes_back_when_nothing_comes():
    """SET_BAUD 1000000 to the 115200 image: UBRR0 goes from 16 to 1 once the reply has left;
    with no good frame at the new rate within the window (250 ms) it goes back to 16.  With
    one, it stays (sim+avr://?fast_baud=1000000: the host switches, then polls at 1 Mbaud)."""
    from lm629_host.bridge.protocol import FrameType
    from lm629_host.transports import open_transport

    t = open_transport("sim+avr://?baud=115200&failsafe=0")  # nothing sent: no feeds either
    UBRR0L = 0xC4
    assert t.sim.peek(UBRR0L) == 16
    frame = t._exchange(FrameType.SET_BAUD, (1_000_000).to_bytes(4, "big"), 0.05, "SET_BAUD", 0)
    assert frame.type == FrameType.BAUD_REPLY and frame.payload == b"\x00" + (1_000_000).to_bytes(4, "big")
    t.clock.sleep(0.01)
    assert t.sim.peek(UBRR0L) == 1
    t.clock.sleep(0.3)
    assert t.sim.peek(UBRR0L) == 16  # nothing came: back to 115200
    frame = t._exchange(FrameType.SET_BAUD, (230400).to_bytes(4, "big"), 0.05, "SET_BAUD", 0)
    assert frame.payload[0] == 7 and t.sim.peek(UBRR0L) == 16  # BAD_BAUD: 3.5 % off
    t.close()
    t = open_transport("sim+avr://?baud=115200&fast_baud=1000000&record=1")
    assert t.baud == 1_000_000 and t.sim.peek(UBRR0L) == 1
    t.clock.sleep(0.3)
    assert t.sim.peek(UBRR0L) == 1  # a good frame came at the new rate: it stays
    chip = LM629(t)
    chip.reset()
    t0 = t.clock.now()
    chip.read_real_position()
    assert t.clock.now() - t0 < 400e-6  # a 1 Mbaud round trip, not 115200's 2 ms
    t.close()


def test_the_firmwares_own_counters_can_be_read():
    """The fault tests check the far end's counters only when they can be read (avr-nm finds
    ``link`` with the layout avr.py expects): a layout change must not skip those checks
    silently."""
    import shutil

    if shutil.which("avr-nm") is None:
        pytest.skip("no avr-nm")
    t = open_transport("sim+avr://?baud=1000000")
    counters = t.sim.link_counters()
    assert counters is not None, "link_t's layout differs from avr._LINK_T_SIZE"
    chip = LM629(t)
    chip.reset()
    counters.reset()
    chip.read_real_position()
    chip.read_real_position()
    assert (counters.frames, counters.runs, counters.bad_frames) == (2, 2, 0)
    t.close()


# ------------------------------------------------------------------ an AVR used again
def _power_on_state(s: AvrSim) -> dict[str, object]:
    """All a new AVR's state the harness can see: the cycle count, RAM and registers, flash,
    EEPROM, every IRQ's level and flags, and what the harness queued or counted."""
    return {"cycle": s.cycle, "data": s.memory("data"), "flash": s.memory("flash"),
            "eeprom": s.memory("eeprom"), "irqs": s.irq_state(), "output": s.take_output(),
            "pending input": s._lib.fitl_pending_input(s._h), "bus cycles": s.bus_cycles,
            "uart": s.uart_counts(), "violations": s.violations()}


def _leave_a_mess(url: str) -> None:
    """A session that leaves the bridge far from power-on: switched to 1 Mbaud, programs in
    its RUN_CODE cache, an axis moving, its failsafe tripped by a silent host, bytes left in
    both directions; and the AVR's RAM, flash and EEPROM scribbled on (as a firmware that
    wrote them would)."""
    chip = lm629_host.open(url)
    t = chip.transport
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=60000, velocity_mode=True, start=True)
    chip.clock.sleep(0.2)
    assert chip.read_real_position() > 0
    end = t.clock.now() + 0.2
    while t.clock.now() < end:
        t.pipe.read(0.01)
    assert t.failsafe_state().tripped
    s = t.sim
    s.write(bytes(range(1, 40)))  # half a frame into the UART, never answered
    s.run_for(0.001)
    for which, address in (("data", 0x100), ("data", 0x8FF), ("flash", 0x10), ("flash", 0x7FFF),
                           ("eeprom", 0), ("eeprom", 0x3FF)):
        s.poke(which, address, s.memory(which)[address] ^ 0x5A)
    chip.transport.close()


def test_a_closed_sims_avr_powers_on_again_as_a_new_one():
    """An open/close no longer makes and frees a simavr AVR (simavr 1.6 leaks part of each):
    the next open of the same image takes the closed one and powers it on again.  After a
    session that left it mid-move, tripped, at 1 Mbaud, with bytes half-sent and its memories
    scribbled on, it is the same as an AVR made new beside it: RAM, registers, flash and
    EEPROM as the image says, every IRQ as made, the cycle count, the harness's queues and
    counters; and the same frames then give the same bytes at the same cycles and the same
    bus cycles on the chip."""
    IDLE_AVRS.clear()
    _leave_a_mess("sim+avr://?failsafe=0.1&fast_baud=1000000")
    used, new = sim("sim://"), sim("sim://")
    assert used.reused and not new.reused
    got, want = _power_on_state(used), _power_on_state(new)
    for name in want:
        assert got[name] == want[name], f"{name} differs from a new AVR's"
    g = golden()
    for s in (used, new):
        s.bus_log = []
    for name in ("hello", "run_an693_filter", "ping"):
        assert exchange(used, g[name]) == exchange(new, g[name])
        assert used.cycle == new.cycle
    assert used.bus_log == new.bus_log and used.bus_log
    used.close()
    new.close()


def test_the_next_open_after_a_tripped_session_is_a_fresh_bridge():
    """Through ``sim+avr://``: the bridge after a tripped session answers HELLO as a new one,
    its failsafe back at the default and not tripped, its clock at the same time as a new
    one's, the position 0, nothing stale in the link."""
    IDLE_AVRS.clear()
    random.seed(629)  # the link's first seq: the same frames, so the same cycles, both opens
    fresh = lm629_host.open("sim+avr://")
    t = fresh.transport
    want = (t.info, t.failsafe_state(), t.sim.cycle, t.sim.uart_counts())
    fresh.close()
    _leave_a_mess("sim+avr://?failsafe=0.1")
    random.seed(629)
    chip = lm629_host.open("sim+avr://")
    t = chip.transport
    assert t.sim.reused
    assert (t.info, t.failsafe_state(), t.sim.cycle, t.sim.uart_counts()) == want
    assert not t.failsafe_state().tripped
    chip.reset()
    assert chip.read_real_position() == 0 and t.stats.retries == 0
    counters = t.sim.link_counters()
    if counters is not None:
        assert counters.bad_frames == 0
    chip.close()


def test_sims_open_together_have_their_own_avrs_and_another_image_is_another_avr(tmp_path):
    """Two sims open at once never share an AVR; an AVR is used again only for the same image
    file, unchanged: a copy elsewhere, or the same path rewritten, gets a new one; only a
    closed sim's AVR is kept (one the garbage collector finds is freed: the collector may run
    while the idle list's lock is held)."""
    from lm629_host.sim.harness import firmware_path

    IDLE_AVRS.clear()
    a, b = sim("sim://"), sim("sim://")
    assert a._h != b._h and not a.reused and not b.reused
    a.close()
    b.close()
    assert len(IDLE_AVRS) == 2
    c, d, e = sim("sim://"), sim("sim://"), sim("sim://")
    assert [c.reused, d.reused, e.reused] == [True, True, False]
    assert len({c._h, d._h, e._h}) == 3 and len(IDLE_AVRS) == 0
    for s in (c, d, e):
        s.close()
    copy = tmp_path / "bridge.elf"
    copy.write_bytes(firmware_path().read_bytes())
    f = sim("sim://", firmware=copy)
    assert not f.reused
    f.close()
    os.utime(copy, ns=(0, 0))  # rewritten (or rebuilt) where it was
    g = sim("sim://", firmware=copy)
    assert not g.reused
    g.close()
    h = sim("sim://", firmware=copy)
    assert h.reused
    h.close()
    IDLE_AVRS.clear()
    lost = sim("sim://")  # never closed: the garbage collector frees its AVR, keeps none
    del lost
    gc.collect()
    assert len(IDLE_AVRS) == 0


def test_an_avr_used_again_has_the_eeprom_its_image_says(tmp_path):
    """An image with EEPROM data (an .eeprom section, as avr-gcc makes for EEMEM): a firmware
    that wrote its EEPROM finds it, at the next power-on, as the image says, not as it left it."""
    import shutil
    import subprocess

    from lm629_host.sim.harness import firmware_path

    if shutil.which("avr-objcopy") is None:
        pytest.skip("no avr-objcopy")
    image = b"EEPROM of the image"
    (tmp_path / "ee.bin").write_bytes(image)
    elf = tmp_path / "with_eeprom.elf"
    subprocess.run(["avr-objcopy", "--add-section", f".eeprom={tmp_path / 'ee.bin'}",
                    "--set-section-flags", ".eeprom=contents,alloc,load,data",
                    "--change-section-address", ".eeprom=0x810000", str(firmware_path()), str(elf)],
                   check=True, capture_output=True)
    want = image + b"\xff" * (1024 - len(image))  # the ATmega328P's 1 KiB, erased where unset
    s = sim("sim://", firmware=elf)
    assert s.memory("eeprom") == want
    for address in (0, 5, len(image), 1023):
        s.poke("eeprom", address, 0x42)
    s.close()
    s = sim("sim://", firmware=elf)
    assert s.reused and s.memory("eeprom") == want
    s.close()
