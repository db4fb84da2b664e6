"""The tuner's design and searches (lm629_host.physics.design, .search), without a bus.

The axis: the ``sim://`` default motor in the tuner's units (12 V, 4 ohm, 0.025 N m/A,
4e-6 kg m^2, 500 lines, 256 us samples): 5.97e6 counts/s^2 at full output, a 25.3 ms time
constant, dry friction 2e-4 N m = 0.27 % of full output, and a holding load of 0.003 N m =
4.0 % (5.1 of the 128 output codes; 1311 of the filter's 32768 units).
"""

from __future__ import annotations

import math

import pytest

from lm629_host.physics.axis import AxisModel
from lm629_host.physics.design import (
    default_profile,
    design,
    holding_need,
    integral_note,
    needs_holding,
    record_duration,
)
from lm629_host.physics.search import golden, nelder_mead

T = 2048 / 8e6


def axis(load: float) -> AxisModel:
    accel = 5.968e6 * T * T
    return AxisModel(accel, T / 0.02528, 0.002667 * accel, load * accel)


def test_holding_need_is_the_load_in_filter_units():
    assert holding_need(axis(0.04)) == pytest.approx(0.04 * 32768)


def test_a_loaded_axis_gets_an_integral_that_holds_it_and_rests():
    m = axis(0.04)
    horizon = record_duration(m, 2000, T, 0.4)
    g, _step, move = design(m, 2000, 2, horizon, T, default_profile(m), rest_s=0.02)
    assert g.ki > 0 and g.il >= holding_need(m)  # the limit lets the term carry the load
    assert move is not None and move.rests and abs(move.final_error) <= 1
    assert move.overshoot <= 20  # 1 % of the move
    note = integral_note(m, g, T)
    assert f"ki={g.ki} il={g.il}" in note and "holds the load's 5.1 output codes" in note


def test_an_unloaded_axis_needs_no_holding():
    m = axis(0.0)
    horizon = record_duration(m, 2000, T, 0.4)
    g, step, move = design(m, 2000, 2, horizon, T, default_profile(m), rest_s=0.02)
    assert move is not None and move.rests and abs(move.final_error) <= 2
    assert not needs_holding(m, (step, move), 2)


def test_nelder_mead_and_golden_find_known_minima():
    p, v = nelder_mead(lambda x: (x[0] - 3) ** 2 + 10 * (x[1] + 1) ** 2, [0.0, 0.0],
                       [1.0, 1.0], 200)
    assert p[0] == pytest.approx(3, abs=1e-3) and p[1] == pytest.approx(-1, abs=1e-3)
    assert v < 1e-5
    assert golden(lambda x: math.cos(x), 2.0, 4.0, tol=1e-6) == pytest.approx(math.pi, abs=1e-5)
