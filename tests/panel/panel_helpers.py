"""Helpers of the panel's tests: ``lm629 panel`` as its own process, Debian's chromium driven
headless by selenium through chromedriver, and a plain HTTP client for the security checks.

Real parts on both sides: the installed console script serves, the real browser loads the
page, runs its script and clicks; everything on loopback, started and stopped by the tests."""

from __future__ import annotations

import http.client
import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from dataclasses import dataclass
from urllib.parse import urlsplit

import pytest

from served import _console_script, _env

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
#: the flags the notes give for a headless chromium that reaches nothing but loopback
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--window-size=1400,1000")


@dataclass
class Panel:
    proc: subprocess.Popen
    url: str

    @property
    def hostport(self) -> str:
        return urlsplit(self.url).netloc

    def page_token(self) -> str:
        """The token the page carries (what a page from this server can read)."""
        status, body = request(self, "GET", "/" + (("?" + urlsplit(self.url).query)
                                                   if urlsplit(self.url).query else ""))
        assert status == 200, body
        start = body.index('"token": "') + len('"token": "')
        return body[start:body.index('"', start)]

    def end(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        """Signal the panel; its exit code and stderr."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        _out, err = self.proc.communicate(timeout=30)
        return self.proc.returncode, err


@contextmanager
def panel(port: str = "sim://", *extra: str, listen: str = "127.0.0.1:0") -> Iterator[Panel]:
    """``lm629 --port PORT panel --listen LISTEN`` as a process; ready once it printed its
    address (its first line)."""
    argv = [_console_script(), "--port", port, "panel", "--listen", listen, *extra]
    env = {k: v for k, v in _env().items() if k != "LM629_SIM_STRICT"}
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    p = Panel(proc, "")
    try:
        first = proc.stdout.readline().strip()
        assert first.startswith("http://"), first + proc.stderr.read()
        p.url = first
        yield p
    finally:
        if proc.poll() is None:
            p.end()


@contextmanager
def profile_panel(path) -> Iterator[Panel]:
    """``lm629 --profile PATH panel --listen 127.0.0.1:0`` as a process (the strict simulator
    of the tests' environment); ready once it printed its address."""
    argv = [_console_script(), "--profile", str(path), "panel", "--listen", "127.0.0.1:0"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env())
    p = Panel(proc, proc.stdout.readline().strip())
    assert p.url.startswith("http://"), p.url + proc.stderr.read()
    try:
        yield p
    finally:
        p.end()


@contextmanager
def panel_on_profile(folder: Path, text: str, name: str = "bench.toml"
                     ) -> Iterator[tuple[Panel, str, Path]]:
    """The profile ``text`` written to ``folder/name`` and :func:`profile_panel` on it:
    (the panel, its page's token, the profile's path)."""
    path = folder / name
    path.write_text(text)
    with profile_panel(path) as p:
        yield p, p.page_token(), path


def request(p: Panel, method: str, path: str, *, body: dict | None = None,
            headers: dict[str, str] | None = None, host: str | None = None) -> tuple[int, str]:
    """One HTTP request to the panel, the Host header as given (default: the address's)."""
    where = urlsplit(p.url)
    conn = http.client.HTTPConnection(where.hostname, where.port, timeout=30)
    try:
        data = json.dumps(body).encode() if body is not None else None
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", host if host is not None else where.netloc)
        for k, v in (headers or {}).items():
            conn.putheader(k, v)
        if data is not None:
            conn.putheader("Content-Length", str(len(data)))
        conn.endheaders(data)
        resp = conn.getresponse()
        return resp.status, resp.read().decode()
    finally:
        conn.close()


def browser_missing() -> str | None:
    for path in (CHROMIUM, CHROMEDRIVER):
        if not os.path.exists(path):
            return f"{path} is missing (Debian: apt-get install chromium chromium-driver)"
    import importlib.util
    if importlib.util.find_spec("selenium") is None:
        return "selenium is missing (pip install -e '.[test]')"
    return None


@contextmanager
def chromium() -> Iterator[object]:
    """Debian's chromium, headless, a fresh profile, through its chromedriver."""
    missing = browser_missing()
    if missing:
        pytest.skip(missing)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="lm629-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def wait_for(predicate, timeout: float = 10.0, what: str = "condition"):
    """Poll ``predicate`` (a browser or process outside the test's control: wall time) until
    it returns a true value; that value."""
    end = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > end:
            raise AssertionError(f"no {what} within {timeout:g} s (last: {value!r})")
        time.sleep(0.05)


def message(driver) -> str:
    """The page's one-line answer to the last command."""
    return driver.find_element("id", "msg").text


def last_row(driver, axis: str = "0") -> list:
    """The axis's last row the page plotted: [desired, actual, desired velocity, actual
    velocity, status, signals]; waits for the first (a page just loaded beside two busy test
    workers may have none yet: it was None, and a predicate indexing it raised TypeError)."""
    return wait_for(lambda: driver.execute_script(
        f"return window.panelState.axes[{axis!r}].last"), what=f"a row of axis {axis}")


@contextmanager
def events(p: Panel, token: str, timeout: float = 30.0) -> Iterator[Iterator[dict]]:
    """The page's event stream, read as a page reads it (a plain client: what the browser
    gets, without one): yields the messages as dicts."""
    where = urlsplit(p.url)
    conn = http.client.HTTPConnection(where.hostname, where.port, timeout=timeout)
    conn.request("GET", f"/events?token={token}")
    resp = conn.getresponse()
    assert resp.status == 200, resp.read()

    def messages() -> Iterator[dict]:
        while True:
            line = resp.readline()
            if not line:
                return
            if line.startswith(b"data: "):
                yield json.loads(line[6:])
    try:
        yield messages()
    finally:
        conn.close()


def command(p: Panel, token: str, body: dict, origin: str | None = "same") -> tuple[int, dict]:
    """POST a command as the page does (its Origin and token), or as told."""
    headers = {"Content-Type": "application/json", "X-LM629-Token": token}
    if origin is not None:
        headers["Origin"] = f"http://{p.hostport}" if origin == "same" else origin
    if not token:
        del headers["X-LM629-Token"]
    status, text = request(p, "POST", "/api/command", body=body, headers=headers)
    return status, json.loads(text)


@contextmanager
def forward(p: Panel) -> Iterator[int]:
    """A TCP forward to the panel from another loopback port, as ``ssh -L PORT:127.0.0.1:...``
    makes one (no sshd runs here): the browser then names ``localhost:PORT``.  Yields PORT."""
    import socket

    where = urlsplit(p.url)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    stop = threading.Event()

    def pump(a: socket.socket, b: socket.socket) -> None:
        try:
            while data := a.recv(65536):
                b.sendall(data)
        except OSError:
            pass
        finally:
            for s in (a, b):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def accept() -> None:
        listener.settimeout(0.2)
        while not stop.is_set():
            try:
                client, _ = listener.accept()
            except OSError:
                continue
            upstream = socket.create_connection((where.hostname, where.port))
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=pump, args=(a, b), daemon=True).start()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield listener.getsockname()[1]
    finally:
        stop.set()
        thread.join()
        listener.close()
