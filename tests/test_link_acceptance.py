"""The core issue's acceptance scenarios, unchanged, over the bridge link protocol to the Python
far end (``sim+emu://``): every typed command goes through LinkTransport's frames, the
emulator's busy discipline and back, in simulated time.  (``sim+avr://`` runs the same
scenarios through the compiled firmware in tests/test_acceptance.py.)"""

from __future__ import annotations

import pytest

import test_acceptance as _acc  # tests/ is on sys.path (pytest's rootdir conftest)

# the scenarios, collected here a second time with base_url below
globals().update({k: v for k, v in vars(_acc).items() if k.startswith("test_")})


@pytest.fixture(params=["sim+emu://"])
def base_url(request) -> str:
    return request.param
