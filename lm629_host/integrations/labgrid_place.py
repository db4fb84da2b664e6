"""A labgrid place as a port: acquire it, read the serial port it holds, release it.

labgrid brings its own fork of pyserial (pyserial-labgrid), so it lives in a virtual
environment of its own (docs/testing.md) and lm629-host does not import it here: it drives
``labgrid-client``, labgrid's public command line, found on ``PATH`` (``LM629_LABGRID_CLIENT``
names another).  The coordinator is labgrid's own setting, ``LG_COORDINATOR``, read by
``labgrid-client`` itself.

labgrid's lock is the lab's access control (ser2net, which an exporter starts in front of each
bench, has none: whoever reaches its TCP port drives the bench), so a port is used only while
its place is acquired, and a place someone else holds is refused with labgrid's own reason,
which names the holder.

:func:`network_port_url` is the one home of how a labgrid ``NetworkSerialPort`` becomes an
lm629-host URL; the labgrid driver (``labgrid_driver.py``) uses it too.
"""

from __future__ import annotations

import fnmatch
import os
import re
import shutil
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass

from lm629_host.errors import TransportError
from lm629_host.urls import PortURL

#: how long one labgrid-client call may take (a coordinator that does not answer)
CLIENT_TIMEOUT_S = 30.0


class LabgridMissing(TransportError):
    """labgrid's ``labgrid-client`` is not installed where lm629 looks for it."""


class PlaceUnavailable(TransportError):
    """The place could not be acquired (held by someone else, unknown, no coordinator)."""


def network_port_url(host: str, port: int | str, speed: int | str | None = None,
                     protocol: str = "rfc2217",
                     options: Mapping[str, object] | None = None) -> PortURL:
    """The lm629-host URL of a ``NetworkSerialPort`` (an exporter's ser2net): RFC 2217 carries
    the line's rate (``baud=`` the handshake rate, the port's ``speed``), ``raw`` is plain TCP.
    ``options`` are any options a port URL takes (``fast_baud``, ``failsafe``, ...), passed
    through as they are: the transport that reads them checks them."""
    extra = {k: _text(v) for k, v in (options or {}).items()}
    if protocol == "raw":
        url = PortURL.parse(f"socket://{host}:{port}")
    elif protocol == "rfc2217":
        url = PortURL.parse(f"rfc2217://{host}:{port}")
        if speed is not None and "baud" not in extra:
            extra = {"baud": str(speed), **extra}
    else:
        raise ValueError(f"NetworkSerialPort protocol {protocol!r}: expected raw or rfc2217")
    return url.with_options(extra) if extra else url


def _text(value: object) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    return str(value)


def client() -> str:
    """The ``labgrid-client`` to run, or :class:`LabgridMissing` in one line."""
    named = os.environ.get("LM629_LABGRID_CLIENT")
    found = named if named and os.access(named, os.X_OK) else shutil.which("labgrid-client")
    if not found:
        raise LabgridMissing(
            "labgrid is not installed: a place needs labgrid's labgrid-client on PATH (or "
            "LM629_LABGRID_CLIENT): pip install 'lm629-host[labgrid]' in a venv of its own "
            "(docs/testing.md)")
    return found


