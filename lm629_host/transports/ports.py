"""What a port opens: one place that settles a port URL and the options given beside it.

A port is named by a URL (``sim://?axes=2``, ``serial:///dev/ttyACM0?cs=1``,
``socket://bench:7000``).  Four things about the chips behind it can be said in the URL's
query or as arguments (:func:`lm629_host.open`, :func:`lm629_host.open_board`, the CLI's
``--chip``/``--clock``/``--axis``, a profile):

=========  ==================================================================================
``chip``   ``lm628`` or ``lm629`` (default ``lm629``)
``clock``  the chip's clock, 1..8 MHz (``8MHz``, ``6e6``; a number in Hz as an argument)
``axes``   how many chips a multi-axis board has (chip selects 0..axes-1)
``cs``     the one chip :func:`lm629_host.open` drives on such a board
=========  ==================================================================================

The rules, applied by :func:`resolve_port` and nowhere else:

* the same option in the URL and as an argument must agree: a conflict is an
  :class:`~lm629_host.errors.ArgumentError` naming both sides;
* a bad value is an ``ArgumentError`` naming the option (``axes='x' in sim://?axes=x is not
  a whole number of chips``);
* an unknown scheme is a :class:`~lm629_host.errors.SchemeError` (a ValueError and a
  TransportError: bad usage, exit 2 in the CLI), except that any scheme pyserial knows is a
  serial port (``socket://``, ``rfc2217://``, ``spy://``, ``loop://`` through the registry's
  ``URL_SCHEMES``, any other handler with ``serial://`` put in front);
* a simulator builds the chips it is told of: its URL gets the arguments (``chip=``,
  ``clock=``, ``axes=``) so that the model matches what the driver believes; a hardware
  transport gets none of the four (they describe the board, not the link).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from lm629_host.errors import ArgumentError
from lm629_host.bus.program import TraceCallback
from lm629_host.transports import BUILTIN, DEFAULT_URL, URL_SCHEMES, registry, transport_class
from lm629_host.transports.base import Transport
from lm629_host.bus.url_board import AXES_WHAT, BOARD, BOARD_OPTIONS, CHIPS, CS_WHAT, check_clock
from lm629_host.urls import (PortURL, parse_hz, port_url, scheme_of,
                             split_params, with_query)

if TYPE_CHECKING:  # a profile's port is settled here, but only a profile's user reads one
    from lm629_host.config.profile import Profile


@dataclass(frozen=True)
class PortSpec:
    """A port, settled: which transport opens it, with which URL, and what is behind it."""

    url: str  #: the URL as given
    scheme: str  #: the scheme of the transport that opens it (``serial`` for a device path)
    transport: type[Transport]  #: its class (module imported)
    #: the URL handed to ``transport.from_url``: the user's, parsed once, with what the
    #: arguments add for a simulator (``str()`` of it is still what the user wrote)
    open_url: PortURL
    chip: str  #: ``lm628`` or ``lm629``
    clock_hz: float | None  #: the chip's clock when said (URL or argument); None: not said
    axes: int | None  #: the number of chips when said; None: what the transport reports
    cs: int | None  #: the one chip to drive (``open``); None: the only chip, or all of them

    @property
    def simulated(self) -> bool:
        return self.transport.simulated

    def open_transport(self, trace: TraceCallback | None = None) -> Transport:
        """Open the transport (its errors are its own: port missing, busy, no answer)."""
        return self.transport.from_url(self.open_url, trace=trace)


def _hz_text(hz: float) -> str:
    return f"{hz / 1e6:g}MHz" if hz >= 1e6 else f"{hz:g}Hz"


# each option given as an argument, checked (the value, and how to show it); the URL's
# value is checked by the option's row of the transport's table (bus/url_board.py)
def _chip_argument(value: object) -> tuple[str, str]:
    if not isinstance(value, str) or value.lower() not in CHIPS:
        raise ArgumentError("chip", value, f"chip={value!r}: expected 'lm628' or 'lm629'")
    return value.lower(), f"chip={value.lower()}"


def _clock_argument(value: object) -> tuple[float, str]:
    try:
        hz = parse_hz(value) if isinstance(value, str) else float(value)  # type: ignore[arg-type]  # anything else: the TypeError below
    except (TypeError, ValueError):
        raise ArgumentError("clock", value, f"clock={value!r} is not a frequency "
                                            "(8MHz, 6e6)") from None
    return check_clock(hz, f"clock={_hz_text(hz)}"), f"clock={_hz_text(hz)}"


def _whole_argument(name: str, lo: int, what: str) -> Callable[[object], tuple[int, str]]:
    def check(value: object) -> tuple[int, str]:
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            raise ArgumentError(name, value, f"{name}={value!r} must be {what} (at least {lo})",
                                lo=lo)
        return value, f"{name}={value}"
    return check


#: option -> the check of an argument
_ARGUMENTS: dict[str, Callable[[Any], tuple[Any, str]]] = {
    "chip": _chip_argument,
    "clock": _clock_argument,
    "axes": _whole_argument("axes", 1, AXES_WHAT),
    "cs": _whole_argument("cs", 0, CS_WHAT),
}


def _settle(name: str, given: object, url: str, query: dict[str, str]) -> Any:
    """One option: the argument and the URL's value (checked by its row), each checked; they
    must agree."""
    value, shown = _ARGUMENTS[name](given) if given is not None else (None, "")
    if name in query:
        in_url = BOARD[name].convert(query[name], url)
        if value is not None and value != in_url:
            raise ArgumentError(name, given, f"{shown} conflicts with {name}={query[name]} in "
                                              f"{url}: give one of them")
        value = in_url
    return value


def _pyserial_knows(scheme: str) -> bool:
    """True when pyserial has a URL handler for ``scheme`` (``socket``, ``rfc2217``, ``spy``,
    ``loop``, ...): such a URL is a serial port (pyserial's ``serial_for_url`` opens it)."""
    if not scheme.isidentifier():
        return False
    try:
        return importlib.util.find_spec(f"serial.urlhandler.protocol_{scheme}") is not None
    except ImportError:  # pyserial missing: then no serial port at all
        return False


def _transport(url: PortURL) -> tuple[str, type[Transport], PortURL]:
    """(scheme, transport class, URL for it): the registry's (with its :data:`URL_SCHEMES
    <lm629_host.transports.URL_SCHEMES>`, pyserial's usual handlers opened as they are), else
    the serial transport, ``serial://`` in front, for any other scheme pyserial has a handler
    for (``hwgrep://``, ``alt://``...)."""
    scheme = scheme_of(url)
    if (scheme not in BUILTIN and scheme not in URL_SCHEMES and scheme not in registry()
            and _pyserial_knows(scheme)):
        return "serial", transport_class("serial://"), PortURL.parse("serial://" + url.given)
    cls = transport_class(url)  # SchemeError for an unknown scheme
    return cls.scheme or scheme, cls, url


def resolve_port(url: str | PortURL = DEFAULT_URL, *, chip: str | None = None,
                 clock: float | str | None = None, axes: int | None = None,
                 cs: int | None = None) -> PortSpec:
    """Settle ``url`` and the options given beside it (see the module docstring) into a
    :class:`PortSpec`; nothing is opened.  ``clock``: Hz, or a frequency text (``"6MHz"``).

    Raises :class:`~lm629_host.errors.ArgumentError` (a ValueError naming the option, and
    both sides of a conflict) or :class:`~lm629_host.errors.SchemeError` (an unknown scheme);
    a transport's own options are checked when it opens.
    """
    if not isinstance(url, (str, PortURL)) or not str(url).strip():
        raise ArgumentError("port", url, f"port {url!r} is empty: give a URL (sim://, "
                                         "serial:///dev/ttyACM0, ftdi://...) or a device path")
    try:
        parsed = port_url(url)  # the one parse of the user's text
    except ValueError as exc:  # a name given twice
        raise ArgumentError("port", str(url), str(exc)) from None
    scheme, cls, open_url = _transport(parsed)
    q = parsed.query()
    if (cls.simulated and parsed.scheme in BUILTIN
            and (parsed.netloc or parsed.path not in ("", "/"))):
        # the bundled simulators' URLs are a scheme and options: a host or path in one
        # (``sim:///x``) is a mistake said at once, not silently ignored
        where = parsed.netloc or parsed.path
        raise ArgumentError("port", parsed.given, f"{parsed.given}: a simulator has no host "
                            f"or path ({where!r}): its options go after '?', e.g. "
                            f"{parsed.scheme}://?axes=2")
    url = parsed.given
    if cls.simulated and "axis" in q and "profile" not in q:
        # axis= is a simulator's, but only beside profile= (the twin of one of its axes): alone
        # it is the number of chips misspelt, as an unknown name near axes= would be
        number = q["axis"].strip().isdigit()
        raise ArgumentError("axis", q["axis"], f"axis={q['axis']} in {url}: axis= names an axis "
                                               "of a profile (with profile=FILE); "
                                               + (f"did you mean axes={q['axis']} ({q['axis']} "
                                                  "chips on one bus; cs=K opens the one on chip "
                                                  "select K)?" if number else
                                                  "did you mean axes=N (N chips on one bus)?"))
    values = {name: _settle(name, given, url, q)
              for name, given in (("chip", chip), ("clock", clock), ("axes", axes), ("cs", cs))}
    if cls.simulated:  # the model is built from its URL: tell it what the arguments say
        open_url, _cs = split_params(open_url, {"cs"})
        add = {name: str(round(values[name]) if name == "clock" else values[name])
               for name in ("chip", "clock", "axes") if values[name] is not None and name not in q}
        if add:
            open_url = with_query(open_url, add)
    else:  # they describe the board, not the link
        open_url, _taken = split_params(open_url, BOARD_OPTIONS)
    return PortSpec(url=url, scheme=scheme, transport=cls, open_url=open_url,
                    chip=values["chip"] or "lm629", clock_hz=values["clock"],
                    axes=values["axes"], cs=values["cs"])


# ---------------------------------------------------------------------------- a profile's port
def profile_port(profile: Profile) -> PortURL:
    """The port ``profile`` names, with its chip and clock (and, for a simulator, a chip per
    chip select) said in the URL, settled by :func:`resolve_port`, the one place a port meets
    ``chip=``/``clock=``/``axes=``: a URL that says otherwise
    than ``[board]`` is a ProfileError naming both.  ValueError when it names no port."""
    from lm629_host.config.profile import ProfileError  # loaded already, with the Profile

    if not profile.port:
        raise ProfileError(f"{profile.path}: [board] has no port = \"...\": give --port or "
                           "write the port URL into the profile")
    line = f":{profile.lines['port']}" if "port" in profile.lines else ""
    try:
        port = port_url(profile.port)  # the one parse of the profile's port
    except ValueError as exc:
        raise ProfileError(f"{profile.path}{line}: [board] port: {exc}") from None
    if port.scheme == "spy" and "file" in port.query():
        # a file that any command would create or truncate, read-only ones included: a
        # file a profile names could be anything the user may write
        raise ProfileError(f"{profile.path}{line}: [board] port: {profile.port!r} writes its "
                           "traffic to a file (spy://...?file=): a profile never names a "
                           "file to write; give that port with --port on the command line")
    try:
        spec = resolve_port(port, chip=profile.chip, clock=profile.clock_hz)
    except ValueError as exc:
        raise ProfileError(f"{profile.path}{line}: [board] port: {exc}") from None
    have = port.query()
    add = {"chip": profile.chip, "clock": str(round(profile.clock_hz))}
    n = max((a.cs for a in profile.axes.values()), default=0) + 1
    if spec.transport.simulated and n > 1:
        add["axes"] = str(n)  # the simulator builds the chips the profile names
    add = {k: v for k, v in add.items() if k not in have}
    return twin_port(profile, port.with_options(add))


def twin_port(profile: Profile, url: str | PortURL) -> PortURL:
    """``url``, and when it names a simulator, with ``profile=`` the profile's file unless it
    names one: the simulated chips are then built from each axis's ``[axis.NAME.plant]`` (a
    twin of the bench, :mod:`lm629_host.bench.twin`; a URL that gives its own motor keeps it,
    ``lm629_host.sim.build``)."""
    url = port_url(url)
    if not transport_class(url).simulated or "profile" in url.query():
        return url
    return url.with_options({"profile": str(profile.path)})


__all__ = ["BOARD_OPTIONS", "CHIPS", "PortSpec", "profile_port", "resolve_port", "twin_port"]
