"""The host's frame reader and the Python bridge survive arbitrary input and fall back into
step on the next good frame (the firmware's C parser has its own fuzz test)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from lm629_host.sim.bridge import BridgeEmulator
from lm629_host.bridge.protocol import (
    MAX_FRAME,
    Frame,
    FrameError,
    FrameReader,
    FrameType,
    cobs_decode,
    cobs_encode,
    decode_frame,
    encode_frame,
)
from lm629_host.sim.build import build_model

GOOD = encode_frame(FrameType.HELLO, 0x42)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_reader_never_raises_and_resyncs(garbage):
    r = FrameReader()
    items = list(r.feed(garbage))
    assert all(isinstance(i, (Frame, FrameError)) for i in items)
    after = list(r.feed(b"\x00" + GOOD))
    assert after and after[-1] == decode_frame(GOOD)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=MAX_FRAME))
def test_cobs_round_trip(data):
    enc = cobs_encode(data)
    assert 0 not in enc and cobs_decode(enc) == data


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400))
def test_bridge_emulator_survives_garbage(garbage):
    emu = BridgeEmulator(build_model("sim://?strict=0"))
    replies = emu.receive(garbage)
    # anything it answered is a well-formed frame
    for rep in replies:
        decode_frame(rep)
    after = emu.receive(b"\x00" + GOOD)
    assert [decode_frame(x).type for x in after] == [FrameType.HELLO_REPLY]
