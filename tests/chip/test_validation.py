"""Every out-of-range argument of every LM629 method raises ValueError before any bus cycle.

Ranges (datasheet): kp, ki, kd, il, thresholds 0000-7FFF; positions C0000000-3FFFFFFF;
velocity and acceleration 0-3FFFFFFF; derivative interval 1-256 samples; MSKI/RSTI take only
the six interrupt bits (status bits 1-6).
"""

from __future__ import annotations

import pytest

from lm629_host import Status
from lm629_host.chip.shapes import Points, SCurve

BAD_CALLS = [
    # (method, args, kwargs, words that must appear in the message)
    ("mask_interrupts", (0x01,), {}, ["flags", "0x01"]),  # the busy bit is no interrupt
    ("mask_interrupts", (0x80,), {}, ["flags"]),
    ("mask_interrupts", (0x100,), {}, ["flags=256", "0..255"]),
    ("reset_interrupts", (), {"flags": 0x81}, ["flags"]),
    ("reset_interrupts", (), {"flags": -1}, ["flags=-1"]),
    ("start_flags", (0x80,), {}, ["clear=0x80", "not interrupt conditions"]),
    ("load_position_error", (0x8000,), {}, ["threshold=32768", "0..32767"]),
    ("load_position_error", (-1,), {"stop": True}, ["threshold=-1"]),
    ("load_position_error", (1.5,), {}, ["threshold=1.5", "integer"]),
    ("set_breakpoint", (0x40000000,), {}, ["position=1073741824", "-1073741824..1073741823"]),
    ("set_breakpoint", (-0x40000001,), {"relative": True}, ["position=-1073741825"]),
    ("load_filter", (), {"kp": 0x8000}, ["kp=32768", "0..32767"]),
    ("load_filter", (), {"ki": -1}, ["ki=-1"]),
    ("load_filter", (), {"kd": 40000}, ["kd=40000"]),
    ("load_filter", (), {"il": 0x10000}, ["il=65536"]),
    ("load_filter", (), {"derivative_interval": 0}, ["derivative_interval=0", "1..256"]),
    ("load_filter", (), {"derivative_interval": 257}, ["derivative_interval=257"]),
    ("load_filter", (), {"kp": "20"}, ["kp='20'"]),
    ("load_filter", (), {"kp": True}, ["kp=True"]),
    ("load_trajectory", (), {"acceleration": -1}, ["acceleration=-1", "0..1073741823"]),
    ("load_trajectory", (), {"acceleration": 0x40000000}, ["acceleration=1073741824"]),
    ("load_trajectory", (), {"velocity": 0x40000000}, ["velocity=1073741824"]),
    ("load_trajectory", (), {"velocity": -5}, ["velocity=-5"]),
    ("load_trajectory", (), {"position": 0x40000000}, ["position=1073741824"]),
    ("load_trajectory", (), {"position": -0x40000001}, ["position=-1073741825"]),
    ("load_trajectory", (), {"stop": "hard"}, ["stop='hard'"]),
    ("load_trajectory", (), {"stop": "smooth", "position": 10}, ["stop='smooth'", "cannot"]),
    ("load_trajectory", (), {"velocity_mode": True, "position": 10}, ["velocity_mode"]),
    ("load_trajectory", (), {"velocity": 100, "start": True, "position": 2**31}, ["position="]),
    ("record", (0,), {"duration_s": 1}, ["period_s=0", "above 0"]),
    ("record", (1e-3, 5e-4), {}, ["duration_s=0.0005", "in 0.001..65.535"]),
    ("record", (1e-3, 100.0), {}, ["duration_s=100.0", "in 0.001..65.535", "65535 rows"]),
    ("record", (1e-3, float("inf")), {}, ["duration_s=inf", "in 0.001..65.535"]),
    ("record_stream", (float("nan"),), {}, ["period_s=nan"]),
    ("run_velocity", (2**30,), {}, ["velocity=1073741824", "-1073741823..1073741823"]),
    ("run_velocity", (65536,), {"acceleration": -1}, ["acceleration=-1"]),
    ("move_to", (1000,), {"velocity": 0}, ["velocity=0", "1..1073741823"]),
    ("move_to", (1000,), {"velocity": 65536, "acceleration": 0}, ["acceleration=0"]),
    ("move_to", (1000,), {"velocity": float("inf")}, ["velocity=inf"]),
    ("move_to", (0x40000000,), {"velocity": 65536}, ["position=1073741824"]),
    ("check_move", (0x40000000,), {"velocity": 65536}, ["position=1073741824"]),
    ("check_move", (1000,), {"velocity": 0}, ["velocity=0", "1..1073741823"]),
    ("move_profile", (0x40000000, SCurve(1e4, 1e5, 1e6)), {}, ["position=1073741824",
                                                               "0xC0000000..0x3FFFFFFF"]),
    ("move_profile", (1000, "s-curve"), {}, ["shape='s-curve'", "SCurve"]),
    ("move_profile", (1000, SCurve(1e4, 1e5, 1e6)), {"piece_s": 0.005},
     ["piece_s=0.005", "0.01..0.25"]),
    ("move_profile", (2000, Points([(0, 0), (0.1, 1e4), (0.2, 0)])), {"relative": True},
     ["points cover 1000 counts but the move is 2000 counts", "the area"]),
    ("wait_for", (0,), {}, ["flags=0"]),
    ("wait_for", (Status.TRAJECTORY_COMPLETE,), {"timeout": 0}, ["timeout=0"]),
    ("raw", (0x100,), {}, ["command=256"]),
    ("raw", (0x1E,), {"write": [0x10000]}, ["word=65536"]),
    ("raw", (0x0A,), {"read": 17}, ["read=17"]),
    ("raw", (0x1E,), {"write": [1], "read": 1}, ["not both"]),
]


