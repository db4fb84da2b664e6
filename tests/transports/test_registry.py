"""The transport contract and the registry: built-ins, and a third-party transport installed as
a distribution with an ``lm629_host.transports`` entry point (a real one on ``sys.path``,
found by importlib.metadata as pip would leave it), seen by ``open``, ``lm629 list`` and
``lm629 doctor`` without any edit of this package."""

from __future__ import annotations

import textwrap

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host.cli import main as cli
from lm629_host.errors import TransportError
from lm629_host.bus.opcodes import Status
from lm629_host.transports import (
    BUILTIN,
    ENTRY_POINT_GROUP,
    Transport,
    is_simulated,
    registry,
    transport_class,
    transport_classes,
)

PLUGIN = '''
from lm629_host.transports.reports import Check, PortInfo
from lm629_host.transports.sim import SimTransport
from lm629_host.sim.build import build_model


class BenchTransport(SimTransport):
    """A third party's transport: here the chip model under another scheme."""

    scheme = "bench"

    @classmethod
    def from_url(cls, url, *, trace=None):
        return cls(build_model("sim://"), url, trace=trace)

    @classmethod
    def list_ports(cls):
        return [PortInfo("bench://rig-7", "the rig in room 7")]

    @classmethod
    def doctor(cls, port=None):
        return [Check("bench rig", True, "rig 7 answers")]


class NotATransport:
    pass
'''


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """A distribution 'lm629-bench' that registers bench:// (and tries to take sim://)."""
    (tmp_path / "lm629_bench_plugin.py").write_text(PLUGIN)
    info = tmp_path / "lm629_bench-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lm629-bench\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(f"""\
        [{ENTRY_POINT_GROUP}]
        bench = lm629_bench_plugin:BenchTransport
        sim = lm629_bench_plugin:BenchTransport
        broken = lm629_bench_plugin:NotATransport
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_every_builtin_keeps_the_contract():
    for scheme, cls, problem in transport_classes():
        assert problem is None, (scheme, problem)
        assert issubclass(cls, Transport)
        assert cls.scheme == scheme
        assert cls.simulated == scheme.startswith("sim"), scheme
        assert isinstance(cls.list_ports(), list)
    assert set(registry()) == set(BUILTIN)


def test_open_says_simulated_and_repr():
    assert is_simulated("sim+emu://") and not is_simulated("/dev/ttyACM0")
    with lm629_host.open("sim://?chip=lm628") as chip:
        assert repr(chip.transport) == "<SimTransport 'sim://?chip=lm628'>"
        assert chip.variant == "lm628"  # a simulator URL's chip= is the chip


def test_a_third_party_transport_through_its_entry_point(plugin, caplog):
    assert registry()["bench"] == "lm629_bench_plugin:BenchTransport"
    # a plug-in cannot take a built-in scheme
    assert registry()["sim"] == BUILTIN["sim"]
    assert "sim:// is built in" in caplog.text
    with lm629_host.open("bench://rig-7") as chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        st = chip.sync()  # UDF done; after reset: motor off (80/C0), no command error
        assert st & Status.MOTOR_OFF and not st & (Status.COMMAND_ERROR | Status.BUSY)
        assert type(chip.transport).__name__ == "BenchTransport"
    with pytest.raises(TransportError, match="not a Transport subclass"):
        transport_class("broken://")

    r = CliRunner().invoke(cli, ["list"])
    assert r.exit_code == 0, r.output
    assert "bench://rig-7" in r.output and "the rig in room 7" in r.output
    # the notice is the command's line, as every other it prints: lm629:, not the logger's
    # name (that comes with -v, where it helps to find the code)
    notice = "entry point sim = lm629_bench_plugin:BenchTransport ignored: sim:// is built in"
    assert f"lm629: {notice}" in r.stderr and "lm629_host.transports:" not in r.stderr
    r = CliRunner().invoke(cli, ["-v", "list"])
    assert f"lm629_host.transports: {notice}" in r.stderr
    assert "broken://  not available" in r.output
    r = CliRunner().invoke(cli, ["doctor"])
    assert "bench://" in r.output and "rig 7 answers" in r.output


def test_unknown_scheme_names_the_known_ones():
    with pytest.raises(TransportError, match=r"unknown port scheme 'nope'; known: sim://"):
        lm629_host.open("nope://x")


@pytest.mark.parametrize("scheme", ["sim", "sim+emu", "sim+ftdi"])
def test_a_simulator_gives_its_models_clock_and_chip_count(scheme):
    """Transport.clock_hz / chip_count: what the driver asks instead of looking at a model;
    the clock sets the default move timeout (Move.watch) through LM629.clock_hz."""
    with lm629_host.open(f"{scheme}://?clock=6MHz&axes=2") as chip:
        assert chip.transport.clock_hz == 6e6 and chip.clock_hz == 6e6
        assert chip.transport.chip_count == 2


def test_hardware_knows_no_clock_and_the_chip_assumes_8mhz():
    from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
    from lm629_host.sim.build import build_bus
    from lm629_host.transports.link import LinkTransport

    # the serial link's own class (what serial:// opens), to the emulated bridge of a 6 MHz chip
    t = LinkTransport(EmuPipe(BridgeEmulator(build_bus("sim://?clock=6MHz")), baud=None), "emu")
    chip = lm629_host.LM629(t)
    assert t.clock_hz is None and t.chip_count is None
    assert chip.clock_hz == 8e6  # nothing says otherwise: the nominal 8 MHz part
    chip.move_rules = lm629_host.MoveRules(clock_hz=6e6)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    # 1 count/sample reached in 100 samples at 655/65536: two 100-sample ramps (50 counts each)
    # and 1900 counts of cruise, 2100 samples
    m = chip.move_to(2000, velocity=65536, acceleration=655)
    assert m.profile_s(6e6) == pytest.approx(2100 * 2048 / 6e6, rel=0.01)
    assert m.watch().timeout == pytest.approx(1.5 * m.profile_s(6e6) + 1.0 + 1.0)
