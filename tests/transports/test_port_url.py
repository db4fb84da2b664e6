"""A port URL is settled once: parsed once per command, options added beside the user's text
(never rewritten into it), every message quoting what the user wrote, and the URLs that used
to pass silently refused in one line."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import lm629_host
import lm629_host.urls as urls
from lm629_host import cli
from lm629_host.transports.ports import resolve_port
from lm629_host.urls import PortURL


def _invoke(*args: str):
    return CliRunner().invoke(cli.main, list(args), env={"LM629_PORT": "", "LM629_PROFILE": ""})


def test_a_command_parses_its_port_once(monkeypatch):
    seen: list[str] = []
    real = urls.urlsplit

    def counting(text, *a, **k):
        seen.append(text)
        return real(text, *a, **k)

    monkeypatch.setattr(urls, "urlsplit", counting)
    r = _invoke("--port", "sim+emu://?failsafe=0.2", "status")
    assert r.exit_code == 0, r.output
    assert "failsafe armed, 0.2 s" in r.output  # the option reached the link
    assert seen == ["sim+emu://?failsafe=0.2"]


@pytest.mark.parametrize("url, said", [
    ("sim://?chip=lm629&chip=lm628", "chip= is given twice ('lm629' and 'lm628')"),
    ("sim:///x", "a simulator has no host or path ('/x')"),
    ("sim://host:1/", "a simulator has no host or path ('host:1')"),
    ("sim://?vcd=", "vcd= is empty: give the file to write"),
    ("socket://host", "socket:// needs a host and a port number"),
    ("sim+avr://?baud=0", "baud=0 is outside 300..4000000 baud"),
])
def test_an_ill_formed_port_is_refused_in_one_line_naming_it(url, said):
    r = _invoke("--port", url, "status")
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert said in lines[0] and url in lines[0]
    # the URL the user typed, never one the CLI rewrote (chip= and clock= added beside it)
    assert "clock=8000000" not in lines[0]


def test_options_are_added_beside_the_users_text():
    parsed = PortURL.parse("sim+emu://?usb=uno")
    more = parsed.with_options({"chip": "lm628", "usb": "cdc"})
    assert str(more) == "sim+emu://?usb=uno"  # what the user wrote, for every message
    assert more.text == "sim+emu://?usb=cdc&chip=lm628"  # what is opened
    assert more.added == {"chip"}
    rest, taken = more.without({"chip"})
    assert taken == {"chip": "lm628"} and rest.text == "sim+emu://?usb=cdc"
    spec = resolve_port(parsed, chip="lm628", clock="6MHz")
    assert spec.open_url.query() == {"usb": "uno", "chip": "lm628", "clock": "6000000"}
    with lm629_host.open(spec.open_url) as chip:
        assert chip.transport.url == "sim+emu://?usb=uno"
        assert chip.transport.clock_hz == 6e6


def test_every_bridge_port_takes_the_links_options_with_one_range():
    """serial://, sim+avr:// and sim+emu:// declare their options from the link's rows: baud,
    fast_baud, retries and the failsafe's, each with the same range everywhere (a rate the real
    port refuses is refused by the simulators too), only the defaults their own."""
    from lm629_host.transports import serial, simavr, simemu
    from lm629_host.transports.link import LINK_OPTIONS

    for table in (serial.OPTIONS, simavr.OPTIONS, simemu.OPTIONS):
        rows = {o.name: o for o in table}
        for row in LINK_OPTIONS:
            assert (rows[row.name].lo, rows[row.name].hi) == (row.lo, row.hi), row.name
    for url in ("serial:///dev/null?fast_baud=100", "sim+avr://?fast_baud=100",
                "sim+emu://?fast_baud=100"):
        with pytest.raises(ValueError, match=r"fast_baud=100 is outside 0 \(off\) or 300..4000000"):
            lm629_host.open(url)