def _run(place: str | None, *args: str) -> subprocess.CompletedProcess[str]:
    argv = [client(), *(("-p", place) if place else ()), *args]
    try:
        return subprocess.run(argv, capture_output=True, text=True, timeout=CLIENT_TIMEOUT_S,
                              stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise PlaceUnavailable(f"labgrid-client {' '.join(args)} got no answer in "
                               f"{CLIENT_TIMEOUT_S:g} s: is the coordinator at "
                               f"{coordinator()} running?", place) from None


def coordinator() -> str:
    """Where labgrid-client looks for the coordinator (its own default when unset)."""
    return os.environ.get("LG_COORDINATOR", "127.0.0.1:20408")


def _reason(p: subprocess.CompletedProcess[str]) -> str:
    """labgrid-client's own one-line reason: the line naming who holds what (``... already
    acquired by HOST/USER``, on stderr for a place, on stdout for a resource), else its last
    error line."""
    lines = [ln.strip() for ln in (p.stderr + p.stdout).splitlines() if ln.strip()]
    line = next((ln for ln in lines if "acquired by" in ln), None) or next(
        (ln for ln in reversed(lines) if "Error" in ln or "error" in ln),
        lines[-1] if lines else f"labgrid-client exit {p.returncode}")
    line = re.sub(r"^labgrid-client: (Error: )?", "", line)
    if "'<broken>'" in line:
        line += (": the exporter could not serve it (its log says why; a RawSerialPort's "
                 "path must start with /dev/)")
    return line


def acquire(place: str) -> None:
    """Lock ``place`` for this user; :class:`PlaceUnavailable` with labgrid's reason (``Place
    NAME is already acquired by HOST/USER``) when it cannot."""
    p = _run(place, "acquire")
    if p.returncode != 0:
        raise PlaceUnavailable(f"labgrid refused the place: {_reason(p)} "
                               f"(coordinator {coordinator()})", place)


def release(place: str) -> bool:
    """Unlock ``place`` when this user holds it (a place someone else holds is left alone:
    labgrid refuses that release).  True when it was released."""
    try:
        return _run(place, "release").returncode == 0
    except TransportError:
        return False


@dataclass(frozen=True)
class NetworkPort:
    """A ``NetworkSerialPort`` of an acquired place, as ``labgrid-client env`` gives it."""

    host: str
    port: int
    speed: int | None = None
    protocol: str = "rfc2217"

    def url(self, options: Mapping[str, object] | None = None) -> PortURL:
        return network_port_url(self.host, self.port, self.speed, self.protocol, options)


def serial_port(place: str) -> NetworkPort:
    """The serial port of the acquired ``place`` (the environment labgrid-client writes for
    it): one ``NetworkSerialPort``, else :class:`PlaceUnavailable` saying what it holds."""
    p = _run(place, "env")
    if p.returncode != 0:
        raise PlaceUnavailable(f"labgrid-client env: {_reason(p)}", place)
    ports = parse_env_ports(p.stdout)
    if len(ports) != 1:
        raise PlaceUnavailable(
            f"holds {len(ports)} NetworkSerialPort(s), expected one (labgrid-client -p {place} "
            "show lists its resources; add-match the bench's serial port)", place)
    return ports[0]


def parse_env_ports(text: str) -> list[NetworkPort]:
    """The ``NetworkSerialPort`` entries of ``labgrid-client env``'s YAML (a list item
    ``- NetworkSerialPort:`` and its ``key: value`` lines)."""
    ports: list[NetworkPort] = []
    fields: dict[str, str] | None = None
    indent = 0

    def done() -> None:
        if fields is not None and "host" in fields and "port" in fields:
            speed = fields.get("speed")
            ports.append(NetworkPort(fields["host"], int(fields["port"]),
                                     int(speed) if speed else None,
                                     fields.get("protocol", "rfc2217")))

    for line in text.splitlines():
        m = re.match(r"(\s*)- NetworkSerialPort:\s*$", line)
        if m:
            done()
            fields, indent = {}, len(m[1])
            continue
        kv = re.match(r"(\s*)(\w+):\s*(\S.*?)\s*$", line)
        if fields is not None and kv and len(kv[1]) > indent + 2:
            fields[kv[2]] = kv[3].strip("'\"")
        elif fields is not None and line.strip() and len(line) - len(line.lstrip()) <= indent + 2:
            done()
            fields = None
    done()
    return ports


def places(pattern: str = "*") -> list[str]:
    """The coordinator's places whose name matches the shell pattern ``pattern``, sorted."""
    p = _run(None, "places")
    if p.returncode != 0:
        raise PlaceUnavailable(f"labgrid-client places: {_reason(p)} (coordinator "
                               f"{coordinator()})")
    names = [ln.split()[0] for ln in p.stdout.splitlines() if ln.strip()]
    return sorted(n for n in names if fnmatch.fnmatchcase(n, pattern))


def split_place(text: str) -> tuple[str, dict[str, str]]:
    """``NAME?opt=v&...`` -> (NAME, options): a place takes the options a port URL takes."""
    name, _, query = text.partition("?")
    name = name.strip()
    if not name:
        raise ValueError(f"{text!r}: a place name, e.g. lm629-bench (labgrid-client places "
                         "lists them)")
    return name, PortURL.parse("x://" + ("?" + query if query else "")).query()


__all__ = ["LabgridMissing", "NetworkPort", "PlaceUnavailable", "acquire", "client",
           "network_port_url", "parse_env_ports", "places", "release", "serial_port",
           "split_place"]
