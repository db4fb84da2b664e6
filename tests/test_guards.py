"""Guards for rules that a mutation audit (issue 16) found unguarded or guarded once: each rule
here is checked on its own, against numbers from the spec, not by comparing two
implementations with each other.

* the PID's integration limit, negative as well as positive, in every sample loop the model
  can run (readable per-sample code, flattened Python loop, C loop): the ki term is limited
  to +/- il (AN-706 4.5.2), and RDSUM reads that term;
* ``LM629.reset()`` sets the remembered derivative interval back to 1 sample (the chip's
  reset sets ds to 0, i.e. every sample; LFIL re-sends the remembered one);
* RSTI clears exactly the flags asked for and leaves the others;
* the far end's reply cache is keyed by seq AND CRC (PROTOCOL.md "Exactly once"), on the
  Python bridge and on the compiled firmware;
* the far end never answers or runs a frame that fails its CRC, on both.
"""

from __future__ import annotations

import pytest

from lm629_host.bridge.protocol import (
    FrameReader,
    FrameType,
    cobs_encode,
    crc16,
    encode_frame,
    run_payload,
)
from lm629_host.opcodes import INTERRUPTS, Cmd, Status
from lm629_host.program import BusOp, Op, Program

MOVE = dict(acceleration=65536 * 2, velocity=65536 * 20)


# ------------------------------------------------------------------ PID integration limit
@pytest.mark.parametrize("loop", ["0", "py", "c"])
@pytest.mark.parametrize("target,ki,il", [(-1000, 300, 500), (1000, 300, 500),
                                          (-3000, 100, 12345)])
def test_integration_term_is_limited_to_il_both_signs(open_chip, loop, target, ki, il):
    """Shaft locked (stall=1), kp = kd = 0: the desired position runs to ``target`` and stays
    there, so the error ends at e = target and the 24-bit sum keeps growing by e until the
    term ki x (sum >> 8) passes il; from then on RDSUM reads exactly sign(e) x il.  ki and il
    are chosen so that no multiple of ki equals il (300 x k never is 500, 100 x k never is
    12345): an unlimited term would read the first multiple past il (-600, -12400...)."""
    if loop == "c":
        from lm629_host.sim.model import fastloop
        if getattr(fastloop, "c_loop", None) is None and not _c_loop_built():
            pytest.skip("the C sample loop is not built here (pip install -e . builds it)")
    chip = open_chip(f"sim://?stall=1&fast={loop}")
    chip.reset()
    chip.load_filter(kp=0, ki=ki, kd=0, il=il)
    chip.update_filter()
    chip.load_trajectory(position=target, start=True, **MOVE)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=1.0)
    chip.clock.sleep(0.05)  # ~200 more samples at the limit
    expected = il if target > 0 else -il
    assert chip.read_integration_sum() == expected
    assert chip.read_real_position() == 0  # the shaft did not move: e stayed = target


def _c_loop_built() -> bool:
    try:
        from lm629_host.sim.model import _fastloop  # noqa: F401 - only whether it was built
        return True
    except ImportError:
        return False


# ------------------------------------------------------------------ ds after reset
def test_reset_sets_the_remembered_derivative_interval_back_to_one_sample(open_chip, recorder):
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=5, derivative_interval=4)
    assert chip.derivative_interval == 4
    chip.reset()
    assert chip.derivative_interval == 1
    recorder.clear()
    chip.load_filter(kp=6)  # no interval given: the remembered one, 1 sample (ds byte 0)
    data = recorder.data()
    assert data[0] == ("command", int(Cmd.LFIL))
    assert data[1][0] == "write" and data[1][1] >> 8 == 0


