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
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, overload
from urllib.parse import parse_qsl, urlencode, urlsplit

__all__ = ["Option", "PortURL", "port_url", "dataclass_options", "parse_bool", "parse_hz", "parse_options",
           "query_params", "scheme_of", "read_rows", "split_params", "table_names", "with_defaults", "with_query"]

#: the words a boolean option takes (an empty value, ``?strict``, means true)
_TRUE = ("1", "true", "yes", "on", "")
_FALSE = ("0", "false", "no", "off")


@dataclass(frozen=True, eq=False)
class PortURL:
    """A port URL, parsed once: what the user wrote, its parts, and its options in order.

    Every layer that reads a port's options (the CLI, :mod:`~lm629_host.transports.ports`,
    each transport, the simulators) takes a ``PortURL`` or a text; given a text it parses it
    here, given a ``PortURL`` it reads the parts already split.  What the CLI and a profile add
    (``chip=``, ``clock=``, ``axes=``, ``vcd=``, ``profile=``) goes into :meth:`with_options`,
    never into a rewritten string, and ``str()`` is always what the user wrote: every message
    that quotes the port quotes the user's text.  :attr:`text` is the whole URL with what was
    added (what a library that takes a URL string, pyserial, is handed).

    A name given twice (``sim://?chip=lm629&chip=lm628``) is refused here, whatever layer owns
    it: which one was meant cannot be guessed, and pyserial refuses it too.
    """

    given: str  #: what the user wrote (``str()`` of the URL)
    scheme: str  #: lower case; ``serial`` for a bare device path
    netloc: str
    path: str
    params: tuple[tuple[str, str], ...]  #: the options in order, the added ones last
    added: frozenset[str] = frozenset()  #: the names :meth:`with_options` added
    base: str = ""  #: the URL without its query (``sim://``, ``serial:///dev/ttyACM0``)

    @classmethod
    def parse(cls, text: str) -> PortURL:
        """``text`` split once; ValueError for a name given twice."""
        parts = urlsplit(text)
        scheme = "serial" if "://" not in text else text.split("://", 1)[0].lower()
        pairs = tuple(parse_qsl(parts.query, keep_blank_values=True))
        seen: dict[str, str] = {}
        for k, v in pairs:
            if k in seen:
                raise ValueError(f"{text}: {k}= is given twice ({seen[k]!r} and {v!r}): "
                                 "give it once")
            seen[k] = v
        return cls(text, scheme, parts.netloc, parts.path, pairs, frozenset(),
                   text.partition("?")[0])

    @property
    def text(self) -> str:
        """The whole URL, with the options added to it (for a library that takes a string)."""
        return self.base + ("?" + urlencode(self.params, safe=":/") if self.params else "")

    def query(self) -> dict[str, str]:
        """The options by name (each given at most once: :meth:`parse` refused duplicates)."""
        return dict(self.params)

    def with_options(self, values: Mapping[str, str]) -> PortURL:
        """These options replaced or added (order kept), not written into :attr:`given`:
        what the CLI or a profile says beside the user's URL."""
        values = dict(values)
        pairs = [(k, values.pop(k) if k in values else v) for k, v in self.params]
        added = self.added | {k for k in values}
        pairs += list(values.items())
        return PortURL(self.given, self.scheme, self.netloc, self.path, tuple(pairs),
                       frozenset(added), self.base)

    def without(self, names: frozenset[str] | set[str]) -> tuple[PortURL, dict[str, str]]:
        """This URL without the options ``names``, and their values."""
        taken = {k: v for k, v in self.params if k in names}
        if not taken:
            return self, {}
        rest = tuple((k, v) for k, v in self.params if k not in names)
        return (PortURL(self.given, self.scheme, self.netloc, self.path, rest,
                        self.added - set(names), self.base), taken)

    def unwrapped(self) -> PortURL:
        """A pyserial URL given after ``serial://`` (``serial://socket://host:2000?baud=1``) as
        the URL inside, its options and :attr:`given` kept; any other URL as it is."""
        inner = self.base[len("serial://"):] if self.scheme == "serial" else ""
        if "://" not in inner or not self.base.lower().startswith("serial://"):
            return self
        parts = urlsplit(inner)
        return PortURL(self.given, inner.split("://", 1)[0].lower(), parts.netloc, parts.path,
                       self.params, self.added, inner)

    def __str__(self) -> str:
        return self.given

    def __repr__(self) -> str:
        return f"PortURL({self.text!r})"

    def __eq__(self, other: object) -> bool:
        if isinstance(other, PortURL):
            return self.text == other.text
        return NotImplemented

    def __hash__(self) -> int:
        return hash(self.text)


def port_url(url: str | PortURL) -> PortURL:
    """``url`` as a :class:`PortURL` (parsed now when it is a text)."""
    return url if isinstance(url, PortURL) else PortURL.parse(url)


def scheme_of(url: str | PortURL) -> str:
    """The scheme of ``url``; a bare device path (``/dev/ttyUSB0``, ``COM3``) means serial."""
    if isinstance(url, PortURL):
        return url.scheme
    if "://" not in url:
        return "serial"
    return url.split("://", 1)[0].lower()


def query_params(url: str | PortURL) -> dict[str, str]:
    """``?a=1&b=2`` of a URL as a dict (a name given twice: ValueError, see :class:`PortURL`)."""
    return port_url(url).query()


