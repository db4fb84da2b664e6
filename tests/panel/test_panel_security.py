"""``lm629 panel``'s doors (docs/panel.md, "Security"; the notes' "a page on loopback that
moves motors"): a request whose Host is not the panel's (DNS rebinding) is refused, a command
from another site's Origin or without the token is refused and moves nothing, a page's own
command with its token goes through; listening beyond loopback needs --expose and puts the
token in the address.  A real ``lm629 panel`` process, plain HTTP (what a browser sends: the
headers are the point here)."""

from __future__ import annotations

import itertools
import subprocess
import time

import pytest

from panel_helpers import command, events, panel, request
from served import _console_script, _env


@pytest.fixture(scope="module")
def served_panel():
    with panel("sim://") as p:
        yield p, p.page_token()


def _desired_after(stream, seconds: float) -> int:
    """The desired position of the last row that came within ``seconds`` of wall time."""
    end = time.monotonic() + seconds
    last = None
    for m in stream:
        if m["type"] == "rows":
            last = m["rows"][-1][1]
        if time.monotonic() > end and last is not None:
            return last
    raise AssertionError("the event stream ended")


def test_bad_host_refused_forwarded_localhost_served(served_panel):
    p, _token = served_panel
    status, text = request(p, "GET", "/", host=f"evil.example:{p.url.rsplit(':', 1)[1]}")
    assert status == 403 and "Host 'evil.example:" in text and "DNS rebinding" in text
    status, text = request(p, "GET", "/", host="")
    assert status == 403
    # an SSH forward's local end: another port, a loopback name
    for host in ("localhost:9000", "127.0.0.1:18629", "[::1]:9000", p.hostport):
        status, text = request(p, "GET", "/", host=host)
        assert status == 200 and "lm629 panel" in text, host


def test_commands_need_own_origin_and_token_and_move_nothing_else(served_panel):
    p, token = served_panel
    with events(p, token) as stream:
        hello = next(stream)
        assert hello["type"] == "hello"
        move = {"cmd": "move", "target": "3000", "client": hello["client"]}
        refusals = [
            command(p, token, move, origin="http://evil.example"),  # another site's page
            command(p, token, move, origin=None),  # no Origin (a script outside a browser)
            command(p, token, move, origin=f"http://localhost:1{p.hostport.rsplit(':', 1)[1]}"),
            command(p, "", move),  # no token
            command(p, "x" + token[1:], move),  # a wrong one
        ]
        for status, answer in refusals:
            assert status == 403 and answer["ok"] is False and answer["text"].startswith("refused:")
        assert "Origin 'http://evil.example'" in refusals[0][1]["text"]
        assert "token" in refusals[3][1]["text"]
        status, text = request(p, "GET", "/events")  # the rows too need the token
        assert status == 403 and "token" in text
        assert _desired_after(stream, 0.5) == 0  # nothing moved
        # the page's own request goes through: the same body, its Origin and token
        status, answer = command(p, token, move)
        assert status == 200 and answer["ok"], answer
        assert answer["text"].startswith("moving to 3000 counts")
        assert _desired_after(stream, 0.5) > 0
        status, answer = command(p, token, {"cmd": "stop", "client": hello["client"]})
        assert answer == {"ok": True, "code": 0, "text": "abrupt stop sent", "data": None}


def test_event_rate_at_least_20_a_second(served_panel):
    """The page gets at least 20 updates a second (25 sent), each with the rows sampled
    since the last (50 a second)."""
    p, token = served_panel
    with events(p, token) as stream:
        for m in stream:
            if m["type"] == "rows":
                break
        start = time.monotonic()
        updates = rows = 0
        for m in itertools.takewhile(lambda _m: time.monotonic() - start < 2.0, stream):
            if m["type"] == "rows":
                updates += 1
                rows += len(m["rows"])
    assert updates >= 40, updates
    assert rows >= 80, rows  # 50 rows a second sampled


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([_console_script(), "--port", "sim://", *args], capture_output=True,
                          text=True, timeout=60, env=_env())


def test_listen_beyond_loopback_needs_expose():
    r = _run("panel", "--listen", "127.0.0.2:0")
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--expose" in lines[0] and "moves motors" in lines[0], r.stderr
    r = _run("panel", "--listen", "nowhere")
    assert r.returncode == 2 and "HOST:PORT" in r.stderr


def test_exposed_address_carries_the_token():
    with panel("sim://", "--expose", listen="127.0.0.2:0") as p:
        assert p.url.startswith("http://127.0.0.2:") and "/?token=" in p.url
        token = p.url.split("token=", 1)[1]
        status, text = request(p, "GET", "/")
        assert status == 403 and "token" in text  # beyond loopback the page itself needs it
        status, text = request(p, "GET", f"/?token={token}")
        assert status == 200 and token in text
        status, text = request(p, "GET", f"/?token={token}", host="evil.example")
        assert status == 403
        # what the page loads: the package's public files, without the token; the rows with it
        status, text = request(p, "GET", "/static/panel.js")
        assert status == 200 and "EventSource" in text
        assert request(p, "GET", "/events")[0] == 403
        code, err = p.end()
    assert code == 143 and err.strip().endswith("lm629: terminated (SIGTERM)"), err


def test_a_port_in_use_is_one_line_exit_3(served_panel):
    p, _token = served_panel
    r = _run("panel", "--listen", p.hostport)
    assert r.returncode == 3 and r.stdout == ""
    assert r.stderr.strip() == (f"lm629: cannot listen on {p.hostport}: Address already in use "
                                "(another panel there? --listen 127.0.0.1:0 takes a free port); "
                                "nothing was opened")