@pytest.mark.parametrize("method,args,kwargs,words", BAD_CALLS,
                         ids=[f"{m}-{i}" for i, (m, *_rest) in enumerate(BAD_CALLS)])
def test_bad_argument_raises_before_any_bus_cycle(open_chip, recorder, method, args, kwargs, words):
    chip = open_chip("sim://")
    stats_before = chip.transport.stats.as_dict()
    with pytest.raises(ValueError) as info:
        getattr(chip, method)(*args, **kwargs)
    for w in words:
        assert w in str(info.value), f"{w!r} not in {info.value}"
    assert recorder.cycles == []
    assert chip.transport.stats.as_dict() == stats_before


def test_port12_on_an_lm629_raises_before_the_bus(open_chip, recorder):
    chip = open_chip("sim://")
    with pytest.raises(ValueError, match="LM628"):
        chip.port12()
    assert recorder.cycles == []


def test_relative_velocity_may_be_negative(open_chip, recorder):
    """A relative velocity is a signed change; the chip (not the host) refuses one that would
    make the velocity negative, so the host only checks the word range."""
    chip = open_chip("sim://")
    recorder.clear()
    chip.load_trajectory(velocity=-65536, velocity_relative=True)
    assert recorder.data() == [("command", 0x1F), ("write", 0x000C), ("write", 0xFFFF),
                               ("write", 0x0000)]


def test_every_method_has_a_validated_argument_or_none():
    """Guard: every public method taking arguments appears in BAD_CALLS."""
    import inspect

    from lm629_host import LM629

    covered = {m for m, *_ in BAD_CALLS}
    takes_args = {
        name for name, fn in inspect.getmembers(LM629, inspect.isfunction)
        if not name.startswith("_") and len(inspect.signature(fn).parameters) > 1
        # run, intercept and shadow take a program or a runner; start_checked the status
        # bytes a board's STT program read; extended a snapshot this chip read;
        # clearing_wrap a program this chip built
        and name not in ("run", "intercept", "shadow", "filter_program", "trajectory_program",
                         "start", "start_checked", "extended", "clearing_wrap")
    }
    assert takes_args - covered == set()


@pytest.mark.parametrize("method,kwargs,argument,value,lo,hi", [
    ("load_filter", {"kp": 0x8000}, "kp", 0x8000, 0, 0x7FFF),
    ("load_filter", {"derivative_interval": 0}, "derivative_interval", 0, 1, 256),
    ("set_breakpoint", {"position": 0x40000000}, "position", 0x40000000, -0x40000000, 0x3FFFFFFF),
    ("load_position_error", {"threshold": 1.5}, "threshold", 1.5, 0, 0x7FFF),
])
def test_an_argument_error_carries_its_argument_value_and_range(open_chip, method, kwargs,
                                                                argument, value, lo, hi):
    """The CLI names its own option (--ds for derivative_interval) from these fields, not
    from the message text."""
    from lm629_host.errors import ArgumentError
    chip = open_chip("sim://")
    with pytest.raises(ArgumentError) as info:
        getattr(chip, method)(**kwargs)
    e = info.value
    assert isinstance(e, ValueError)
    assert (e.argument, e.value, e.lo, e.hi) == (argument, value, lo, hi)


def test_an_axis_error_is_an_argument_error_naming_the_axis(open_chip):
    from lm629_host import AxisError, LM629
    from lm629_host.errors import ArgumentError
    chip = open_chip("sim://?axes=2")
    with pytest.raises(AxisError) as info:
        LM629(chip.transport, axis=2)
    assert isinstance(info.value, ArgumentError)
    assert (info.value.argument, info.value.value, info.value.lo, info.value.hi) == ("axis", 2, 0, 1)


def test_a_wait_timeout_says_what_it_waited_for(open_chip):
    from lm629_host import WaitTimeout
    chip = open_chip("sim://")
    chip.reset()
    with pytest.raises(WaitTimeout) as info:
        chip.wait_for(Status.INDEX_PULSE, timeout=0.01, what="the index pulse")
    assert info.value.what == "the index pulse" and info.value.flags == Status.INDEX_PULSE
    assert "waited 0.01 s for the index pulse but status stayed" in str(info.value)
    with pytest.raises(WaitTimeout) as info:
        chip.wait_for(Status.POSITION_ERROR, timeout=0.01)
    assert info.value.what == str(Status.POSITION_ERROR)