@overload
def with_query(url: str, values: Mapping[str, str]) -> str: ...
@overload
def with_query(url: PortURL, values: Mapping[str, str]) -> PortURL: ...
def with_query(url: str | PortURL, values: Mapping[str, str]) -> str | PortURL:
    """``url`` with its query options replaced or added (order kept): a text for a text, a
    :class:`PortURL` (its :attr:`~PortURL.given` kept) for a ``PortURL``."""
    if isinstance(url, PortURL):
        return url.with_options(values)
    return PortURL.parse(url).with_options(values).text


@overload
def split_params(url: str, names: frozenset[str] | set[str]) -> tuple[str, dict[str, str]]: ...
@overload
def split_params(url: PortURL, names: frozenset[str] | set[str]
                 ) -> tuple[PortURL, dict[str, str]]: ...
def split_params(url: str | PortURL, names: frozenset[str] | set[str]
                 ) -> tuple[str | PortURL, dict[str, str]]:
    """``url`` without the query parameters ``names``, and their values (e.g. ``cs`` and
    ``axes``, which the board layer reads and a hardware transport does not know)."""
    if isinstance(url, PortURL):
        return url.without(names)
    if "?" not in url:
        return url, {}
    rest, taken = PortURL.parse(url).without(names)
    return (rest.text if taken else url), taken


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
    #: words besides ``none`` that stand for None in an optional option (``busy_us=auto``)
    none_words: tuple[str, ...] = ()
    #: a text option with its own grammar (``wiring=d5-low,d2-d3``): text -> value, ValueError
    #: saying what is allowed; the message gets the URL and the option's name in front
    parse: Callable[[str], Any] | None = None
    #: a number taken outside the range that turns the option off (``failsafe=0``)
    off: float | None = None
    #: the row's own check of the URL's text, ``(text, url) -> value``, raising its whole
    #: message (the board's rows: an ArgumentError naming the option, as for an argument)
    check: Callable[[str, Any], Any] | None = None

    def convert(self, text: str, url: str | PortURL) -> Any:
        """``text`` as this option's value; ValueError naming ``url`` and the option."""
        name = self.name
        if self.check is not None:
            return self.check(text, url)
        if self.optional and text.strip().lower() in ("none", *self.none_words):
            return None
        if self.kind == "bool":
            try:
                return parse_bool(text)
            except ValueError as exc:
                raise ValueError(f"{url}: {name}={text!r}: {exc}") from None
        if self.kind == "str":
            if not text and self.parse is None and "" not in self.choices:
                raise ValueError(f"{url}: {name}= is empty: give a value or leave it out")
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
        if value == self.off:
            return value
        if (self.lo is not None and value < self.lo) or (self.hi is not None and value > self.hi):
            raise ValueError(f"{url}: {name}={text} is outside {self.range()}")
        return value

    def range(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        off = f"{_fmt(self.off)} (off) or " if self.off is not None else ""
        return f"{off}{_fmt(self.lo)}..{_fmt(self.hi)}{unit}"

    def describe(self) -> str:
        """``name`` with its unit or choices, for the list of known options."""
        if self.choices:
            return f"{self.name} ({'|'.join(c for c in self.choices if c)})"
        return f"{self.name} ({self.unit})" if self.unit else self.name


def _fmt(v: float | None) -> str:
    if v is None:
        return ""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e12 else f"{v:g}"


def parse_options(url: str | PortURL, options: Iterable[Option], *, what: str = "",
                  aliases: Mapping[str, str] | None = None,
                  given_only: bool = False) -> dict[str, Any]:
    """The options of ``url``, checked and converted against one table: ``{name: value}``.

    ``options`` is the whole table of what the URL may say (a transport's: the board's rows,
    the link's, its own, its simulator's); it is what the checks and the list of known names
    in the message both use.  Every option appears with its default unless ``given_only``.
    ``aliases``: short URL names for option names (``busy`` -> ``command_busy_s``).  Any other
    name raises ValueError listing the known ones and the closest, as does a value of the
    wrong type or outside its range.
    """
    specs = {o.name: o for o in options}
    aliases = dict(aliases or {})
    url = port_url(url)
    raw = url.query()
    q = {aliases.get(k, k): v for k, v in raw.items()}
    said = {aliases.get(k, k): k for k in raw}  # the name as the URL spells it, for messages
    unknown = set(q) - set(specs)
    if unknown:  # every name the table takes: the scheme's whole list
        known = sorted([*(o.describe() for o in specs.values()), *aliases])
        names = [*specs, *aliases]
        hints = []
        import difflib  # here: only a mistake needs it, and every port's options pass by

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


def read_rows(url: str | PortURL, rows: Iterable[Option]) -> dict[str, Any]:
    """The values of ``rows`` in ``url`` (their defaults where not given), each converted by
    its row: how a part reads its own rows of a table its transport has parsed the URL
    against (:func:`parse_options`: the one check of every name), with no list of the
    names that are not its own."""
    q = port_url(url).query()
    return {o.name: o.convert(q[o.name], url) if o.name in q else o.default for o in rows}


def table_names(options: Iterable[Option], aliases: Mapping[str, str] | None = None
                ) -> frozenset[str]:
    """Every name a URL parsed against ``options`` (and ``aliases``) may carry."""
    return frozenset(o.name for o in options) | frozenset(aliases or ())


def with_defaults(rows: Iterable[Option], **defaults: Any) -> tuple[Option, ...]:
    """``rows`` (a parent's option table) with the defaults of the rows named replaced: a
    child declares its options from its parent's, the ranges kept."""
    rows = tuple(rows)
    unknown = set(defaults) - {o.name for o in rows}
    if unknown:
        raise KeyError(f"no option(s) {', '.join(sorted(unknown))} in these rows")
    return tuple(dataclasses.replace(o, default=defaults[o.name]) if o.name in defaults else o
                 for o in rows)


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
