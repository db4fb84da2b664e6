"""``serial://`` opens through pyserial's ``serial_for_url``: a bridge on another machine
(``socket://``, as behind ser2net) and ``spy://`` work.  The far end is served on a real TCP
port (or pty) by ``lm629 sim serve``'s server, in real time: the Python bridge, and the
compiled firmware in simavr."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import lm629_host
from lm629_host import Status, TransportError
from lm629_host.bus.opcodes import Cmd
from lm629_host.sim.serve import SimServer
from test_serial_pty import three_commands_once
from lm629_host.bridge.protocol import REPLY_TO, FrameReader, FrameType
from lm629_host.transports.link import RTT_PINGS
from lm629_host.transports.serial import SerialTransport, options_of


@pytest.fixture
def tcp_server():
    srv = SimServer(tcp=("127.0.0.1", 0), url="sim://?record=1").start()
    yield srv
    srv.close()


def test_socket_url_reaches_a_bridge_on_a_tcp_port(tcp_server):
    port = tcp_server.address[1]
    url = f"serial://socket://localhost:{port}?retries=3"
    with lm629_host.open(url) as chip:
        t = chip.transport
        assert isinstance(t, SerialTransport) and t.retries == 3
        assert t.info is not None and t.info.firmware_version == "1.4.0"  # the Python bridge: the firmware release it emulates
        three_commands_once(chip, tcp_server.model)


def test_a_second_tcp_client_is_refused_while_one_is_connected(tcp_server):
    """ser2net and a pty serve one client: so does a served TCP bench.  The second client
    gets a TransportError that says why, and the first keeps its link and its chip."""
    url = tcp_server.client_url
    with lm629_host.open(url) as first:
        first.reset()
        first.define_home()
        with pytest.raises(TransportError) as info:
            lm629_host.open(url)
        assert "take one client at a time" in str(info.value)
        assert first.read_desired_position() == 0  # the running client's link still works
        assert first.read_status() & Status.MOTOR_OFF
    with lm629_host.open(url) as later:  # once the first has gone, the next one is served
        assert later.read_real_position() == 0


def test_the_chip_keeps_its_state_between_tcp_clients(tcp_server):
    url = tcp_server.client_url
    assert url == f"socket://127.0.0.1:{tcp_server.address[1]}"  # no serial:// in front
    with lm629_host.open(url) as a:
        a.reset()
        a.set_breakpoint(0x00012345)
        a.define_home()
    with lm629_host.open(url) as b:  # a second connection: the same chip, its state kept
        assert b.read_desired_position() == 0
        b.load_filter(kp=7)
    hist = tcp_server.model.history
    assert (int(Cmd.SBPA), (0x0001, 0x2345)) in hist and hist[-1] == (0x1E, (0x0008, 0x0007))


def test_handler_options_pass_through_ours_are_checked():
    o = options_of("serial://socket://bench-pc:2000?baud=57600&logging=debug")
    assert o.device == "socket://bench-pc:2000?logging=debug" and o.baud == 57600
    with pytest.raises(ValueError, match="baud=9 is outside 300..4000000"):
        options_of("serial://socket://bench-pc:2000?baud=9")
    with pytest.raises(ValueError, match="unknown serial parameter"):
        options_of("serial:///dev/ttyACM0?logging=debug")  # a device path has no handler


def test_a_closed_tcp_port_says_what_to_check():
    import socket
    with socket.socket() as s:  # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(TransportError, match="is the bridge's server .* running"):
        lm629_host.open(f"serial://socket://127.0.0.1:{port}?boot=0")


def test_spy_url_hex_dumps_the_traffic(tmp_path):
    log = tmp_path / "spy.txt"
    with SimServer(tmp_path / "lm629").start() as srv:
        with lm629_host.open(f"serial://spy://{srv.link}?file={log}") as chip:
            chip.reset()
    # pyserial's spy writes "time TX|RX offset hex... ascii" lines: decode both directions
    wire: dict[str, bytearray] = {"TX": bytearray(), "RX": bytearray()}
    for line in log.read_text().splitlines():
        m = re.match(r"\S+ (TX|RX) +[0-9A-F]{4}  ((?:[0-9A-F]{2} {1,2}){1,16})", line)
        if m:
            wire[m.group(1)] += bytes.fromhex(m.group(2))
    sent = [f.type for f in FrameReader().feed(bytes(wire["TX"]))]
    got = [f.type for f in FrameReader().feed(bytes(wire["RX"]))]
    # the handshake, the switch to 1 Mbaud (SET_BAUD, then HELLO at the new rate), the five
    # PINGs that time the round trip (RTT_PINGS), the failsafe's report and arm, then reset's
    # programs in the compact form, and the failsafe's disarm at the close (and any feed)
    head = [FrameType.HELLO, FrameType.SET_BAUD, FrameType.HELLO]
    n = len(head) + RTT_PINGS
    assert sent[:n + 2] == head + [FrameType.PING] * RTT_PINGS + [FrameType.FAILSAFE] * 2
    assert set(sent[n + 2:-1]) <= {FrameType.RUN_SHORT, FrameType.RUN_STORE,
                                   FrameType.RUN_CODE, FrameType.FAILSAFE}
    assert sent[-1] == FrameType.FAILSAFE
    assert got == [REPLY_TO[FrameType(t)] for t in sent]


def test_firmware_in_simavr_behind_a_tcp_port():
    from firmware_helpers import require_firmware

    require_firmware()  # skips only without the toolchain; a broken build fails
    with SimServer(tcp=("127.0.0.1", 0), url="sim://?record=1", firmware=True).start() as srv:
        with lm629_host.open(srv.client_url) as chip:
            assert "bridge firmware 1." in chip.transport.describe()
            chip.reset()
            chip.load_filter(kp=10)
            chip.update_filter()
    assert srv.model.history[-2:] == [(0x1E, (0x0008, 0x000A)), (0x04, ())]


def test_sim_serve_tcp_cli(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(Path(lm629_host.__file__).parent.parent))
    proc = subprocess.Popen([sys.executable, "-m", "lm629_host", "sim", "serve",
                             "--tcp", "127.0.0.1:0", "--url", "sim://?chip=lm628"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        first = proc.stdout.readline()
        second = proc.stdout.readline()
        assert "simulated LM628" in first and "TCP port 127.0.0.1:" in first, first
        url = second.split("--port ", 1)[1].split()[0]
        assert url.startswith("socket://127.0.0.1:")
        with lm629_host.open(url) as chip:
            assert chip.reset() in (Status(0x80), Status(0xC0))
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0, out
    assert "stopped (" in out
    r = subprocess.run([sys.executable, "-m", "lm629_host", "sim", "serve"],
                       capture_output=True, text=True, env=env, timeout=30)
    assert r.returncode == 2 and "give --pty PATH or --tcp" in r.stderr
    r = subprocess.run([sys.executable, "-m", "lm629_host", "sim", "serve", "--tcp", "0",
                        "--url", "sim://?usb=ch340"], capture_output=True, text=True, env=env,
                       timeout=30)
    assert r.returncode == 2 and "usb='ch340': expected one of none, uno, ftdi, cdc" in r.stderr


@pytest.mark.parametrize("url, device", [
    ("socket://bench-pc:2000?baud=57600&logging=debug", "socket://bench-pc:2000?logging=debug"),
    ("rfc2217://bench-pc:2217?timeout=3", "rfc2217://bench-pc:2217?timeout=3"),
    ("spy:///dev/ttyACM0?file=/tmp/x.txt", "spy:///dev/ttyACM0?file=/tmp/x.txt"),
    ("loop://", "loop://"),
])
def test_pyserial_urls_are_ports_as_they_are(url, device):
    """The registry sends pyserial's URL schemes to the serial bridge transport; the URL is
    pyserial's device, our options taken out of it (``serial://`` in front means the same)."""
    from lm629_host.transports import transport_class

    assert transport_class(url) is SerialTransport
    assert options_of(url).device == device
    assert options_of("serial://" + url).device == device
    assert not lm629_host.transports.is_simulated(url)


