"""What every transport's ``execute`` does around the program (lm629_host/transports/base.py):
the chip-select range check before any bus cycle, the program count, observers that see (and
may refuse) each program, and the simulators' strict mode read through the transport.

LTRJ with a velocity word above 3FFFFFFF is a host protocol violation (AN-706 2.7: the velocity
is a 30-bit unsigned value); the simulator records it with that message.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host import AxisError, Cmd, ProtocolViolation
from lm629_host.bus.program import BusCycle, Op, Program, ProgramResult
from lm629_host.transports.base import BusObserver, Transport

#: a single-chip simulator, the Python bridge (4 chip selects), the emulated FT232H (2)
URLS = [("sim://", 1), ("sim+emu://", 4), ("sim+ftdi://", 2)]


@pytest.mark.parametrize("url, selects", URLS)
def test_a_chip_select_it_lacks_is_refused_before_any_bus_cycle(url, selects):
    """The first operation is a status read: on a refused program it never happens (the model's
    clock and history do not move, no exchange is counted)."""
    with lm629_host.open(url) as chip:
        t = chip.transport
        assert t.chip_selects == selects
        model = t.model
        tick, history, before = model.tick, len(model.history), t.stats.as_dict()
        with pytest.raises(AxisError, match=f"axis {selects} does not exist: .* has {selects} "
                                            r"chip select\(s\)"):
            t.execute(Program().status().select(selects).status())
        assert (model.tick, len(model.history), t.stats.as_dict()) == (tick, history, before)
        # the last chip select it has is taken (one status read each side of the select)
        assert len(t.execute(Program().status().select(selects - 1).status()).statuses) == 2
        assert t.stats.programs == before["programs"] + 1


class Watcher(BusObserver):
    def __init__(self, refuse: int | None = None) -> None:
        self.refuse = refuse
        self.seen: list[tuple[str, tuple[int, ...], object]] = []

    def program_starting(self, transport: Transport, program: Program) -> None:
        commands = tuple(o.arg for o in program.ops if o.op is Op.COMMAND)
        self.seen.append(("starting", commands, transport.program_depth))
        if self.refuse in commands:
            raise RuntimeError("refused by the watcher")

    def program_ended(self, transport: Transport, program: Program,
                      result: ProgramResult | None, error: BaseException | None) -> None:
        commands = tuple(o.arg for o in program.ops if o.op is Op.COMMAND)
        self.seen.append(("ended", commands, result.words if result else repr(error)))


@pytest.mark.parametrize("url", ["sim://", "sim+emu://"])
def test_an_observer_sees_each_program_and_can_refuse_one(url):
    with lm629_host.open(url) as chip:
        chip.reset()
        chip.load_trajectory(position=1234, velocity=65536, acceleration=100, start=True)
        t, w = chip.transport, Watcher(refuse=Cmd.DFH)
        t.add_observer(w)
        chip.transport.clock.sleep(0.5)  # the move: 1 count/sample for well past 1234 samples
        position = chip.read_desired_position()
        assert position == 1234
        history = len(t.model.history)
        with pytest.raises(RuntimeError, match="refused by the watcher"):
            chip.define_home()
        assert len(t.model.history) == history  # nothing of DFH reached the chip
        # a refused program never started: no program_ended for it
        assert w.seen == [("starting", (Cmd.RDDP,), 1), ("ended", (Cmd.RDDP,), (0, 1234)),
                          ("starting", (Cmd.DFH,), 1)]
        with pytest.raises(Exception, match="chip select"):
            t.execute(Program().select(9))  # a program that fails: ended with its error
        assert w.seen[-1][0] == "ended" and "AxisError" in w.seen[-1][2]
        t.remove_observer(w)
        chip.define_home()
        assert len(w.seen) == 5 and chip.read_desired_position() == 0


def test_only_an_observer_of_cycles_makes_the_simulator_show_its_polls():
    """A program-level observer leaves sim:// on its fast path (busy polls counted, not made
    one by one); one that overrides bus_cycle gets every cycle, busy polls included."""
    class Cycles(BusObserver):
        def __init__(self) -> None:
            self.cycles: list[BusCycle] = []

        def bus_cycle(self, cycle: BusCycle) -> None:
            self.cycles.append(cycle)

    with lm629_host.open("sim://") as chip:
        chip.reset()
        t = chip.transport
        t.add_observer(Watcher())
        assert not t._tracing()
        c = Cycles()
        t.add_observer(c)
        assert t._tracing()
        polls = t.stats.busy_polls
        chip.load_filter(kp=20)  # LFIL, control word, kp: a busy check before each
        kinds = [x.kind for x in c.cycles]
        assert [x for x in kinds if x != "status"] == ["command", "write", "write"]
        assert kinds.count("status") == t.stats.busy_polls - polls >= 3
        t.remove_observer(c)
        assert not t._tracing()


@pytest.mark.parametrize("url", ["sim://?strict=0", "sim+emu://?strict=0", "sim+ftdi://?strict=0"])
def test_strict_mode_is_read_and_set_through_the_transport(url):
    with lm629_host.open(url) as chip:
        chip.reset()
        t = chip.transport
        assert t.strict is False
        assert t.take_violations() == []
        before = t.clock.now()
        chip.raw(Cmd.LTRJ, [0x0008, 0xFFFF, 0xFFFF])  # recorded, not raised
        taken = t.take_violations()
        assert [str(v) for v in taken] == ["LTRJ velocity word FFFFFFFF is above 3FFFFFFF "
                                          "(AN-706 2.7: 30-bit unsigned range)"]
        # stamped on the simulator's clock, during that program
        assert 0 < before < taken[0].time <= t.clock.now()
        assert t.take_violations() == []  # forgotten once taken
        assert t.set_strict(True) is False and t.strict is True
        with pytest.raises(ProtocolViolation, match="above 3FFFFFFF"):
            chip.raw(Cmd.LTRJ, [0x0008, 0xFFFF, 0xFFFF])
        assert len(t.take_violations()) == 1
        assert t.set_strict(False) is True
