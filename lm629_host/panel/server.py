"""The panel's web server: the standard library's ``http.server``, Server-Sent Events for the
rows, JSON POSTs for the commands.  Nothing to install, nothing fetched at run time: the page,
its script and the plotting library (uPlot, MIT, its licence beside it) are files in the
package.

Why these checks (docs/panel.md, "Security"): loopback is no wall against the browser itself.
Any page the user visits can send requests to 127.0.0.1 (cross-site requests) and, through
DNS rebinding, read the answers.  So, as local servers that act do (Jupyter):

- every request's ``Host`` must name this server: ``127.0.0.1``, ``localhost`` or ``[::1]``
  at any port (an SSH forward's local end: ``ssh -L 9000:127.0.0.1:8629``), or the host
  given to ``--listen``; a rebound name is refused;
- commands come only by POST with the page's own ``Origin`` (a form or script from another
  site sends its own, or none);
- every command carries the server's token (``X-LM629-Token``), which a page gets only by
  loading the panel from an address that passes the checks above; listening beyond loopback
  the address itself carries it (``?token=``) and every request must show it.
"""

from __future__ import annotations

import hmac
import json
import queue
import secrets
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from lm629_host.panel.bench import SIGNAL_BITS, STATUS_BITS, BenchWorker, Outcome
from lm629_host.panel.commands import PanelRequestError, build

#: what GET serves from the package, by name
STATIC = {"uPlot.iife.min.js": "text/javascript", "uPlot.min.css": "text/css",
          "uPlot.LICENSE": "text/plain", "panel.js": "text/javascript",
          "panel.css": "text/css"}
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


def is_loopback(host: str) -> bool:
    """The addresses served without --expose: this machine's usual loopback names only (any
    other, even 127.0.0.2, counts as elsewhere: a token in the address, an explicit flag)."""
    return host in ("127.0.0.1", "localhost", "::1", "[::1]")


def _static(name: str) -> bytes:
    return resources.files("lm629_host.panel").joinpath("static").joinpath(name).read_bytes()


