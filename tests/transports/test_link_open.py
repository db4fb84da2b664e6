"""One open sequence for every bridge port: the serial port (a served pseudo-terminal, the real
pyserial path) and both simulated bridges (the firmware in simavr, the Python far end) send the
same frames in the same order when they open: HELLO, the faster rate (SET_BAUD, then HELLO at
it), the round trip timed (five PINGs), the failsafe's report and arm last (so that neither the
switch nor the PINGs are timed by it).  Nothing else goes out before the first program."""

from __future__ import annotations

import re

import pytest

import lm629_host
from lm629_host.bridge.protocol import FrameReader, FrameType
from lm629_host.sim.serve import SimServer
from lm629_host.transports import simavr, simemu
from lm629_host.transports.link import RTT_PINGS

from sim_urls import available

#: what an open sends, worked out from the sequence the module doc gives
OPEN = ([FrameType.HELLO, FrameType.SET_BAUD, FrameType.HELLO] + [FrameType.PING] * RTT_PINGS
        + [FrameType.FAILSAFE, FrameType.FAILSAFE])


class _Sent:
    """The bytes the host writes to a simulated bridge's line, kept (outside any USB model)."""

    def __init__(self, pipe) -> None:
        self.pipe = pipe
        self.clock = pipe.clock
        self.sent = bytearray()

    def write(self, data: bytes) -> None:
        self.sent += data
        self.pipe.write(data)

    def __getattr__(self, name: str):
        return getattr(self.pipe, name)


def _frames(data: bytes) -> list[int]:
    return [f.type for f in FrameReader().feed(data)]


def _opened_simulated(url: str, line: list[_Sent]) -> list[int]:
    transport = lm629_host.open(url).transport
    transport.close()
    (sent,) = line
    line.clear()
    return _frames(bytes(sent.sent))[:-1]  # the disarm at the close is not the open's


def _opened_serial(tmp_path) -> list[int]:
    log = tmp_path / "spy.txt"
    with SimServer(tmp_path / "lm629").start() as srv:
        lm629_host.open(f"serial://spy://{srv.link}?file={log}&fast_baud=1000000").close()
    tx = bytearray()  # pyserial's spy: "time TX offset hex... ascii" lines
    for line in log.read_text().splitlines():
        m = re.match(r"\S+ TX +[0-9A-F]{4}  ((?:[0-9A-F]{2} {1,2}){1,16})", line)
        if m:
            tx += bytes.fromhex(m.group(1))
    return _frames(bytes(tx))[:-1]


def test_the_serial_port_and_both_simulated_bridges_open_alike(tmp_path, monkeypatch):
    line: list[_Sent] = []  # the simulated line of the port being opened
    for module in (simavr, simemu):
        def spy(pipe, adapter, inner=module.wrap_usb):
            line.append(_Sent(inner(pipe, adapter)))
            return line[-1]
        monkeypatch.setattr(module, "wrap_usb", spy)
    opened = {"serial": _opened_serial(tmp_path),
              "sim+emu": _opened_simulated("sim+emu://?fast_baud=1000000", line)}
    if available("sim+avr://"):
        opened["sim+avr"] = _opened_simulated("sim+avr://?fast_baud=1000000", line)
    else:  # pragma: no cover - CI installs the AVR toolchain
        pytest.skip("sim+avr:// not available here")
    names = [FrameType(t).name for t in OPEN]
    for port, frames in opened.items():
        assert [FrameType(t).name for t in frames] == names, port
