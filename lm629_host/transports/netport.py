"""A serial port over the network, as pyserial's URL handlers reach it (``rfc2217://``,
``socket://``): pyserial's RFC 2217 client fitted to ser2net, and what a server says when it
refuses a client.

ser2net (tested with 4.3.11, docs/bridge.md) in front of a bridge: pyserial's RFC 2217 client
refuses a ``write_timeout``, waits 3 s for a SET-CONTROL answer ser2net does not give on a
line without modem-control wires, and sends every port setting again on any change (150 ms);
the bridge's switch to its faster rate must be heard within 250 ms.  A server that refuses a
second client says why in words ("Port already in use") before it closes.  The serial
transport (:mod:`.serial`) opens its ports through :func:`rfc2217_port_class` and quotes
:func:`server_says`.
"""

from __future__ import annotations

import logging
import threading
from urllib.parse import parse_qsl, urlencode

from lm629_host.urls import scheme_of

log = logging.getLogger("lm629_host.serial")

#: how long a write may block on a port before it gives up (pyserial's ``write_timeout``;
#: the RFC 2217 socket's timeout)
WRITE_TIMEOUT_S = 2.0


#: values of ``ign_set_control=`` that mean "wait for the server's answer after all"
_NO = ("0", "no", "false", "off")


def rfc2217_url(device: str) -> str:
    """``device`` with pyserial's ``ign_set_control`` option added when it is an
    ``rfc2217://`` URL that does not say otherwise.  ser2net in front of a pseudo-terminal (or
    any line without modem-control wires) does not answer RFC 2217's SET-CONTROL, and without
    the option pyserial's open waits 3 s for that answer and fails ("timeout while waiting for
    option 'control'").  The bridge uses no modem-control line, so nothing is lost by not
    waiting.  ``ign_set_control=0`` (or no/false/off) drops the option: the answer is awaited.
    Other schemes are returned as they are."""
    if scheme_of(device) != "rfc2217":
        return device
    base, _, query = device.partition("?")
    pairs = parse_qsl(query, keep_blank_values=True)
    given = [v for k, v in pairs if k == "ign_set_control"]
    if given and given[0].strip().lower() in _NO:
        pairs = [(k, v) for k, v in pairs if k != "ign_set_control"]
    elif not given:
        pairs.append(("ign_set_control", ""))
    return base + ("?" + urlencode(pairs, safe=":/") if pairs else "")


#: the name pyserial gives its RFC 2217 client's reader thread (serial/rfc2217.py)
_RFC2217_READER = "pySerial RFC 2217 reader thread"


def quiet_rfc2217_reader() -> None:
    """pyserial's RFC 2217 client answers telnet options from its reader thread without a
    guard: a server that closes at once (ser2net refusing a second client, or killed) ends
    that thread with a traceback on stderr, while the open or the link reports the same
    failure in its own one line.  Such an end goes to the debug log instead; every other
    thread's exception still goes to the hook that was there."""
    previous = threading.excepthook
    if getattr(previous, "lm629_quiet", False):
        return

    def hook(args) -> None:  # threading.ExceptHookArgs
        thread = args.thread
        if thread is not None and thread.name.startswith(_RFC2217_READER) and \
                issubclass(args.exc_type, OSError):
            log.debug("%s ended: %s", thread.name, args.exc_value)
            return
        previous(args)

    hook.lm629_quiet = True  # type: ignore[attr-defined]  # a mark on the function: installed once
    threading.excepthook = hook


