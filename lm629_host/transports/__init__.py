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
``sim+emu://``     the bridge link protocol to the Python bridge emulator      ``simemu``
``socket://``,     pyserial's URL handlers as ports, as they are: a bridge      ``serial``
``rfc2217://``,    behind ser2net or ``lm629 sim serve --tcp``, a hex dump of
``spy://``,        the traffic, a loopback (``serial://`` in front of them is
``loop://``        accepted too)
=================  ==========================================================  ===============

A transport is a :class:`~.base.Transport` subclass (the contract is in its docstring:
``from_url``, ``list_ports``, ``doctor``, ``simulated``).  The built-in ones are the table
above (:data:`BUILTIN`); another package adds its own without editing this one, through the
entry-point group ``lm629_host.transports`` (name = scheme, value = ``module:Class``), e.g. in
its ``pyproject.toml``::

    [project.entry-points."lm629_host.transports"]
    mybus = "mypackage.mybus:MyBusTransport"

Modules are imported on first use, so that optional dependencies stay optional and the
simulators are only loaded when a simulator URL is opened.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Iterator

from lm629_host.clock import Clock, WallClock
from lm629_host.errors import SchemeError, TransportError
from lm629_host.bus.program import TraceCallback
from lm629_host.urls import PortURL, query_params, scheme_of, split_params
from lm629_host.transports.base import Transport
from lm629_host.transports.reports import Check, PortInfo, Stats
from lm629_host.transports.cycle import CycleTransport

log = logging.getLogger("lm629_host.transports")

#: the entry-point group through which other packages register transports
ENTRY_POINT_GROUP = "lm629_host.transports"

#: scheme -> "module:Class" of the transports that ship with this package
BUILTIN: dict[str, str] = {
    "sim": "lm629_host.transports.sim:SimTransport",
    "serial": "lm629_host.transports.serial:SerialTransport",
    "ftdi": "lm629_host.transports.ftdi:FtdiTransport",
    "sim+avr": "lm629_host.transports.simavr:SimAvrTransport",
    "sim+ftdi": "lm629_host.transports.simftdi:SimFtdiTransport",
    "sim+emu": "lm629_host.transports.simemu:EmuLinkTransport",
}
#: other schemes a built-in transport opens as they are: pyserial's URL handlers
#: (``serial_for_url``), so that ``--port socket://host:port`` needs no ``serial://`` in front.
#: Not transports of their own (``lm629 list`` and ``doctor`` walk :data:`BUILTIN` once).
URL_SCHEMES: dict[str, str] = {"socket": "serial", "rfc2217": "serial", "spy": "serial",
                               "loop": "serial"}
#: :data:`BUILTIN` by the name lab scripts and plug-ins import it under
SCHEMES = BUILTIN

DEFAULT_URL = "sim://"


def registry() -> dict[str, str]:
    """scheme -> "module:Class": the built-in transports, then those that installed packages
    register under :data:`ENTRY_POINT_GROUP` (read afresh at each call: a package installed
    while the program runs is seen).  A plug-in cannot replace a built-in scheme."""
    from importlib.metadata import entry_points  # here: importing it costs ~13 ms at startup

    found = dict(BUILTIN)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        scheme = ep.name.lower()
        if scheme in BUILTIN:
            log.warning("entry point %s = %s ignored: %s:// is built in", ep.name, ep.value,
                        scheme)
            continue
        found.setdefault(scheme, ep.value)
    return found


def _load(scheme: str, target: str) -> type[Transport]:
    module_name, _, cls_name = target.partition(":")
    cls = getattr(importlib.import_module(module_name), cls_name)
    if not (isinstance(cls, type) and issubclass(cls, Transport)):
        raise TypeError(f"{target} (registered for {scheme}://) is not a Transport subclass")
    return cls


def transport_class(url: str | PortURL) -> type[Transport]:
    """The transport class for ``url``'s scheme (its module imported now); an unknown scheme
    is a :class:`~lm629_host.errors.SchemeError`."""
    scheme = scheme_of(url)
    key = URL_SCHEMES.get(scheme, scheme)
    # a built-in scheme is never a plug-in's (registry()): the entry points are read (~10 ms
    # of every command that opens a port) only for a scheme that is not built in
    target = BUILTIN.get(key)
    if target is None:
        known = registry()
        target = known.get(key)
        if target is None:
            names = [*known, *URL_SCHEMES]
            raise SchemeError(
                f"unknown port scheme {scheme!r}; known: {', '.join(s + '://' for s in names)} "
                "or a serial device path", port=str(url))
    try:
        return _load(scheme, target)
    except (ImportError, AttributeError, TypeError) as exc:
        raise TransportError(f"the {scheme}:// transport is not available: {exc}", port=str(url)) from exc


def transport_classes() -> Iterator[tuple[str, type[Transport] | None, str | None]]:
    """(scheme, class or None, why it cannot be loaded) for every registered transport: what
    ``lm629 list`` and ``lm629 doctor`` walk through."""
    for scheme, target in registry().items():
        try:
            yield scheme, _load(scheme, target), None
        except Exception as exc:  # noqa: BLE001 - a missing optional backend is a doctor line
            yield scheme, None, f"{type(exc).__name__}: {exc}"


def is_simulated(url: str | PortURL) -> bool:
    """True when ``url`` names a simulated port (no hardware behind it)."""
    return transport_class(url).simulated


def open_transport(url: str | PortURL = DEFAULT_URL, *, trace: TraceCallback | None = None) -> Transport:
    """Open the transport named by ``url``."""
    return transport_class(url).from_url(url, trace=trace)


__all__ = [
    "BUILTIN", "Check", "Clock", "CycleTransport", "DEFAULT_URL", "ENTRY_POINT_GROUP",
    "PortInfo", "SCHEMES", "Stats", "Transport", "URL_SCHEMES", "WallClock", "is_simulated",
    "open_transport",
    "query_params", "registry", "scheme_of", "split_params", "transport_class", "transport_classes",
]
