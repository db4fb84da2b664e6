"""Shared by the firmware and simavr tests: build once per session, skip without toolchain."""

from __future__ import annotations

import pytest

from lm629_host import avrsim


@pytest.fixture(scope="session")
def firmware_built() -> None:
    """``make -C firmware_bridge firmware harness`` (incremental); skip with the reason when
    the AVR toolchain or libsimavr is missing (CI installs them: .ci/run)."""
    missing = avrsim.toolchain_missing()
    if missing:
        pytest.skip(f"AVR toolchain missing ({', '.join(missing)}): apt-get install "
                    f"{avrsim.PACKAGES}")
    avrsim.ensure_built()
