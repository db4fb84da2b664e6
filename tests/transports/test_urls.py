"""The one URL-options parser (lm629_host.urls) that every transport and simulator uses."""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.urls import Option, parse_hz, parse_options, query_params, scheme_of, with_query

OPTS = (Option("baud", "int", 115200, 300, 4_000_000, "baud"),
        Option("boot", "float", 2.5, 0, 30, "s"),
        Option("clock", "hz", 8e6, 1e6, 8e6, "Hz"),
        Option("strict", "bool", False),
        Option("fault", "str", None, choices=("reset", "busy"), optional=True))


def test_types_units_and_defaults():
    assert parse_options("x://?baud=0x1C200&clock=6MHz&strict", OPTS) == {
        "baud": 115200, "boot": 2.5, "clock": 6e6, "strict": True, "fault": None}
    assert parse_options("x://?baud=1e6&boot=0.5&clock=6000k&fault=none", OPTS,
                         given_only=True) == {"baud": 1_000_000, "boot": 0.5, "clock": 6e6,
                                              "fault": None}
    assert parse_hz("8 MHz") == parse_hz("8e6") == parse_hz("8000k") == 8e6


@pytest.mark.parametrize("url, message", [
    ("x://?baud=fast", "baud='fast' is not a number"),
    ("x://?baud=1.5", "baud='1.5' is not a whole number"),
    ("x://?baud=100", "baud=100 is outside 300..4000000 baud"),
    ("x://?clock=9MHz", "clock=9MHz is outside 1000000..8000000 Hz"),
    ("x://?clock=nan", "clock='nan' is not a frequency (8MHz, 6e6)"),
    ("x://?strict=maybe", "strict='maybe': expected a boolean (1/0), got 'maybe'"),
    ("x://?fault=smoke", "fault='smoke': expected one of reset, busy"),
    ("x://?speed=9600", "unknown demo parameter(s) speed; known: baud (baud), boot (s), "
                        "clock (Hz), fault (reset|busy), strict"),  # the table's, no other
])
def test_errors_name_the_url_the_option_and_what_is_allowed(url, message):
    with pytest.raises(ValueError) as info:
        parse_options(url, OPTS, what="demo")
    assert str(info.value) == f"{url}: {message}"


def test_aliased_names():
    assert parse_options("x://?b=300", OPTS, aliases={"b": "baud"},
                         given_only=True) == {"baud": 300}
    with pytest.raises(ValueError, match="b='x' is not a number"):  # the URL's own spelling
        parse_options("x://?b=x", OPTS, aliases={"b": "baud"})


def test_url_helpers():
    assert scheme_of("/dev/ttyUSB0") == "serial" and scheme_of("SIM+AVR://") == "sim+avr"
    assert query_params("sim://?a=1&b") == {"a": "1", "b": ""}
    with pytest.raises(ValueError, match=r"a= is given twice \('1' and '2'\)"):
        query_params("sim://?a=1&a=2&b")
    assert with_query("sim://?chip=lm628&x=1", {"x": "2", "clock": "6000000"}) == \
        "sim://?chip=lm628&x=2&clock=6000000"


def test_every_simulator_takes_a_clock_with_units():
    # 6 MHz: one sample is 2048 / 6e6 s, as the model counts it
    with lm629_host.open("sim://?clock=6MHz") as chip:
        assert chip.transport.model.clock_hz == 6_000_000
    with lm629_host.open("sim+emu://?clock=6MHz&baud=0") as chip:
        assert chip.transport.model.clock_hz == 6_000_000


@pytest.mark.parametrize("env, url, strict", [("1", "sim://", True), ("1", "sim://?strict=0", False),
                                              ("0", "sim://", False), ("", "sim://?strict", True)])
def test_strict_is_decided_in_one_place(monkeypatch, env, url, strict):
    """LM629_SIM_STRICT sets the default (sim.build.strict_default), the URL's strict= wins;
    the transports that apply strictness themselves take it from the model."""
    from lm629_host.sim.build import build_model
    from lm629_host.transports.simftdi import SimFtdiTransport
    monkeypatch.setenv("LM629_SIM_STRICT", env)
    assert build_model(url).params.strict is strict
    t = SimFtdiTransport.from_url(url.replace("sim://", "sim+ftdi://"))
    try:
        assert t.strict is strict and not t.model.params.strict  # applied after each exchange
    finally:
        t.close()


@pytest.mark.parametrize("url, typo, meant, also", [
    ("sim://?axess=2", "axess", "axes", ["cs", "chip", "clock", "wiring", "axis", "profile"]),
    ("sim+emu://?fast_bud=1", "fast_bud", "fast_baud", ["axes", "cs", "usb", "baud"]),
    ("serial:///dev/null?bau=9600", "bau", "baud", ["axes", "cs", "fast_baud", "retries"]),
])
def test_an_unknown_url_option_lists_every_option_of_the_scheme_and_the_closest(url, typo, meant, also):
    import lm629_host
    with pytest.raises(ValueError) as info:
        lm629_host.open(url)
    text = str(info.value)
    assert f"unknown {text.split('unknown ')[1].split(' parameter')[0]} parameter(s) {typo} " \
           f"(did you mean {meant}?)" in text
    known = text.split("; known: ")[1].split(", ")
    assert {k.split(" ")[0] for k in known} >= {meant, *also}
