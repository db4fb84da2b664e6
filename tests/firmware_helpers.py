"""Shared by the firmware and simavr tests: build once per session.

Without the AVR toolchain (and no images built earlier) these tests skip, loudly: the
terminal summary says how many (tests/conftest.py), and with ``LM629_REQUIRE_AVR=1`` (set by
``.ci/run``) they fail instead.  With the toolchain, a firmware that does not build FAILS them:
a broken build must never turn a third of the suite into skips.
"""

from __future__ import annotations

import os

import pytest

from lm629_host.sim import harness

#: set by .ci/run: a missing toolchain fails the firmware tests instead of skipping them
REQUIRE_ENV = "LM629_REQUIRE_AVR"


def require_firmware() -> None:
    """Build the firmware and harness (incremental), or skip/fail as described above."""
    missing = harness.toolchain_missing()
    if missing and not (harness.LIBRARY.exists() and harness.firmware_path().exists()):
        why = (f"AVR toolchain missing ({', '.join(missing)}): apt-get install "
               f"{harness.PACKAGES} (or run .ci/run as root)")
        if os.environ.get(REQUIRE_ENV) == "1":
            pytest.fail(f"{REQUIRE_ENV}=1 and {why}")
        pytest.skip(why)
    harness.ensure_built()  # HarnessError (the build failed): the test fails with make's output


@pytest.fixture(scope="session")
def firmware_built() -> None:
    """``make -C firmware_bridge firmware harness`` once per session (see the module doc)."""
    require_firmware()