# ------------------------------------------------------------------ RSTI
def test_rsti_clears_only_the_flags_asked_for(open_chip, recorder):
    """Trajectory complete (a zero-length move) and command error (a data read after a write
    command) both set; RSTI for one leaves the other, and the word on the bus is
    INTERRUPTS & ~flags (0 bits clear)."""
    chip = open_chip("sim://?strict=0")
    chip.reset()
    chip.load_trajectory(position=0, start=True, **MOVE)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=1.0)
    chip.run(Program().command(Cmd.SBPA).read(1))  # wrong direction: command error
    both = Status.TRAJECTORY_COMPLETE | Status.COMMAND_ERROR
    assert chip.read_status() & both == both
    recorder.clear()
    chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
    assert recorder.data() == [("command", int(Cmd.RSTI)),
                               ("write", int(INTERRUPTS) & ~int(Status.TRAJECTORY_COMPLETE))]
    st = chip.read_status()
    assert st & Status.COMMAND_ERROR and not st & Status.TRAJECTORY_COMPLETE
    chip.reset_interrupts(Status.COMMAND_ERROR)
    assert not chip.read_status() & both


# ------------------------------------------------------------------ far ends: cache, CRC
def _far(kind: str):
    """(pipe, model) of a far end after a clean handshake; frames are sent raw below."""
    if kind == "emu":
        from lm629_host.transports.simemu import open_emulated
        t = open_emulated("sim://?record=1", baud=1_000_000)
        return t, t.pipe, t.model
    from lm629_host.transports import open_transport
    t = open_transport("sim+avr://?record=1&baud=1000000")
    return t, t.pipe, t.model


@pytest.fixture(params=["emu", "avr"])
def far(request):
    if request.param == "avr":
        request.getfixturevalue("firmware_built")
    t, pipe, model = _far(request.param)
    model.record_clear()
    yield pipe, model
    t.close()


def _sbpa(pos: int) -> bytes:
    return run_payload([BusOp(Op.COMMAND, int(Cmd.SBPA)), BusOp(Op.WRITE, pos >> 16),
                        BusOp(Op.WRITE, pos & 0xFFFF)], 1000)


def _exchange(pipe, wire: bytes, wait_s: float = 0.02) -> list:
    """Send ``wire``; every good frame that comes back within ``wait_s``."""
    pipe.write(wire)
    reader = FrameReader()
    out = []
    deadline = pipe.clock.now() + wait_s
    while (left := deadline - pipe.clock.now()) > 0:
        data = pipe.read(left)
        if not data:
            break
        out += [f for f in reader.feed(data) if not isinstance(f, Exception)]
    return out


def test_reply_cache_is_keyed_by_seq_and_crc(far):
    pipe, model = far
    a, b = _sbpa(0x10001), _sbpa(0x10002)
    sbpa = int(Cmd.SBPA)
    r1 = _exchange(pipe, encode_frame(FrameType.RUN, 77, a))
    assert [f.seq for f in r1] == [77] and model.history == [(sbpa, (1, 1))]
    # the same frame again: answered from the cache, byte for byte, not run
    r2 = _exchange(pipe, encode_frame(FrameType.RUN, 77, a))
    assert r2 == r1 and model.history == [(sbpa, (1, 1))]
    # same seq, other program (other CRC): a new request, run
    r3 = _exchange(pipe, encode_frame(FrameType.RUN, 77, b))
    assert [f.seq for f in r3] == [77] and model.history == [(sbpa, (1, 1)), (sbpa, (1, 2))]
    # same program, other seq: run again
    _exchange(pipe, encode_frame(FrameType.RUN, 78, b))
    assert model.history == [(sbpa, (1, 1)), (sbpa, (1, 2)), (sbpa, (1, 2))]


@pytest.mark.parametrize("where", ["crc", "payload"])
def test_frame_failing_its_crc_is_neither_run_nor_answered(far, where):
    pipe, model = far
    payload = _sbpa(0x12345)
    body = bytearray(bytes((FrameType.RUN, 5)) + payload)
    body += crc16(bytes(body)).to_bytes(2, "big")
    # one bit flipped, the COBS framing kept valid: only the CRC can tell
    at = len(body) - 1 if where == "crc" else 7
    body[at] ^= 0x01 if body[at] != 0x01 else 0x02
    assert _exchange(pipe, cobs_encode(bytes(body)) + b"\x00") == []
    assert model.history == []
    # the line recovers at once: the good frame runs
    assert len(_exchange(pipe, encode_frame(FrameType.RUN, 5, payload))) == 1
    assert model.history == [(int(Cmd.SBPA), (1, 0x2345))]