def rfc2217_port_class() -> type:
    """pyserial's RFC 2217 client, with its port settings sent only when they change.

    pyserial sends every setting again (rate, data bits, parity, stop bits, then SET-CONTROL)
    and waits for the answers, 50 ms a look and 100 ms more for SET-CONTROL under
    ``ign_set_control``, whenever any attribute changes, a read timeout included: 150 ms.  The
    bridge's switch to its faster rate must be heard at the new rate within its 250 ms window
    (BAUD_WINDOW_MS), so that 150 ms made the switch miss on a busy machine.  Here a change
    of the rate alone is SET-BAUDRATE alone, its answer looked for every millisecond (ser2net
    answers with the rate it set; another rate is pyserial's ValueError, "remote rejected"),
    a change the server does not see (a timeout) sends nothing, and anything else is
    pyserial's own full exchange."""
    import struct
    import time

    from serial import SerialException
    from serial.rfc2217 import Serial

    class RFC2217Port(Serial):
        _sent: tuple | None = None  # the settings the server last acknowledged

        def open(self) -> None:
            """pyserial's open; then the write deadline every other port has
            (:data:`WRITE_TIMEOUT_S`), as the socket's timeout: pyserial refuses a
            ``write_timeout`` here, and its socket's own (5 s) bounded a write before."""
            super().open()
            if self._socket is not None:
                self._socket.settimeout(WRITE_TIMEOUT_S)

        def rfc2217_set_control(self, value: bytes) -> None:
            """SET-CONTROL (DTR, RTS, flow control) sent; under ``ign_set_control`` no answer
            is awaited at all (pyserial sleeps 100 ms instead, three times in each open: the
            bridge uses no modem-control line)."""
            if not self._ignore_set_control_answer:
                super().rfc2217_set_control(value)
                return
            self._rfc2217_options["control"].set(value)

        def _settings(self) -> tuple:
            return (self._baudrate, self._bytesize, self._parity, self._stopbits,
                    self._rtscts, self._xonxoff, self._write_timeout)

        def _reconfigure_port(self) -> None:
            sent, now = self._sent, self._settings()
            if sent is None or self._socket is None or sent[1:] != now[1:]:
                super()._reconfigure_port()
            elif sent[0] != now[0]:
                item = self._rfc2217_port_settings["baudrate"]
                item.set(struct.pack("!I", self._baudrate))
                deadline = time.monotonic() + self._network_timeout
                while not item.is_ready():  # ValueError when the server set another rate
                    if time.monotonic() > deadline:
                        raise SerialException(f"no answer to SET-BAUDRATE {self._baudrate} "
                                              f"within {self._network_timeout:g} s")
                    time.sleep(0.001)
            self._sent = now

    return RFC2217Port



def server_words(data: bytes) -> str:
    """The text at the end of ``data`` when it is a line of words (``Port already in use``),
    else ''."""
    if not data.endswith(b"\n"):
        return ""
    line = data.rstrip(b"\r\n\0").rpartition(b"\n")[2].strip()
    if len(line) >= 6 and all(32 <= b < 127 for b in line) and any(65 <= b <= 122 for b in line):
        return line.decode("ascii")
    return ""


def refusal(device: str, said: str) -> str:
    """The one line for a server that refused this client with ``said``."""
    hostport = device.split("://", 1)[1].split("?", 1)[0]
    if "in use" in said.lower():
        port = hostport.rpartition(":")[2]
        return (f"the server at {hostport} answered {said!r}: another client holds this bench "
                "(ser2net serves one at a time; on its machine `ss -tn state established "
                f"sport = :{port}` shows who; in a lab, the place's lock says)")
    return f"the server at {hostport} answered {said!r} and closed the connection"


def server_says(device: str, wait_s: float = 1.0) -> str:
    """What the TCP server of a ``socket://`` or ``rfc2217://`` URL says to a new connection
    before anything is sent (ser2net: "Port already in use" to a second client), or ''.
    Asked only after an open failed, to say why."""
    import socket
    import time

    hostport = device.split("://", 1)[1].split("?", 1)[0].split("/", 1)[0]
    host, _, port = hostport.rpartition(":")
    heard = b""
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=wait_s) as sock:
            deadline = time.monotonic() + wait_s
            while (left := deadline - time.monotonic()) > 0:
                sock.settimeout(left)
                chunk = sock.recv(256)
                if not chunk:
                    break
                heard += chunk.replace(b"\xff\xff", b"")
                if server_words(no_telnet(heard)):
                    break
    except (OSError, ValueError):
        pass
    return server_words(no_telnet(heard))


def no_telnet(data: bytes) -> bytes:
    """``data`` without its telnet commands (IAC sequences: ser2net's RFC 2217 greeting)."""
    out, i = bytearray(), 0
    while i < len(data):
        b = data[i]
        if b != 0xFF:
            out.append(b)
            i += 1
        elif i + 1 < len(data) and data[i + 1] == 0xFA:  # SB ... IAC SE
            end = data.find(b"\xff\xf0", i + 2)
            i = len(data) if end < 0 else end + 2
        else:
            i += 3 if i + 1 < len(data) and 0xFB <= data[i + 1] <= 0xFE else 2
    return bytes(out)


__all__ = ["WRITE_TIMEOUT_S", "no_telnet", "quiet_rfc2217_reader", "refusal", "rfc2217_port_class",
           "rfc2217_url", "server_says", "server_words"]
