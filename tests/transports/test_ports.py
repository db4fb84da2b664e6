"""One place settles a port: lm629_host.transports.ports.resolve_port, used by open, open_board and the
CLI.  The same option in the URL and beside it must agree; a bad value names the option; an
unknown scheme is bad usage; a scheme pyserial knows is a serial port."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host.cli import main as cli
from lm629_host.errors import ArgumentError, SchemeError, TransportError
from lm629_host.transports.ports import resolve_port
from lm629_host.sim.serve import SimServer
from lm629_host.transports.serial import SerialTransport
from lm629_host.transports.sim import SimTransport


def test_a_bad_axes_in_the_url_names_axes():
    with pytest.raises(ValueError) as info:
        lm629_host.open_board("sim://?axes=x")
    assert isinstance(info.value, ArgumentError) and info.value.argument == "axes"
    assert str(info.value) == "axes='x' in sim://?axes=x is not a whole number of chips"


def test_a_chip_in_the_url_and_another_beside_it_is_a_conflict_naming_both():
    with pytest.raises(ValueError) as info:
        lm629_host.open("sim://?chip=lm628", chip="lm629")
    assert "chip=lm629" in str(info.value) and "chip=lm628 in sim://?chip=lm628" in str(info.value)
    assert info.value.argument == "chip"


@pytest.mark.parametrize("args, words", [
    ({"url": "sim://?clock=8MHz", "clock": 6e6}, "clock=6MHz conflicts with clock=8MHz"),
    ({"url": "sim://?axes=2", "axes": 3}, "axes=3 conflicts with axes=2"),
    ({"url": "sim://?cs=1", "cs": 0}, "cs=0 conflicts with cs=1"),
    ({"url": "sim://?clock=9MHz"}, "clock=9MHz in sim://?clock=9MHz is outside the chip's 1-8 MHz"),
    ({"url": "sim://", "clock": "fast"}, "clock='fast' is not a frequency"),
    ({"url": "sim://?cs=-1"}, "cs=-1 in sim://?cs=-1: at least 0"),
    ({"url": "sim://", "axes": 0}, "axes=0 must be a whole number of chips (at least 1)"),
    ({"url": "sim://", "chip": "lm630"}, "chip='lm630': expected 'lm628' or 'lm629'"),
    ({"url": "  "}, "is empty"),
])
def test_conflicts_and_bad_values_name_the_option(args, words):
    with pytest.raises(ArgumentError) as info:
        resolve_port(**args)
    assert words in str(info.value)


def test_an_unknown_scheme_is_bad_usage_and_a_transport_error():
    with pytest.raises(SchemeError) as info:
        resolve_port("nosuch://x")
    assert isinstance(info.value, ValueError) and isinstance(info.value, TransportError)
    assert info.value.argument == "port" and "unknown port scheme 'nosuch'" in str(info.value)
    r = CliRunner().invoke(cli, ["--port", "nosuch://x", "status"])
    assert r.exit_code == 2, r.output
    assert "unknown port scheme 'nosuch'" in r.stderr


def test_a_simulator_builds_the_chip_it_is_told_of():
    """The arguments go into a simulator's URL: open("sim://", chip="lm628") is an LM628
    model, not an LM628 driver over an LM629 model."""
    spec = resolve_port("sim://?cs=1&lines=500", chip="LM628", clock="6MHz", axes=2)
    assert spec.transport is SimTransport and spec.simulated
    assert (spec.chip, spec.clock_hz, spec.axes, spec.cs) == ("lm628", 6e6, 2, 1)
    assert spec.open_url.text == "sim://?lines=500&chip=lm628&clock=6000000&axes=2"
    with lm629_host.open("sim://", chip="lm628", clock=6e6) as chip:
        assert chip.variant == "lm628" and chip.transport.models[0].params.variant == "lm628"
        assert chip.clock_hz == 6e6


def test_a_hardware_url_keeps_its_own_options_and_gives_up_the_boards():
    spec = resolve_port("/dev/ttyACM0?baud=57600&chip=lm628&clock=6MHz&axes=2&cs=1")
    assert spec.transport is SerialTransport and spec.scheme == "serial" and not spec.simulated
    assert spec.open_url.text == "/dev/ttyACM0?baud=57600"
    assert (spec.chip, spec.clock_hz, spec.axes, spec.cs) == ("lm628", 6e6, 2, 1)


@pytest.mark.parametrize("url, open_url", [
    ("socket://bench:7000?logging=debug", "socket://bench:7000?logging=debug"),
    ("rfc2217://bench:7000?chip=lm628", "rfc2217://bench:7000"),  # the board's option taken
    ("spy:///dev/ttyUSB0?file=x.txt", "spy:///dev/ttyUSB0?file=x.txt"),
    ("loop://", "loop://"),
    # a handler the registry does not list: serial:// in front, as it has always been taken
    ("hwgrep://0403:6014", "serial://hwgrep://0403:6014"),
])
def test_a_scheme_pyserial_knows_is_a_serial_port(url, open_url):
    spec = resolve_port(url)
    assert spec.transport is SerialTransport and spec.scheme == "serial"
    assert spec.open_url.text == open_url


def test_a_socket_url_given_directly_reaches_a_bridge():
    srv = SimServer(tcp=("127.0.0.1", 0), url="sim://").start()
    try:
        with lm629_host.open(f"socket://127.0.0.1:{srv.address[1]}?cs=0") as chip:
            assert isinstance(chip.transport, SerialTransport)
            chip.reset()
            chip.set_breakpoint(0x1234)
            assert chip.read_desired_position() == 0
    finally:
        srv.close()


def test_open_board_takes_no_cs():
    with pytest.raises(ArgumentError, match="cs=1 names one chip"):
        lm629_host.open_board("sim://?axes=2&cs=1")


def test_the_cli_puts_a_conflict_on_the_option_typed():
    r = CliRunner().invoke(cli, ["--port", "sim://?axes=x", "status"])
    assert r.exit_code == 2 and "Invalid value for --port: axes='x'" in r.stderr
    r = CliRunner().invoke(cli, ["--port", "sim://?chip=lm628", "--chip", "lm629", "status"])
    assert r.exit_code == 2 and "Invalid value for --chip" in r.stderr
    assert "chip=lm629 conflicts with chip=lm628" in r.stderr