def test_loop_url_opens_pyserial_and_says_no_bridge_answered():
    """``loop://`` is opened by pyserial (its loopback hears the host's own HELLO, which is
    no reply): the error is the bridge's "no answer", not an unknown scheme."""
    with pytest.raises(TransportError, match="no answer to HELLO"):
        lm629_host.open("loop://?boot=0")


def test_cli_status_on_a_socket_port_from_separate_processes():
    """``lm629 --port socket://127.0.0.1:PORT status`` against ``lm629 sim serve --tcp``, each
    its own process, as on a bench: the status a reset chip has (0xC0 or 0x80, AN-706 4.2)."""
    env = dict(os.environ, PYTHONPATH=str(Path(lm629_host.__file__).parent.parent))
    env.pop("LM629_PORT", None)
    proc = subprocess.Popen([sys.executable, "-m", "lm629_host", "sim", "serve",
                             "--tcp", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        proc.stdout.readline()
        url = proc.stdout.readline().split("--port ", 1)[1].split()[0]
        assert re.fullmatch(r"socket://127\.0\.0\.1:\d+", url), url
        cli = [sys.executable, "-m", "lm629_host", "--port", url]
        r = subprocess.run([*cli, "reset"], capture_output=True, text=True, env=env, timeout=60)
        assert r.returncode == 0, r.stderr
        r = subprocess.run([*cli, "status", "--json"], capture_output=True, text=True, env=env,
                           timeout=60)
        assert r.returncode == 0, r.stderr
        import json
        assert int(json.loads(r.stdout)["status"], 16) in (0x80, 0xC0), r.stdout
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)


def test_an_rfc2217_url_gets_ign_set_control_unless_it_says_otherwise():
    """ser2net in front of a line without modem-control wires does not answer SET-CONTROL:
    pyserial's open waited 3 s for it and failed, so the option that skips the wait is added
    to rfc2217:// URLs; ``ign_set_control=0`` (no, false, off) asks for the wait after all,
    and pyserial's other options pass as they are.  Other schemes are untouched."""
    from lm629_host.transports.netport import rfc2217_url

    assert rfc2217_url("rfc2217://bench:2000") == "rfc2217://bench:2000?ign_set_control="
    assert rfc2217_url("rfc2217://bench:2000?ign_set_control") == \
        "rfc2217://bench:2000?ign_set_control="
    assert rfc2217_url("rfc2217://bench:2000?logging=debug&timeout=1") == \
        "rfc2217://bench:2000?logging=debug&timeout=1&ign_set_control="
    for no in ("0", "no", "False", "off"):
        assert rfc2217_url(f"rfc2217://bench:2000?ign_set_control={no}&logging=debug") == \
            "rfc2217://bench:2000?logging=debug"
    assert rfc2217_url("socket://bench:2000") == "socket://bench:2000"
    assert options_of("serial://rfc2217://bench:2000?baud=57600&ign_set_control=0").device == \
        "rfc2217://bench:2000?ign_set_control=0"  # what the user wrote goes to open_port
