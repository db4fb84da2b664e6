"""``serial://PATH?baud=115200``: the bridge firmware on a USB serial port, through pyserial.

A bare device path (``/dev/ttyACM0``, ``/dev/ttyUSB0``, ``COM3``) means the same, and so does a
pyserial URL as it is (``socket://host:port``, ``rfc2217://host:port``, ``spy://PORT``,
``loop://``: the registry sends those schemes here) or after ``serial://``.  URL parameters (all
optional)::

    serial:///dev/ttyACM0?baud=115200&fast_baud=1000000&retries=7&boot=2.5&low_latency=1&cs=0

* ``baud``: must match the firmware's (115200 unless it was built otherwise);
* ``fast_baud``: the rate to switch to after the handshake when the bridge can (HELLO capability
  BAUD_SWITCH), default 1000000; ``fast_baud=0`` keeps ``baud``.  A bridge or adapter that cannot
  do it leaves the link at ``baud``, with a warning;
* ``boot``: seconds to keep asking HELLO after the port opens.  An Uno or a Nano resets when
  the port opens (DTR) and its bootloader needs 1-2 s before the firmware answers;
* ``low_latency``: ask the USB serial driver for low latency (on Linux, FTDI adapters hold
  short replies back for up to 16 ms otherwise: the "latency timer trap").

The link itself (frames, retries, exactly-once) is :class:`~lm629_host.bridge.protocol.LinkTransport`;
this module adds the port: opening it with errors that say what to do, the pipe over pyserial,
the round-trip time measured after the handshake, ``list_ports()`` and ``doctor()``.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import sys
from dataclasses import dataclass

try:  # POSIX only; imported early so that the advice works even where modules can't load
    import grp
except ImportError:  # pragma: no cover - Windows
    grp = None  # type: ignore[assignment]  # Windows has no grp module

try:  # POSIX only: pyserial's reset_input_buffer on a tty lets termios.error through
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - Windows
    _TermiosError = OSError  # type: ignore[assignment,misc]  # nothing else to catch there

from lm629_host.bridge.protocol.constants import FAST_BAUD
from lm629_host.clock import Clock, WallClock
from lm629_host.errors import TransportError
from lm629_host.bus.program import TraceCallback
from lm629_host.urls import Option, PortURL, parse_options, port_url, scheme_of, table_names, with_defaults
from lm629_host.bus.url_board import BOARD_ROWS
from lm629_host.transports.reports import Check, PortInfo
from lm629_host.transports.failsafe import FailsafeOptions
from lm629_host.transports.link import LINK_OPTIONS, LinkTransport
from lm629_host.transports.session import DEFAULT_RETRIES
from lm629_host.transports.netport import (
    WRITE_TIMEOUT_S,
    quiet_rfc2217_reader,
    refusal,
    rfc2217_port_class,
    rfc2217_url,
    server_says,
    server_words,
)

log = logging.getLogger("lm629_host.serial")

#: what a port that went away (or never was a tty) raises from pyserial or the descriptor:
#: SerialException and its PortNotOpenError are OSError (so are a socket's errors and the
#: stuck write's TimeoutError); ValueError for a descriptor closed under a select; termios's
#: own error for a tty call on something that is no tty.  A TypeError or an AttributeError is
#: a bug, never "was the board unplugged?"
PORT_ERRORS: tuple[type[Exception], ...] = (OSError, ValueError, _TermiosError)

DEFAULT_BAUD = 115200
#: seconds to keep asking HELLO after opening (boot time of an Uno after its DTR reset)
DEFAULT_BOOT_S = 2.5

#: USB ids of the boards and adapters a bridge is usually built on: (vid, pid) -> name
KNOWN_USB_IDS: dict[tuple[int, int], str] = {
    (0x2341, 0x0043): "Arduino Uno R3",
    (0x2341, 0x0001): "Arduino Uno",
    (0x2341, 0x0243): "Arduino Uno R3 (16U2)",
    (0x2A03, 0x0043): "Arduino Uno R3 (arduino.org)",
    (0x1A86, 0x7523): "CH340 USB serial (Nano clone)",
    (0x1A86, 0x5523): "CH341 USB serial",
    (0x0403, 0x6001): "FTDI FT232R (Nano, Duemilanove)",
    (0x0403, 0x6015): "FTDI FT231X",
    (0x10C4, 0xEA60): "Silicon Labs CP210x",
}

#: the URL options of a serial bridge: the board's, the link's, the port's (a pyserial
#: handler's own options, ``logging=``, pass through to it)
OPTIONS = (
    *BOARD_ROWS,
    *with_defaults(LINK_OPTIONS, baud=DEFAULT_BAUD, fast_baud=FAST_BAUD),
    Option("boot", "float", DEFAULT_BOOT_S, 0.0, 30.0, "s"),
    Option("low_latency", "bool", True),
)
_OPTION_NAMES = table_names(OPTIONS)


def is_handler_url(device: str) -> bool:
    """True for a pyserial URL (``socket://host:port``, ``rfc2217://host:port``,
    ``spy:///dev/ttyUSB0``...) rather than a device path."""
    return "://" in device


def _ask_group(path: str) -> str:
    """The group that owns ``path`` (dialout on Debian/Ubuntu, uucp on Arch)."""
    try:
        return grp.getgrgid(os.stat(path).st_gid).gr_name
    except (AttributeError, KeyError, OSError):
        return "dialout"


def advice_permission(path: str) -> str:
    group = _ask_group(path)
    return (f"permission denied on {path}: your user is not in the group {group!r} that owns "
            f"it. Run: sudo usermod -aG {group} $USER  then log out and in again "
            f"(check with: id -nG).")


def advice_busy(path: str) -> str:
    return (f"{path} is in use by another program (a serial monitor, the Arduino IDE, "
            "ModemManager, another lm629 or `lm629 sim serve` client): close it and retry; "
            f"`fuser -v {path}` shows who holds it.")


def advice_missing(path: str) -> str:
    return (f"no serial port {path}: is the board plugged in? `lm629 bridge list` shows the "
            "candidate ports (a Uno is usually /dev/ttyACM0, a Nano clone /dev/ttyUSB0).")


def device_of(url: str | PortURL) -> str:
    """The device path of a ``serial://`` URL or a bare path; a pyserial URL (``socket://
    host:port``, or after ``serial://``) is its own device, without its options."""
    u = port_url(url).unwrapped()
    return u.netloc + u.path if u.scheme == "serial" else u.base


@dataclass(frozen=True)
class SerialOptions:
    device: str
    baud: int = DEFAULT_BAUD
    retries: int = DEFAULT_RETRIES
    boot_s: float = DEFAULT_BOOT_S
    low_latency: bool = True
    cs: int = 0
    fast: int = FAST_BAUD
    failsafe: FailsafeOptions | None = None  #: None: the link reads them from the URL


def options_of(url: str | PortURL) -> SerialOptions:
    """Parse and check a ``serial://`` URL (ValueError naming the parameter)."""
    url = port_url(url)
    inner = url.unwrapped()
    device = device_of(url)
    if not device:
        raise ValueError(f"{url}: no device path (e.g. serial:///dev/ttyACM0)")
    ours = url
    if inner.scheme != "serial":  # socket://, rfc2217://, spy://: the other options are its own
        if inner.scheme in ("socket", "rfc2217"):
            host, _, port = inner.netloc.rpartition(":")
            if not host or not port.isdigit():
                raise ValueError(f"{url}: {inner.scheme}:// needs a host and a port number "
                                 f"({inner.scheme}://HOST:PORT, e.g. "
                                 f"{inner.scheme}://localhost:7000)")
        theirs = inner.without(_OPTION_NAMES)[0]
        ours = url.without(set(url.query()) - _OPTION_NAMES)[0]
        device = theirs.text  # pyserial's own options, handed on as the user wrote them
    opts = parse_options(ours, OPTIONS, what="serial")
    return SerialOptions(device=device, baud=opts["baud"], retries=opts["retries"],
                         boot_s=opts["boot"], low_latency=opts["low_latency"],
                         cs=opts["cs"] or 0, fast=opts["fast_baud"],
                         failsafe=FailsafeOptions.of(opts))


def _lost_hint(device: str | None, heard: bytes = b"") -> str:
    """What a link that failed mid-use most likely means on this kind of port; ``heard``: the
    last bytes the server sent (ser2net says why it refuses a client in words)."""
    if device and scheme_of(device) in ("socket", "rfc2217"):
        said = server_words(heard)
        if said:
            return refusal(device, said)
        return ("the server closed the connection: is it still running (ser2net, "
                "`lm629 sim serve --tcp`) and the network path up? (Both take one client at a "
                "time: is another one connected?)")
    return "was the board unplugged?"


def line_advice_of(device: str | None) -> str | None:
    """What to check when the link on ``device`` fails, for a line that is no USB cable (a
    pseudo-terminal, a network socket); None for a real serial device."""
    if not device:
        return None
    scheme = scheme_of(device) if "://" in device else ""
    if scheme in ("socket", "rfc2217"):
        return ("Check the network path to the server and that the server (ser2net, "
                "`lm629 sim serve --tcp`) is running and keeps up")
    if scheme:
        return None
    real = os.path.realpath(device)
    if real.startswith("/dev/pts/") or real == "/dev/ptmx":
        return ("Check the program at the pseudo-terminal's other end (a served bench: is "
                "`lm629 sim serve` still running, and not starved of CPU?)")
    return None


class SerialPipe:
    """A :class:`~lm629_host.bridge.protocol.Pipe` over an open pyserial port, in real time.
    ``line_advice``: what to check when the line fails, where it is no USB cable."""

    def __init__(self, port, clock: Clock | None = None,
                 device: str | None = None) -> None:  # port: serial.Serial
        self.port = port
        #: the port as the user gave it (messages quote it; pyserial's may carry an option
        #: :func:`open_port` added)
        self.device: str = device or getattr(port, "port", None) or "?"
        self.line_advice = line_advice_of(self.device)
        self.clock = clock or WallClock()
        self._heard = b""
        try:
            self._fd: int | None = port.fileno()
        except OSError:  # io.UnsupportedOperation: Windows ports and URL handlers have no fd
            self._fd = None
        if self._fd is not None:
            port.timeout = 0  # non-blocking reads; waiting is done with select below
        elif port.timeout != self.READ_SLICE_S:
            # set once: a URL handler may do real work on each change of a setting
            # (pyserial's RFC 2217 client renegotiates every port setting with the server,
            # 150 ms, when its timeout is set), so a wait is cut into reads of this slice
            port.timeout = self.READ_SLICE_S
        #: whether a change of rate reaches the line: not through raw TCP (``socket://``),
        #: which carries bytes only, so that the far UART (ser2net's) keeps its rate; RFC 2217
        #: sends it to the far UART as SET-BAUDRATE and waits for the server's answer
        self.sets_line_rate = scheme_of(self.device) != "socket"
        #: writes go to the descriptor itself only on a plain device (a URL handler such as
        #: spy:// does its own work in write())
        self._write_raw = self._fd is not None and type(port).__module__ == "serial.serialposix"

    #: the longest a read on a port without a descriptor waits at once: how far a wait on
    #: such a port may overrun the time asked (data ends a read at once, whatever this is)
    READ_SLICE_S = 0.005
    #: the last bytes read are kept, this many: a server that refuses a client says why in
    #: words before it closes (ser2net: "Port already in use"), and a lost link quotes them
    HEARD = 80
    #: how long a write may find the port full before the link is given up as lost
    WRITE_STUCK_S = 2.0

    def write(self, data: bytes) -> None:
        try:
            if self._write_raw:
                self._write_fd(data)
            else:
                self.port.write(data)
        except PORT_ERRORS as exc:
            raise TransportError(f"write failed ({exc}): {_lost_hint(self.device, self._heard)}",
                                 port=self.device) from exc

    def _write_fd(self, data: bytes) -> None:
        """All of ``data`` to the port's descriptor (non-blocking, as pyserial opens it),
        failing only when the port stays full for :attr:`WRITE_STUCK_S`.  Not pyserial's
        ``write(timeout)``: it judges its deadline after each write, so a host paused in the
        middle of one (SIGSTOP, a busy machine) got "Write timeout" for bytes that had gone."""
        fd = self._fd
        assert fd is not None  # write() takes this path only with a descriptor
        view = memoryview(data)
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if view and not select.select([], [fd], [], self.WRITE_STUCK_S)[1]:
                raise TimeoutError(f"the port took nothing for {self.WRITE_STUCK_S:g} s")

    def read(self, timeout_s: float) -> bytes:
        data = self._read(timeout_s)
        if data:
            self._heard = (self._heard + data)[-self.HEARD:]
        return data

    def _read(self, timeout_s: float) -> bytes:
        port = self.port
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], max(0.0, timeout_s))
                if not ready:
                    return b""
                data = port.read(max(1, port.in_waiting))
                return bytes(data)
            return self._read_sliced(timeout_s)
        except PORT_ERRORS as exc:
            raise TransportError(f"read failed ({exc}): {_lost_hint(self.device, self._heard)}",
                                 port=self.device) from exc

    def _read_sliced(self, timeout_s: float) -> bytes:
        """What arrives within ``timeout_s`` on a port without a descriptor, in reads of
        :attr:`READ_SLICE_S` (the port's fixed timeout): the first bytes end the wait."""
        port = self.port
        if port.in_waiting:
            return bytes(port.read(port.in_waiting))
        if timeout_s <= 0:
            return b""
        deadline = self.clock.now() + max(0.0, timeout_s)
        while True:
            data = port.read(1)
            if data:
                return bytes(data) + bytes(port.read(port.in_waiting) if port.in_waiting else b"")
            if self.clock.now() >= deadline:
                return b""

    def set_baud(self, baud: int) -> None:
        """Run the port at ``baud`` (what was written is sent first)."""
        try:
            self.port.flush()
            self.port.baudrate = baud
        except PORT_ERRORS as exc:  # ValueError: a rate this port's driver cannot make
            raise TransportError(f"cannot set {baud} baud ({exc})", port=self.device) from exc

    def reset_input(self) -> None:
        try:
            self.port.reset_input_buffer()
        except PORT_ERRORS:  # a pty or a vanished port: nothing to drop
            pass

    def close(self) -> None:
        try:
            self.port.close()
        except PORT_ERRORS:  # closing a vanished port must not raise
            pass


