"""``ftdi://`` URLs, ``lm629 list``/``doctor`` data and the open errors, through pyftdi's own
device lookup (``UsbTools``) running on the emulated FT232H's pyusb backend.

pyftdi picks its pyusb backend from ``UsbTools.BACKENDS`` (module names with a
``get_backend()``); the emulator's backend module is put there, so the lookup, the string
descriptors and the open sequence are pyftdi's and pyusb's real code.
"""

from __future__ import annotations

import errno
from pathlib import Path

import pytest
from pyftdi.usbtools import UsbTools

import lm629_host
from click.testing import CliRunner

from lm629_host import data
from lm629_host.cli import main as cli
from lm629_host import TransportError
from lm629_host.sim.ftdi import SHARED, EmulatedFT232H
from lm629_host.sim.model import ChipModel
from lm629_host.transports import ftdi, ftdi_open

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def bus(monkeypatch):
    """An emulated USB bus with one FT232H (serial FT5LM629) wired to a chip model."""
    monkeypatch.setattr(UsbTools, "BACKENDS", ("lm629_host.sim.ftdi.backend",))
    UsbTools.flush_cache()
    UsbTools.release_all_devices()
    monkeypatch.setattr(SHARED, "devices", [EmulatedFT232H(ChipModel(), serial="FT5LM629")])
    monkeypatch.setattr(SHARED, "libusb_present", True)
    yield SHARED
    UsbTools.release_all_devices()
    UsbTools.flush_cache()


def test_list_ports_shows_the_adapter_by_serial(bus):
    ports = ftdi.list_ports()
    assert [p.url for p in ports] == ["ftdi://ftdi:232h:FT5LM629/1"]
    assert ports[0].usable and "FT5LM629" in ports[0].description


def test_open_by_url_runs_programs_through_pyftdi_lookup(bus):
    device = bus.devices[0]
    with lm629_host.open("ftdi://ftdi:232h:FT5LM629/1?latency=2") as chip:
        assert device.latency_ms == 2  # the latency timer is set as asked (default 1 ms)
        assert chip.read_status() in (0x80, 0x84, 0xC0, 0xC4)
        chip.load_filter(kp=10)
        assert device.model.filter_buffer.kp == 10
        assert device.counters.bulk_out >= 2


def test_default_latency_timer_is_low(bus):
    with lm629_host.open("ftdi://ftdi:232h:FT5LM629/1"):
        assert bus.devices[0].latency_ms == ftdi_open.DEFAULT_LATENCY_MS == 1


def test_wrong_serial_lists_what_was_found(bus):
    with pytest.raises(TransportError) as info:
        lm629_host.open("ftdi://ftdi:232h:NOSUCH/1")
    assert "no FT232H matches ftdi://ftdi:232h:NOSUCH/1" in str(info.value)
    assert "ftdi://ftdi:232h:FT5LM629/1" in str(info.value)


def test_access_denied_says_how_to_install_the_udev_rule(bus):
    bus.devices[0].open_error = errno.EACCES
    with pytest.raises(TransportError) as info:
        lm629_host.open("ftdi://ftdi:232h:FT5LM629/1")
    text = str(info.value)
    assert "access denied" in text
    # the command names the rule where this installation keeps it (no checkout needed)
    assert f"sudo cp {data.udev_rule()} /etc/udev/rules.d/" in text and data.udev_rule().is_file()
    assert "udevadm control --reload-rules" in text


def test_busy_device_says_how_to_detach_ftdi_sio(bus):
    bus.devices[0].claim_error = errno.EBUSY
    with pytest.raises(TransportError) as info:
        lm629_host.open("ftdi://ftdi:232h:FT5LM629/1")
    text = str(info.value)
    assert "device busy" in text and "ftdi_sio" in text and "unbind" in text


def test_missing_libusb_says_which_package(bus):
    bus.libusb_present = False
    with pytest.raises(TransportError) as info:
        lm629_host.open("ftdi://ftdi:232h/1")
    assert "no USB backend" in str(info.value)
    assert "apt-get install libusb-1.0-0" in str(info.value)
    assert ftdi.list_ports() == []
    checks = {c.name: c for c in ftdi.doctor()}
    assert not checks["libusb"].ok and "libusb-1.0-0" in checks["libusb"].message


def test_doctor_finds_the_adapter(bus):
    checks = {c.name: c for c in ftdi.doctor()}
    assert checks["pyftdi"].ok and checks["libusb"].ok
    assert checks["FT232H"].ok and "ftdi://ftdi:232h:FT5LM629/1" in checks["FT232H"].message


def test_bad_options_are_value_errors_before_any_usb_traffic(bus):
    with pytest.raises(ValueError, match="latency=0 is outside 1..255"):
        lm629_host.open("ftdi://ftdi:232h:FT5LM629/1?latency=0")
    with pytest.raises(ValueError, match="unknown FT232H parameter"):
        lm629_host.open("ftdi://ftdi:232h:FT5LM629/1?baud=9600")
    assert bus.devices[0].counters.control == 0


def test_udev_rule_matches_the_ft232h_and_the_documented_commands():
    rule = data.udev_rule().read_text()
    lines = [ln for ln in rule.splitlines() if ln.strip() and not ln.startswith("#")]
    assert any('ATTRS{idVendor}=="0403"' in ln and 'ATTRS{idProduct}=="6014"' in ln
               and 'MODE="0660"' in ln and 'GROUP="plugdev"' in ln for ln in lines)
    section = (ROOT / "docs" / "ftdi.md").read_text()
    assert 'sudo cp "$(lm629 udev --path)" /etc/udev/rules.d/' in section
    r = CliRunner().invoke(cli, ["udev", "--path"])
    assert r.output.strip() == str(data.udev_rule())
    r = CliRunner().invoke(cli, ["udev"])
    assert all(c in r.output for c in data.udev_install_commands())
    assert ftdi_open.UDEV_RULE == "/etc/udev/rules.d/99-lm629-ft232h.rules"


def test_documented_wiring_table_is_the_pin_map():
    """docs/ftdi.md's table is generated from ftdi_pins (tests/wiring/test_wiring.py checks it is
    current); here, that its rows say what the masks say."""
    section = (ROOT / "docs" / "ftdi.md").read_text()
    from lm629_host.wiring import ft232h as p
    for mask, line in ((p.CS, "/CS (pin 12)"), (p.RD, "/RD (pin 13)"), (p.WR, "/WR (pin 15)"),
                       (p.PS, "/PS (pin 16)"), (p.HI, "HI (pin 17)"), (p.RST, "/RST (pin 27)")):
        n = mask.bit_length() - 1
        assert f"| ADBUS{n} | D{n} | {line} |" in section, line
    for i in range(8):  # D0 on pin 11 ... D7 on pin 4 (tests/wiring/test_pinout.py has the sources)
        assert f"| ACBUS{i} | C{i} | D{i} (pin {11 - i}) |" in section
