"""Port URLs: the scheme, the query string, and one parser for the options of every transport
and simulator.

A port is named by a URL (``sim://?chip=lm628``, ``serial:///dev/ttyACM0?baud=115200``,
``ftdi://ftdi:232h/1?latency=1``).  Each transport declares its options as :class:`Option`
rows and calls :func:`parse_options`, so that every URL says the same things the same way:
``name=value`` with a type (int, float, bool, a frequency such as ``8MHz``, text), a range,
a unit for the messages, and an error that names the URL, the option and what is allowed,
for a bad value and for an unknown name alike.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, parse_qsl, urlencode, urlsplit

__all__ = ["BOARD_OPTIONS", "Option", "dataclass_options", "parse_bool", "parse_hz", "parse_options",
           "query_params", "scheme_of", "split_params", "with_query"]

#: the words a boolean option takes (an empty value, ``?strict``, means true)
_TRUE = ("1", "true", "yes", "on", "")
_FALSE = ("0", "false", "no", "off")


def scheme_of(url: str) -> str:
    """The scheme of ``url``; a bare device path (``/dev/ttyUSB0``, ``COM3``) means serial."""
    if "://" not in url:
        return "serial"
    return url.split("://", 1)[0].lower()


def query_params(url: str) -> dict[str, str]:
    """``?a=1&b=2`` of a URL as a dict of last values."""
    q = urlsplit(url).query
    return {k: v[-1] for k, v in parse_qs(q, keep_blank_values=True).items()}


def with_query(url: str, values: Mapping[str, str]) -> str:
    """``url`` with its query options replaced or added (order kept)."""
    values = dict(values)
    base, _, query = url.partition("?")
    pairs = [(k, values.pop(k) if k in values else v)
             for k, v in parse_qsl(query, keep_blank_values=True)]
    pairs += list(values.items())
    return base + ("?" + urlencode(pairs, safe=":/") if pairs else "")


def split_params(url: str, names: frozenset[str] | set[str]) -> tuple[str, dict[str, str]]:
    """``url`` without the query parameters ``names``, and their values (e.g. ``cs`` and
    ``axes``, which the board layer reads and a hardware transport does not know)."""
    if "?" not in url:
        return url, {}
    base, query = url.split("?", 1)
    pairs = parse_qsl(query, keep_blank_values=True)
    taken = {k: v for k, v in pairs if k in names}
    if not taken:
        return url, {}
    rest = urlencode([(k, v) for k, v in pairs if k not in names], safe=":/")
    return (base + "?" + rest if rest else base), taken


def parse_hz(text: str) -> float:
    """A frequency: ``8MHz``, ``8 MHz``, ``8e6``, ``8000k`` -> Hz.  ValueError for anything
    else, inf and nan included."""
    t = str(text).strip().lower().replace("hz", "").strip()
    mult = 1.0
    if t.endswith("m"):
        mult, t = 1e6, t[:-1]
    elif t.endswith("k"):
        mult, t = 1e3, t[:-1]
    v = float(t) * mult
    if v != v or v in (float("inf"), float("-inf")):
        raise ValueError(text)
    return v


def parse_bool(text: str) -> bool:
    """1/0, true/false, yes/no, on/off (an empty value is true: ``?strict``)."""
    low = text.strip().lower()
    if low in _TRUE:
        return True
    if low in _FALSE:
        return False
    raise ValueError(f"expected a boolean (1/0), got {text!r}")


def _number(text: str, kind: str) -> int | float:
    """int: decimal, 0x.., or a whole number in float notation (``1e6``); float; hz."""
    if kind == "hz":
        return parse_hz(text)
    if kind == "int":
        t = text.strip()
        if "e" in t.lower() and not t.lower().startswith("0x"):
            v = float(t)
            if v != int(v):
                raise ValueError(text)
            return int(v)
        return int(t, 0)
    v = float(text)
    if v != v:
        raise ValueError(text)
    return v


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Option:
    """One URL option: its name, type, default, allowed range (inclusive) and unit.

    ``kind`` is ``"int"``, ``"float"``, ``"hz"`` (a frequency, ``8MHz`` allowed; a float in
    Hz), ``"bool"`` or ``"str"``; ``optional`` lets ``none`` stand for None; ``choices`` limits
    a text option.
    """

    name: str
    kind: str = "str"
    default: Any = None
    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    choices: tuple[str, ...] = ()
    optional: bool = False
    #: a text option with its own grammar (``wiring=d5-low,d2-d3``): text -> value, ValueError
    #: saying what is allowed; the message gets the URL and the option's name in front
    parse: Callable[[str], Any] | None = None

    def convert(self, text: str, url: str) -> Any:
        """``text`` as this option's value; ValueError naming ``url`` and the option."""
        name = self.name
        if self.optional and text.strip().lower() == "none":
            return None
        if self.kind == "bool":
            try:
                return parse_bool(text)
            except ValueError as exc:
                raise ValueError(f"{url}: {name}={text!r}: {exc}") from None
        if self.kind == "str":
            if self.parse is not None:
                try:
                    return self.parse(text)
                except ValueError as exc:
                    raise ValueError(f"{url}: {name}={text!r}: {exc}") from None
            if self.choices and text.lower() not in self.choices:
                raise ValueError(f"{url}: {name}={text!r}: expected one of "
                                 f"{', '.join(self.choices)}")
            return text
        try:
            value = _number(text, self.kind)
        except ValueError:
            what = "a frequency (8MHz, 6e6)" if self.kind == "hz" else "a number"
            if self.kind == "int" and _is_float(text):
                what = "a whole number"
            raise ValueError(f"{url}: {name}={text!r} is not {what}") from None
        if (self.lo is not None and value < self.lo) or (self.hi is not None and value > self.hi):
            raise ValueError(f"{url}: {name}={text} is outside {self.range()}")
        return value

    def range(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return f"{_fmt(self.lo)}..{_fmt(self.hi)}{unit}"

    def describe(self) -> str:
        """``name`` with its unit or choices, for the list of known options."""
        if self.choices:
            return f"{self.name} ({'|'.join(self.choices)})"
        return f"{self.name} ({self.unit})" if self.unit else self.name


def _fmt(v: float | None) -> str:
    if v is None:
        return ""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e12 else f"{v:g}"


#: the options that describe the board, taken on any URL (lm629_host.transports.ports takes them out
#: before a transport sees the rest)
BOARD_OPTIONS = frozenset({"chip", "clock", "axes", "cs"})


def parse_options(url: str, options: Iterable[Option], *, what: str = "",
                  ignore: Iterable[str] = (), aliases: Mapping[str, str] | None = None,
                  given_only: bool = False) -> dict[str, Any]:
    """The options of ``url``, checked and converted: ``{name: value}``.

    Every option appears with its default unless ``given_only``.  ``ignore``: names that
    belong to someone else (another layer of the same URL) and are skipped.  ``aliases``:
    short URL names for option names (``chip`` -> ``variant``).  Any other name raises
    ValueError listing the known ones, as does a value of the wrong type or outside its range.
    """
    specs = {o.name: o for o in options}
    aliases = dict(aliases or {})
    raw = query_params(url)
    q = {aliases.get(k, k): v for k, v in raw.items()}
    said = {aliases.get(k, k): k for k in raw}  # the name as the URL spells it, for messages
    skip = set(ignore)
    unknown = set(q) - set(specs) - skip
    if unknown:
        # every name the URL may carry: this layer's, its aliases, the other layers' (skip)
        # and the board's, so that the list is the scheme's whole list
        others = (skip | BOARD_OPTIONS) - set(specs) - set(aliases)
        known = sorted([*(o.describe() for o in specs.values()), *aliases, *others])
        names = [*specs, *aliases, *others]
        hints = []
        for name in sorted(unknown):
            close = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
            hints.append(f"{name} (did you mean {close[0]}?)" if close else name)
        label = f"{what} " if what else ""
        raise ValueError(f"{url}: unknown {label}parameter(s) {', '.join(hints)}; "
                         f"known: {', '.join(known)}")
    out: dict[str, Any] = {}
    for name, spec in specs.items():
        if name in q:
            shown = spec if said[name] == name else dataclasses.replace(spec, name=said[name])
            out[name] = shown.convert(q[name], url)
        elif not given_only:
            out[name] = spec.default
    return out


def dataclass_options(cls: Any, overrides: Iterable[Option] = ()) -> list[Option]:
    """An :class:`Option` for each field of a dataclass, typed from its annotation (``int``,
    ``float``, ``bool``, ``str``, each possibly ``| None``); ``overrides`` replace fields by
    name (a frequency, a range, choices)."""
    by_name = {o.name: o for o in overrides}
    out = []
    for f in dataclasses.fields(cls):
        if f.name in by_name:
            out.append(by_name[f.name])
            continue
        t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        kind = next((k for k in ("bool", "float", "int") if k in t), "str")
        out.append(Option(f.name, kind, optional="None" in t))
    return out
