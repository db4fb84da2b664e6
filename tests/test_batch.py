"""``LM629.batch()`` and the one-exchange ``move_to`` (issue 19, item 3): exchanges counted in
``transport.stats.round_trips`` on the Python far end and on the compiled firmware."""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host import CommandError
from lm629_host.opcodes import Cmd, Status

URLS = ["sim+emu://?fast_baud=1000000", "sim+avr://?fast_baud=1000000"]


def _chip(url: str, request):
    if "avr" in url:
        request.getfixturevalue("firmware_built")
    chip = lm629_host.open(url + "&record=1")
    chip.reset()
    return chip


@pytest.mark.parametrize("url", URLS)
def test_ten_calls_are_one_exchange(url, request):
    with _chip(url, request) as chip:
        chip.load_filter(kp=20)
        chip.update_filter()
        chip.move_to(500, velocity=65536, acceleration=655).wait()
        st = chip.transport.stats
        before = st.round_trips
        model = chip.transport.model
        model.record_clear()
        with chip.batch() as b:
            h = [b.read_real_position(), b.read_desired_position(), b.read_status(),
                 b.snapshot(), b.load_filter(kp=30, kd=100), b.update_filter(),
                 b.read_signals(), b.set_breakpoint(200), b.read_integration_sum(),
                 b.read_desired_velocity()]
            with pytest.raises(RuntimeError, match="not run yet"):
                _ = h[0].value
        assert st.round_trips - before == 1
        assert len(h) == 10
        cmds = [c for c, _ in model.history]
        # each value is what the call returns outside a batch, read again now (at rest)
        assert h[0].value == chip.read_real_position() == h[3].value.real_position
        assert h[1].value == 500 == h[3].value.desired_position
        assert h[4].value is None and h[9].value == 0
        # the commands reached the chip once each, in call order
        assert cmds == [Cmd.RDRP, Cmd.RDDP, Cmd.RDSIGS, Cmd.RDDP, Cmd.RDRP, Cmd.RDDV, Cmd.RDRV,
                        Cmd.RDSUM, Cmd.LFIL, Cmd.UDF, Cmd.RDSIGS, Cmd.SBPA, Cmd.RDSUM, Cmd.RDDV]
        assert chip.derivative_interval == 1


@pytest.mark.parametrize("url", URLS)
def test_move_to_starts_in_one_exchange(url, request):
    with _chip(url, request) as chip:
        chip.load_filter(kp=20)
        chip.update_filter()
        st = chip.transport.stats
        before = st.round_trips
        m = chip.move_to(1000, velocity=65536, acceleration=655)
        assert st.round_trips - before == 1
        assert m.start.desired_position == 0 and m.start.real_position == 0
        assert m.wait().error <= 20


def test_a_command_error_names_the_call():
    """The chip refuses an STT that changes the acceleration while it moves with the drive on
    (AN-706 4.6.1): the third call's."""
    with lm629_host.open("sim+emu://") as chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        with pytest.raises(CommandError, match=r"batch call 3 of 3, "
                                               r"load_trajectory\(acceleration=200, start=True\)"):
            with chip.batch() as b:
                p = b.read_real_position()
                b.load_trajectory(acceleration=100, velocity=65536, position=100000, start=True)
                b.load_trajectory(acceleration=200, start=True)
        assert p.value == 0  # the calls before it have their values
        assert chip.read_status() & Status.COMMAND_ERROR


def test_bad_arguments_and_unbatchable_calls_send_nothing():
    with lm629_host.open("sim+emu://") as chip:
        st = chip.transport.stats
        with pytest.raises(ValueError, match="kp"):
            with chip.batch() as b:
                b.read_real_position()
                b.load_filter(kp=-1)
        with pytest.raises(AttributeError, match="cannot be queued"):
            chip.batch().reset()
        assert st.round_trips == 0


def _polled_move(url: str) -> float:
    with lm629_host.open(url) as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        return chip.move_to(4000, velocity=4 * 65536, acceleration=6553).wait().duration


@pytest.mark.parametrize("url", URLS)
def test_move_wait_sees_the_end_on_the_far_side(url, request):
    """A 4000-count move at 4 counts/sample: each exchange waits on the bridge for trajectory
    complete (at most a poll) and reads a snapshot; once complete, one exchange holds the
    snapshots the settle rule still needs, a poll apart.  The end is seen when ``sim://``'s
    polling loop (no link) sees it, give or take a poll and the 1 Mbaud link's exchanges."""
    polled = _polled_move("sim://")
    with _chip(url, request) as chip:
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        st = chip.transport.stats
        before = st.round_trips
        move = chip.move_to(4000, velocity=4 * 65536, acceleration=6553)
        assert move.waiter is not None
        seen: list[float] = []
        r = move.wait(progress=lambda s: seen.append(s.time))
        rules = chip.move_rules
        assert abs(r.error) <= 20
        assert abs(r.duration - polled) <= rules.poll + 0.003, (r.duration, polled)
        # polls while it moves, then one or two settle exchanges
        assert st.round_trips - before <= polled / rules.poll + 3
        assert len(seen) >= st.round_trips - before + 3  # the settle check's snapshots


def _value_or_error(handle):
    """A handle's value, or the error reading it raises (a call the batch never ran): a
    value to compare, so that a missing one fails the assertion that lists them all."""
    try:
        return handle.value
    except RuntimeError as exc:
        return exc


@pytest.mark.parametrize("url", URLS)
def test_every_call_of_a_batch_reaches_the_chip_the_last_one_included(url, request):
    """Four calls, the last a write whose only trace is on the bus and in the chip: each
    command is on the chip's bus once, in call order, with the words written (LFIL: control
    word 000F, ds byte 0 and the four gains loaded, then kp ki kd il; SBPA 200: 0000 00C8;
    the chip logs a read without its words); every handle has its value; the filter loaded
    and updated is the chip's working filter."""
    with _chip(url, request) as chip:
        model = chip.transport.model
        model.record_clear()
        raised = None
        try:  # kept, so that a call gone missing fails on what reached the bus, whatever
            # the batch then says about it
            with chip.batch() as b:
                handles = [b.read_real_position(), b.load_filter(kp=30, ki=2, kd=100, il=50),
                           b.update_filter(), b.set_breakpoint(200)]
        except Exception as exc:  # noqa: BLE001 - reported by the assertions below
            raised = exc
        assert list(model.history) == [(Cmd.RDRP, ()), (Cmd.LFIL, (0x000F, 30, 2, 100, 50)),
                                       (Cmd.UDF, ()), (Cmd.SBPA, (0, 200))]
        assert raised is None
        assert [_value_or_error(h) for h in handles] == [0, None, None, None]
        chip.clock.sleep(1e-3)  # UDF takes effect at the next sample
        f = model.filter
        assert (f.kp, f.ki, f.kd, f.il) == (30, 2, 100, 50)
