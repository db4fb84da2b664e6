"""CI never goes green with the firmware untested: without the AVR toolchain the run says so
in a red line, and with LM629_REQUIRE_AVR=1 (.ci/run) it fails.  Run as a child pytest whose
PATH holds only this Python (so make and avr-gcc are not found)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _pytest(env_extra: dict[str, str]) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "LM629_REQUIRE_AVR"}
    env["PATH"] = str(Path(sys.executable).parent)
    env.update(env_extra)
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
                           "tests/sim/test_soak_checker.py"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)


def test_missing_toolchain_is_said_loudly():
    r = _pytest({})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "AVR toolchain missing" in r.stdout and "SKIPPED" in r.stdout


def test_missing_toolchain_fails_when_required():
    r = _pytest({"LM629_REQUIRE_AVR": "1"})
    assert r.returncode != 0
    assert "AVR toolchain is missing" in r.stdout + r.stderr