def open_port(device: str, baud: int):
    """Open ``device`` with pyserial (8N1, exclusive) or raise a :class:`TransportError` that
    says what to do.  ``device`` may be any pyserial URL (``serial_for_url``): a bridge on
    another machine (``socket://host:port`` behind ser2net, ``rfc2217://host:port``), or
    ``spy://PORT?file=...`` to hex-dump the traffic."""
    import serial

    scheme = scheme_of(device)
    if scheme == "rfc2217":
        quiet_rfc2217_reader()
    # pyserial's RFC 2217 client refuses a write_timeout (NotImplementedError): it gets none
    # below, its writes bounded by its socket's timeout instead (RFC2217Port.open)
    bounded = {"write_timeout": WRITE_TIMEOUT_S}
    try:
        if scheme == "rfc2217":  # pyserial's client, its settings sent only when they change
            return rfc2217_port_class()(rfc2217_url(device), baud, timeout=SerialPipe.READ_SLICE_S)
        # exclusive: a lock on a local port (spy:// included); network handlers ignore it
        return serial.serial_for_url(device, baud, timeout=0, exclusive=True, **bounded)
    except (serial.SerialException, OSError) as exc:  # OSError: a network handler's socket
        code = getattr(exc, "errno", None)
        text = str(exc)
        if scheme in ("socket", "rfc2217") and (said := server_says(device)):
            raise TransportError(f"cannot open {device}: {refusal(device, said)}",
                                 port=device) from None
        if is_handler_url(device):
            raise TransportError(
                f"cannot open {device}: {text}. For socket:// and rfc2217://: is the bridge's "
                "server (ser2net, `lm629 sim serve --tcp PORT`) running on that host and port, "
                "and does a firewall let it through?", port=device) from None
        if code == errno.ENOENT or "No such file" in text or "FileNotFoundError" in text:
            raise TransportError(advice_missing(device), port=device) from None
        if code == errno.EACCES or "Permission denied" in text or "PermissionError" in text:
            raise TransportError(advice_permission(device), port=device) from None
        if code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in text or "busy" in text:
            raise TransportError(advice_busy(device), port=device) from None
        raise TransportError(f"cannot open {device}: {text}", port=device) from None


