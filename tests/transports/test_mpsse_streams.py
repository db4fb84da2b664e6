"""The MPSSE stream compiler's bytes are pinned: a refactor of it must change none.

``tests/data/mpsse_streams.json`` holds the streams of representative programs (every bus
operation, every stream cut, both chips, the 1 KiB cut, owed leads, skips, the measured
wait's command cost) and every bulk OUT of typed-command sessions on the emulated FT232H
(calibration and a busy repeat included), written by ``tests/mpsse_golden.py`` from the code
at commit 2728094.  Here the same generator runs on today's code.
A deliberate change of the streams regenerates the file (``python tests/mpsse_golden.py``)
and says why in its commit.
"""

from __future__ import annotations

import json

import pytest

import mpsse_golden

pytest.importorskip("pyftdi")


@pytest.fixture(scope="module")
def golden() -> dict:
    return json.loads(mpsse_golden.OUT.read_text())


def test_compiled_streams_are_unchanged(golden):
    now = json.loads(json.dumps(mpsse_golden.compiled()))
    assert now.keys() == golden["compiled"].keys()
    for key, streams in golden["compiled"].items():
        assert now[key] == streams, key


def test_transported_streams_are_unchanged(golden):
    now = json.loads(json.dumps(mpsse_golden.transported()))
    assert now == golden["transported"]


def test_golden_covers_what_it_claims(golden):
    """Not an empty file: the 550-RDRP program needs many 1 KiB streams, the LTRJ+STT program
    is cut before STT, and the sessions include the calibration's 40 status polls."""
    assert len(golden["compiled"]["fixed100/rdrp_550/lead=0.0"]) > 60
    assert len(golden["compiled"]["fixed100/ltrj_stt/lead=0.0"]) == 2
    first = golden["transported"]["sim+ftdi://"][0:3]
    assert any(isinstance(s, str) and bytes.fromhex(s).count(0x83) > 40 for s in first)
