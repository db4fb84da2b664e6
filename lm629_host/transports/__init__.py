"""Transports, chosen by URL scheme (like pyserial's ``serial_for_url`` and python-can's
interface names).

=================  ==========================================================  ===============
scheme             what                                                        module
=================  ==========================================================  ===============
``sim://``         the bundled chip model, in-process (the default)            ``sim``
``serial://PATH``  the bridge firmware on a USB serial port (bare paths too)   ``serial``
``ftdi://...``     an FT232H in MPSSE mode through pyftdi                      ``ftdi``
``sim+avr://``     the real bridge firmware in simavr, against the chip model  ``simavr``
``sim+ftdi://``    the FT232H transport through pyftdi on an emulated FT232H   ``simftdi``
``sim+emu://``     the bridge link protocol to the Python bridge emulator      ``bridge_emu``
=================  ==========================================================  ===============

A new transport is one module holding a :class:`~.base.Transport` subclass with a
``from_url(url, trace=...)`` classmethod, plus one line in ``SCHEMES``.
"""

from __future__ import annotations

import importlib
from urllib.parse import parse_qs, parse_qsl, urlencode, urlsplit

from ..errors import TransportError
from ..program import TraceCallback
from .base import Check, Clock, CycleTransport, PortInfo, Stats, Transport, WallClock

#: scheme -> "module:Class" (imported on first use, so that optional dependencies stay optional)
SCHEMES: dict[str, str] = {
    "sim": "lm629_host.transports.sim:SimTransport",
    "serial": "lm629_host.transports.serial:SerialTransport",
    "ftdi": "lm629_host.transports.ftdi:FtdiTransport",
    "sim+avr": "lm629_host.transports.simavr:SimAvrTransport",
    "sim+ftdi": "lm629_host.transports.simftdi:SimFtdiTransport",
    "sim+emu": "lm629_host.bridge_emu:EmuLinkTransport",
}

DEFAULT_URL = "sim://"


def scheme_of(url: str) -> str:
    """The scheme of ``url``; a bare device path (``/dev/ttyUSB0``, ``COM3``) means serial."""
    if "://" not in url:
        return "serial"
    return url.split("://", 1)[0].lower()


def query_params(url: str) -> dict[str, str]:
    """``?a=1&b=2`` of a URL as a dict of last values."""
    q = urlsplit(url).query
    return {k: v[-1] for k, v in parse_qs(q, keep_blank_values=True).items()}


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


def transport_class(url: str) -> type[Transport]:
    scheme = scheme_of(url)
    target = SCHEMES.get(scheme)
    if target is None:
        raise TransportError(
            f"unknown port scheme {scheme!r}; known: {', '.join(s + '://' for s in SCHEMES)} "
            "or a serial device path", port=url)
    module_name, cls_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TransportError(f"the {scheme}:// transport is not available: {exc}", port=url) from exc
    return getattr(module, cls_name)


def open_transport(url: str = DEFAULT_URL, *, trace: TraceCallback | None = None) -> Transport:
    """Open the transport named by ``url``."""
    cls = transport_class(url)
    return cls.from_url(url, trace=trace)  # type: ignore[attr-defined]


__all__ = [
    "Check", "Clock", "CycleTransport", "PortInfo", "Stats", "Transport", "WallClock", "SCHEMES", "DEFAULT_URL",
    "open_transport", "query_params", "scheme_of", "split_params", "transport_class",
]