class Clients:
    """The open pages: the oldest commands, the others watch (a stop comes from any)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[str, float] = {}

    def add(self) -> str:
        cid = secrets.token_hex(8)
        with self._lock:
            self._open[cid] = time.time()
        return cid

    def remove(self, cid: str) -> None:
        with self._lock:
            self._open.pop(cid, None)

    def commander(self) -> str | None:
        with self._lock:
            return min(self._open, key=self._open.__getitem__) if self._open else None

    def refusal(self, cid: str) -> str | None:
        """Why tab ``cid`` may not command now (None: it may)."""
        first = self.commander()
        if cid not in self._open:
            return "this page is not connected to the panel (reload it)"
        if first is not None and first != cid:
            opened = time.strftime("%H:%M:%S", time.localtime(self._open[first]))
            return (f"another tab commands this bench (opened at {opened}); this one watches: "
                    "close that tab to command from here (the stop button works in every tab)")
        return None


class PanelServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], worker: BenchWorker, *,
                 token: str | None = None, title: str = "") -> None:
        super().__init__(address, PanelHandler)
        self.worker = worker
        self.token = token or secrets.token_urlsafe(24)
        self.title = title
        self.clients = Clients()
        self._inflight = 0  #: commands whose answer is not yet written
        self._settled = threading.Condition()
        host = address[0]
        self.loopback = is_loopback(host)
        self.hosts = {h.lower() for h in LOOPBACK_NAMES}
        if not self.loopback:
            self.hosts.add(host.lower())

    @contextmanager
    def answering(self) -> Iterator[None]:
        """A command under way, until its answer is written (:meth:`drain` waits for it)."""
        with self._settled:
            self._inflight += 1
        try:
            yield
        finally:
            with self._settled:
                self._inflight -= 1
                self._settled.notify_all()

    def drain(self, timeout: float) -> None:
        """Wait (up to ``timeout``) until every command under way has written its answer: the
        panel ending answers them (a stop's outcome) before the process goes."""
        with self._settled:
            self._settled.wait_for(lambda: self._inflight == 0, timeout)

    @property
    def port(self) -> int:
        return int(self.server_address[1])

    def address(self) -> str:
        """The address to print: loopback as it is, elsewhere with the token."""
        host = str(self.server_address[0])
        if ":" in host:
            host = f"[{host}]"
        url = f"http://{host}:{self.port}/"
        return url if self.loopback else url + f"?token={self.token}"

    def host_ok(self, header: str | None) -> bool:
        """``Host`` names this server (any port for the loopback names: an SSH forward)."""
        if not header:
            return False
        header = header.strip().lower()
        if header.startswith("["):
            name, _, rest = header.partition("]")
            name, port = name + "]", rest.lstrip(":")
        else:
            name, _, port = header.partition(":")
        if port and not port.isdigit():
            return False
        if name in LOOPBACK_NAMES:
            return True
        return name in self.hosts and (not port or int(port) == self.port)


class PanelHandler(BaseHTTPRequestHandler):
    server: PanelServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        pass  # the terminal shows the address and the commands' lines, not every request

    # ------------------------------------------------------------------ answers
    def _send(self, code: int, body: bytes, ctype: str, extra: dict[str, str] | None = None) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("X-Frame-Options", "DENY")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)

    def _refuse(self, code: int, why: str) -> None:
        self._send(code, json.dumps({"ok": False, "code": 2, "text": why}).encode(),
                   "application/json")

    def _token_ok(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.server.token.encode())

    def _checked(self, need_token: bool, public: bool = False) -> dict[str, list[str]] | None:
        """The query, or None once a refusal was sent (bad Host, missing token)."""
        if not self.server.host_ok(self.headers.get("Host")):
            self._refuse(403, f"refused: Host {self.headers.get('Host')!r} is not this panel's "
                              "(a page from another site, or DNS rebinding)")
            return None
        query = parse_qs(urlsplit(self.path).query)
        given = (query.get("token") or [""])[0] or self.headers.get("X-LM629-Token")
        if (need_token or not (self.server.loopback or public)) and not self._token_ok(given):
            self._refuse(403, "refused: no valid token (open the address the panel printed)")
            return None
        return query

    # ------------------------------------------------------------------ GET
    def do_GET(self) -> None:
        path = urlsplit(self.path).path
        if path == "/events":
            query = self._checked(need_token=True)
            if query is not None:
                self._events()
            return
        # the page carries the token (beyond loopback, only an address with it gets the page);
        # its script, style and the plot library are the package's public files
        public = path == "/favicon.ico" or (path.startswith("/static/") and path[8:] in STATIC)
        query = self._checked(need_token=False, public=public)
        if query is None:
            return
        if path in ("/", "/index.html"):
            self._send(200, self._page(), "text/html; charset=utf-8",
                       {"Content-Security-Policy": "default-src 'self'; style-src 'self' "
                                                   "'unsafe-inline'; frame-ancestors 'none'"})
        elif path == "/favicon.ico":
            self._send(204, b"", "image/x-icon")
        elif path.startswith("/static/") and path[8:] in STATIC:
            self._send(200, _static(path[8:]), STATIC[path[8:]])
        else:
            self._send(404, b"not found", "text/plain")

    def _page(self) -> bytes:
        w = self.server.worker
        w.ready.wait(30)
        config = {"token": self.server.token, "axes": [n for _c, n in w.axes],
                  "source": w.source, "failsafe": w.failsafe, "title": self.server.title,
                  "status_bits": STATUS_BITS, "signal_bits": SIGNAL_BITS,
                  "fault": w.error}
        html = _static("index.html").decode()
        text = json.dumps(config).replace("<", "\\u003c")
        return html.replace("{{CONFIG}}", text).encode()

    def _events(self) -> None:
        server = self.server
        cid = server.clients.add()
        q = server.worker.subscribe()
        try:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "close")
            self.end_headers()
            self.close_connection = True
            hello = {"type": "hello", "client": cid, "failsafe": server.worker.failsafe,
                     "fault": server.worker.error}
            self.wfile.write(f"data: {json.dumps(hello)}\n\n".encode())
            self.wfile.flush()
            role = None
            while True:
                commander = server.clients.commander()
                if commander != role:
                    role = commander
                    text = json.dumps({"type": "role", "commands": commander == cid,
                                       "why": server.clients.refusal(cid)})
                    self.wfile.write(f"data: {text}\n\n".encode())
                try:
                    msg = q.get(timeout=0.5)
                except queue.Empty:
                    self.wfile.write(b": keep-alive\n\n")  # finds a closed tab
                    self.wfile.flush()
                    continue
                self.wfile.write(f"data: {msg}\n\n".encode())
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # the tab closed: it stops nothing
        finally:
            server.worker.unsubscribe(q)
            server.clients.remove(cid)

    # ------------------------------------------------------------------ POST
    def do_POST(self) -> None:
        if self._checked(need_token=False) is None:
            return
        origin = self.headers.get("Origin")
        host = self.headers.get("Host", "")
        if origin != f"http://{host}":
            self._refuse(403, f"refused: Origin {origin!r} is not this panel's page "
                              f"(http://{host}): commands come only from the panel itself")
            return
        if not self._token_ok(self.headers.get("X-LM629-Token")):
            self._refuse(403, "refused: no valid token (reload the panel from the address it "
                              "printed)")
            return
        if self.headers.get("Content-Type", "").split(";")[0].strip() != "application/json":
            self._refuse(415, "refused: commands are JSON")
            return
        try:
            length = int(self.headers.get("Content-Length", "0"))
            body = json.loads(self.rfile.read(min(length, 65536)) or b"{}")
            if not isinstance(body, dict):
                raise ValueError("not an object")
        except ValueError:
            self._refuse(400, "refused: the body is not a JSON object")
            return
        path = urlsplit(self.path).path
        if path != "/api/command":
            self._send(404, b"not found", "text/plain")
            return
        with self.server.answering():
            outcome = self._command(body)
            self._send(200, json.dumps(outcome.as_dict()).encode(), "application/json")

    def _command(self, body: dict[str, Any]) -> Outcome:
        server = self.server
        worker = server.worker
        try:
            job = build(body, worker)
        except PanelRequestError as exc:
            return Outcome(2, str(exc))
        if not job.stop:
            why = server.clients.refusal(str(body.get("client", "")))
            if why is not None:
                return Outcome(2, why)
        return worker.submit(job.argv, job.cs, stop=job.stop, then=job.then, live=job.live)


__all__ = ["PanelServer", "is_loopback"]