def set_low_latency(port) -> tuple[bool, str]:
    """pyserial's low-latency mode (Linux: ASYNC_LOW_LATENCY, which makes the FTDI driver use a
    1 ms latency timer).  Returns (done, what happened)."""
    fn = getattr(port, "set_low_latency_mode", None)
    if fn is None:
        return False, f"not available on {sys.platform}"
    try:
        fn(True)
    except (OSError, ValueError, NotImplementedError) as exc:
        return False, f"not supported by this port's driver ({exc})"
    return True, "on"


def latency_timer_ms(device: str) -> int | None:
    """The FTDI latency timer of a ``/dev/ttyUSBn`` (sysfs), or None when there is none."""
    name = os.path.basename(os.path.realpath(device))
    try:
        with open(f"/sys/bus/usb-serial/devices/{name}/latency_timer") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


class SerialTransport(LinkTransport):
    """The bridge over a serial port: the link's open sequence (:meth:`LinkTransport.open_link`)
    after the port is open; ``rtt_s`` is the measured PING round trip."""

    scheme = "serial"
    options = OPTIONS  #: its URL options, one table (parsed once, and listed by a message)
    hello_interval_s = 0.25

    def __init__(self, pipe: SerialPipe, url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = DEFAULT_BAUD, cs: int = 0,
                 boot_s: float = DEFAULT_BOOT_S, low_latency: str = "",
                 measure_rtt: bool = True, fast: int = 0,
                 failsafe: FailsafeOptions | None = None) -> None:
        self.boot_s = boot_s
        self.hello_total_s = max(boot_s, self.hello_interval_s)
        self.low_latency = low_latency
        super().__init__(pipe, url, trace=trace, retries=retries, baud=baud, cs=cs,
                         fast_baud=fast, measure_rtt=measure_rtt, failsafe=failsafe)

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> SerialTransport:
        opts = options_of(url)
        port = open_port(opts.device, opts.baud)
        low = "off (low_latency=0)"
        if opts.low_latency:
            done, low = set_low_latency(port)
        pipe = SerialPipe(port, device=opts.device)
        pipe.reset_input()
        try:
            return cls(pipe, url, trace=trace, retries=opts.retries, baud=opts.baud, cs=opts.cs,
                       boot_s=opts.boot_s, low_latency=low, fast=opts.fast,
                       failsafe=opts.failsafe)
        except TransportError as exc:
            # a server that refused this client may have said why before it closed, and the
            # words lost with the connection (a reset drops what was unread): ask it again
            if scheme_of(opts.device) in ("socket", "rfc2217") and "answered" not in str(exc) \
                    and (said := server_says(opts.device)):
                raise TransportError(f"cannot open {opts.device}: "
                                     f"{refusal(opts.device, said)}", port=opts.device) from None
            raise

    def _no_answer(self, what: str, attempts: int) -> TransportError:
        dev = device_of(self.url)  # with a socket:// URL the advice is the remote board's
        return TransportError(
            f"no answer to {what} within {self.hello_total_s:g} s ({attempts} attempts) at "
            f"{self.baud} baud. Check: is the bridge firmware flashed (lm629 bridge flash "
            f"--port {dev})? An Uno/Nano resets when the port opens and needs ~2 s to boot "
            f"(raise ?boot=5 if it is slower); does ?baud= match the firmware's? Is it the "
            "right port (lm629 bridge list)?", port=self.url)

    @classmethod
    def list_ports(cls, probe: bool = True, boot_s: float = DEFAULT_BOOT_S) -> list[PortInfo]:
        """Serial ports whose USB id is a usual bridge board, each probed with HELLO (``probe``).
        A port that answers says its firmware version; one that does not says why."""
        out: list[PortInfo] = []
        for p in _candidates():
            if p.vid is None:
                continue
            name = KNOWN_USB_IDS.get((p.vid, p.pid))
            if name is None:
                continue
            desc = f"{name} [{p.vid:04X}:{p.pid:04X}]" + (f" s/n {p.serial_number}"
                                                            if p.serial_number else "")
            if not probe:
                out.append(PortInfo(p.device, desc))
                continue
            try:
                t = cls.from_url(f"serial://{p.device}?boot={boot_s}")
            except TransportError as exc:
                out.append(PortInfo(p.device, desc, usable=False, problem=str(exc)))
                continue
            try:
                info = t.info
                rtt = f", round trip {t.rtt_s * 1e3:.2f} ms" if t.rtt_s is not None else ""
                out.append(PortInfo(p.device, f"{desc}: {info.describe() if info else '?'}{rtt}"))
            finally:
                t.close()
        return out

    @classmethod
    def doctor(cls, port: str | None = None) -> list[Check]:
        """What ``lm629 doctor`` reports about serial bridges: pyserial, group membership, the
        ports found, and for ``port`` (or each bridge found) the handshake, the low-latency mode
        and the measured round-trip time."""
        checks: list[Check] = []
        try:
            import serial
            checks.append(Check("pyserial", True, f"pyserial {serial.__version__}"))
        except ImportError:
            return [Check("pyserial", False, "pyserial is missing: pip install pyserial")]
        if sys.platform.startswith("linux") and grp is not None:
            try:
                members = grp.getgrnam("dialout")
                in_group = os.getgid() == members.gr_gid or os.getuid() == 0 or \
                    members.gr_gid in os.getgroups()
                checks.append(Check("dialout", in_group,
                                    "user may open serial ports" if in_group else
                                    "user is not in 'dialout': sudo usermod -aG dialout $USER, "
                                    "then log out and in"))
            except KeyError:
                pass
        ports = [port] if port else [p.url for p in cls.list_ports(probe=False)]
        if not ports:
            checks.append(Check("bridge ports", True, "no Uno/Nano/CH340/FTDI serial port found"))
        for dev in ports:
            try:
                t = cls.from_url(dev if "://" in dev else f"serial://{dev}")
            except (TransportError, ValueError) as exc:
                checks.append(Check(f"bridge {dev}", False, str(exc)))
                continue
            try:
                msg = f"{t.describe()}; low latency {t.low_latency or 'n/a'}"
                timer = latency_timer_ms(device_of(dev))
                if timer is not None:
                    msg += f"; FTDI latency timer {timer} ms"
                ok = t.rtt_s is not None and t.rtt_s < 0.01
                if not ok:
                    msg += (" -- slow round trip: on an FTDI adapter set its latency timer to 1 ms "
                            "(echo 1 > /sys/bus/usb-serial/devices/ttyUSBn/latency_timer)")
                checks.append(Check(f"bridge {dev}", ok, msg))
            finally:
                t.close()
        return checks


def _candidates() -> list:
    try:
        from serial.tools import list_ports as lp
    except ImportError:
        return []
    return list(lp.comports())


#: module-level names of the class methods (``serial.list_ports()``)
list_ports = SerialTransport.list_ports
doctor = SerialTransport.doctor


__all__ = ["SerialPipe", "SerialTransport", "doctor", "list_ports", "options_of", "open_port",
           "KNOWN_USB_IDS", "DEFAULT_BAUD"]
