"""``lm629 --place`` and the labgrid driver's URL without a lab: what they refuse before
anything is acquired, and the URL a place's port becomes (the lab itself:
tests/integrations/test_labgrid_lab.py)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from labgrid_lab import SER2NET_LOOPBACK
from lm629_host.integrations.labgrid_place import network_port_url, split_place
from served import _console_script

ROOT = Path(__file__).resolve().parents[2]


def _lm629(*args: str, path: str = "/usr/bin:/bin") -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("LM629_", "LG_"))}
    env["PATH"] = path
    return subprocess.run([_console_script(), *args], capture_output=True, text=True,
                          timeout=60, env=env)


def test_a_place_without_labgrid_installed_is_one_line_exit_3():
    p = _lm629("--place", "lm629-bench", "status")
    assert p.returncode == 3, p.stderr
    assert p.stderr.splitlines() == [p.stderr.strip()] and p.stdout == ""
    assert "labgrid is not installed" in p.stderr and "labgrid-client" in p.stderr


def test_a_place_and_a_port_together_are_refused(tmp_path):
    p = _lm629("--port", "sim://", "--place", "lm629-bench", "status")
    assert p.returncode == 2, p.stderr
    assert "--port and --place both name a bench" in p.stderr


def test_a_place_needs_a_name():
    p = _lm629("--place", "?fast_baud=0", "status")
    assert p.returncode == 2 and "a place name" in p.stderr, p.stderr


def test_a_place_takes_a_port_urls_options():
    assert split_place("lm629-bench?fast_baud=0&failsafe=0.5") == (
        "lm629-bench", {"fast_baud": "0", "failsafe": "0.5"})
    assert split_place("lm629-bench") == ("lm629-bench", {})
    with pytest.raises(ValueError, match="given twice"):
        split_place("b?failsafe=1&failsafe=2")


def test_a_network_serial_port_becomes_an_rfc2217_url_with_the_options_passed_through():
    url = network_port_url("10.0.0.7", 51234, 115200, "rfc2217", {"fast_baud": 0, "failsafe": 0.5})
    assert url.text == "rfc2217://10.0.0.7:51234?baud=115200&fast_baud=0&failsafe=0.5"
    assert network_port_url("h", 1, 9600, "raw").text == "socket://h:1"
    with pytest.raises(ValueError, match="expected raw or rfc2217"):
        network_port_url("h", 1, 9600, "telnet")


def test_the_docs_show_the_ser2net_wrapper_the_tests_run():
    text = (ROOT / "docs" / "testing.md").read_text()
    blocks = re.findall(r"```sh\n(.*?)```", text, re.S)
    assert SER2NET_LOOPBACK in blocks
