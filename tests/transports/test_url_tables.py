"""Each transport declares its URL options once, as one table (``Transport.options``): the
board's rows, then the link's or the simulator's, then its own.  The table is what the URL is
parsed against, once, and what a message about an unknown name lists; no option is declared
in two places (issue 45 item 3)."""

from __future__ import annotations

import inspect

import pytest

from lm629_host.bus.url_board import BOARD, BOARD_ROWS
from lm629_host.errors import ArgumentError
from lm629_host.sim.build import ALIASES, MODEL_ROWS, SERVED_OPTIONS, TWIN_ROWS, build_bus
from lm629_host.sim.usb import OPTIONS as USB_ROWS
from lm629_host.sim.vcd import OPTIONS as VCD_ROWS
from lm629_host.sim.wiring import OPTION as WIRING
from lm629_host.transports import BUILTIN, transport_class
from lm629_host.transports.link import LINK_OPTIONS
from lm629_host.transports.ports import resolve_port
from lm629_host.urls import parse_options

#: the rows declared for several tables; a transport's other rows are its own
SHARED = {"board": BOARD_ROWS, "link": LINK_OPTIONS, "usb": USB_ROWS, "vcd": VCD_ROWS,
          "wiring": (WIRING,), "model": MODEL_ROWS, "twin": TWIN_ROWS}
#: a URL of each built-in scheme with nothing in its query (its options parse before anything
#: opens: no device, adapter or simulator is touched by an unknown name)
BASE = {"sim": "sim://", "serial": "serial:///dev/null", "ftdi": "ftdi://ftdi:232h/1",
        "sim+avr": "sim+avr://", "sim+ftdi": "sim+ftdi://", "sim+emu": "sim+emu://"}


def _home(name: str) -> list[str]:
    return [group for group, rows in SHARED.items() if name in {o.name for o in rows}]


def test_every_scheme_has_one_table_the_board_s_rows_first():
    assert set(BASE) == set(BUILTIN)
    for scheme in BUILTIN:
        table = transport_class(BASE[scheme]).options
        names = [o.name for o in table]
        assert len(names) == len(set(names)), f"{scheme}: a name declared twice: {names}"
        assert names[:len(BOARD_ROWS)] == list(BOARD), scheme
        # a shared row is the declared row: its type and range (a child may change its default,
        # and sim+emu's baud takes 0 for a line without wire time)
        for row in table:
            homes = _home(row.name)
            assert len(homes) <= 1, f"{row.name} is declared in {homes}"
            if homes:
                declared = next(o for o in SHARED[homes[0]] if o.name == row.name)
                assert (row.kind, row.lo, row.hi, row.choices) == \
                       (declared.kind, declared.lo, declared.hi, declared.choices), row
    served = [o.name for o in SERVED_OPTIONS]
    assert len(served) == len(set(served))


def test_no_option_name_is_declared_in_two_groups():
    seen: dict[str, str] = {}
    for group, rows in SHARED.items():
        for row in rows:
            assert row.name not in seen, f"{row.name}: in {seen.get(row.name)} and {group}"
            seen[row.name] = group
    own = {scheme: [o.name for o in transport_class(BASE[scheme]).options
                    if not _home(o.name)] for scheme in BUILTIN}
    # sim:// has no rows of its own: the simulator's are shared by every simulated transport
    assert own["sim"] == []
    assert {"boot", "low_latency"} <= set(own["serial"]) and {"firmware"} == set(own["sim+avr"])


def test_no_layered_parse():
    """One parse of a URL against one table: the parser takes no names to skip."""
    assert "ignore" not in inspect.signature(parse_options).parameters


@pytest.mark.parametrize("scheme", sorted(BASE))
def test_the_table_is_what_parsing_and_the_unknown_name_message_use(scheme):
    cls = transport_class(BASE[scheme])
    names = [o.name for o in cls.options]
    for name in names:  # a typo of each row: suggested, and the whole table listed
        typo = name + "x"
        url = f"{BASE[scheme]}?{typo}=1"
        with pytest.raises(ValueError) as info:
            cls.from_url(url)
        text = str(info.value)
        assert "\n" not in text and f"parameter(s) {typo}" in text, text
        known = text.split("; known: ")[1].split(", ")
        aliases = list(ALIASES) if cls.simulated else []
        assert sorted(known) == sorted([*(o.describe() for o in cls.options), *aliases])
        assert f"{typo} (did you mean {name}?)" in text, text


def test_the_board_s_url_values_are_checked_by_the_table_s_rows():
    for name, text in (("axes", "x"), ("cs", "-1"), ("chip", "lm630"), ("clock", "9MHz")):
        url = f"sim://?{name}={text}"
        with pytest.raises(ArgumentError) as by_row:
            BOARD[name].convert(text, url)
        with pytest.raises(ArgumentError) as by_port:
            resolve_port(url)
        with pytest.raises(ArgumentError) as by_transport:
            transport_class("sim://").from_url(url)
        with pytest.raises(ArgumentError) as by_model:  # the simulator's builder alone
            build_bus(url)
        assert str(by_row.value) == str(by_port.value) == str(by_transport.value) == \
            str(by_model.value)
        assert by_port.value.argument == name
