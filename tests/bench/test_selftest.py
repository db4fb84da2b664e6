"""The selftest (lm629_host.bench.selftest) on every simulated bench: the same model on both
sides passes; a bench that is not what the profile says is named.

Numbers, from the spec: one sample is 2048 clocks, so a chip clocked at 6 MHz measured by a
velocity run of one count a sample counts 2929.7 counts/s (6e6 / 2048) where the profile's
8 MHz predicts 3906.25: the measured clock is 6.00 MHz.  The model holds busy 20 us after a
command byte (ChipParams.busy_s) unless ``busy=`` says otherwise.
"""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest

import lm629_host
from lm629_host.bench import selftest as st
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import Program
from lm629_host.physics.limits import SoftLimits
from lm629_host.sim.harness import toolchain_missing
from lm629_host.transports.base import BusObserver, Transport

SIMULATORS = ["sim://", "sim+emu://", "sim+emu://?usb=uno&fast_baud=1000000", "sim+ftdi://",
              "sim+avr://"]


def _run(url: str, profile_hz: float = 8e6, **options) -> st.Report:
    if url.startswith("sim+avr") and toolchain_missing():
        pytest.skip("AVR toolchain missing")
    with lm629_host.open(url) as chip:
        return st.run(chip, st.Options(profile_hz, **options))


@pytest.mark.parametrize("url", SIMULATORS)
def test_passes_on_every_simulator(url):
    r = _run(url)
    assert (r.verdict, r.exit_code, r.error, r.faults) == ("PASS", 0, None, [])
    core = [m for m in r.measurements if m.check == "core"]
    assert len(core) > 40 and all(m.measured == m.expected for m in core)
    clock = next(m for m in r.measurements if m.name == "clock: measured")
    assert clock.measured == pytest.approx(8.0, rel=0.005)
    hi = next(m for m in r.measurements if m.name == "velocity past the breakpoint: HI pin")
    assert hi.measured is True and hi.expected is True
    # the timed reads were taken past the breakpoint (8 counts at 1/16 count a sample)
    assert hi.at >= st.BREAKPOINT_AT and hi.sample >= 16 * st.BREAKPOINT_AT
    # the report, saved and compared with today's model, finds no difference: its busy times
    # (the firmware's 4 us tick and op decoding make 20 us read as 5 to 8 on sim+avr://) are
    # compared within the resolution the report states, the transport's
    with lm629_host.open(url) as chip:
        assert r.busy_resolution_us == math.ceil(chip.transport.busy_probe_us) >= 1
    busy = [m for m in r.measurements if m.check == "busy"]
    assert all(m.measured is None or m.measured - 1 <= m.expected <= m.measured
               + r.busy_resolution_us for m in busy)
    assert st.compare(st.Report.from_json(json.loads(json.dumps(r.to_json())))) == []


def test_report_json_follows_its_schema(tmp_path):
    r = _run("sim://")
    path = tmp_path / "report.json"
    md = st.write_report(r, str(path))
    data = json.loads(path.read_text())
    assert st.validate(data) == []
    assert data["verdict"] == "PASS" and data["schema"] == st.SCHEMA_VERSION
    assert {m["check"] for m in data["measurements"]} == {"core", "clock", "wiring", "busy"}
    assert st.load_report(str(path)).to_json() == data  # a round trip keeps everything
    assert "## lm629 selftest: PASS" in Path(md).read_text()
    # what validate names in a broken report
    broken = dict(data, motion="no", extra=1)
    del broken["faults"]
    broken["measurements"] = [dict(data["measurements"][0], at="3")]
    problems = st.validate(broken)
    assert "missing key 'faults'" in problems and "unknown key 'extra'" in problems
    assert "motion is not bool" in problems
    assert "measurements[0].at is not int|null" in problems
    with pytest.raises(ValueError, match="not a selftest report"):
        st.Report.from_json(broken)


def test_a_6mhz_chip_on_an_8mhz_profile_names_the_measured_clock():
    r = _run("sim://?clock=6MHz")
    assert (r.verdict, r.exit_code) == ("DIFFERS", 1)
    clock = next(m for m in r.measurements if m.name == "clock: measured")
    assert clock.measured == pytest.approx(6.0, rel=0.005) and clock.expected == 8.0
    (fault,) = r.faults
    assert fault.line == "clock" and "measures 6.00 MHz" in fault.message
    assert "25 % off" in fault.message and '"6MHz"' in fault.fix
    # the core is compared at chip times (its desired position), not host times: no
    # difference comes from the slower clock
    assert [m for m in r.measurements if m.check == "core" and m.differs] == []


@pytest.mark.parametrize("url", ["sim://?wiring=hi-open", "sim+emu://?wiring=hi-open",
                                 "sim+ftdi://?wiring=hi-open"])
def test_hi_not_wired_is_named(url):
    r = _run(url)
    assert (r.verdict, r.exit_code) == ("DIFFERS", 1)
    (fault,) = r.faults
    assert fault.line == "HI" and "pin 17" in fault.message and "pin 17" in fault.fix
    # the chip's registers still show the interrupt: the core reads agree
    assert [m.name for m in r.differences] == ["velocity past the breakpoint: HI pin"]


@pytest.mark.parametrize("fault,line", [("index-open", "index"), ("encoder-open", "encoder")])
def test_index_and_encoder_faults_are_named_with_motion(fault, line):
    r = _run(f"sim://?wiring={fault}", motion=True)
    assert (r.verdict, r.exit_code) == ("DIFFERS", 1)
    assert [f.line for f in r.faults] == [line]
    # and the motor was left stopped and off (the final reset)
    with lm629_host.open(f"sim://?wiring={fault}") as chip:
        assert st.run(chip, st.Options(8e6)).verdict == "PASS"  # motor off: not seen


def test_motion_passes_on_a_good_bench():
    r = _run("sim://", motion=True)
    assert r.verdict == "PASS"
    assert {m.name: m.measured for m in r.measurements if m.name.startswith("motion: ")} == {
        "motion: encoder counts": True, "motion: index seen": True}


def test_no_chip_on_a_select_of_the_profile_is_named():
    r = _run("sim://?axes=2", selects=(0, 1, 2))
    assert r.exit_code == 1
    assert [f.line for f in r.faults] == ["cs 2"]


class _LateHost(BusObserver):
    """A host that is late now and then: before some programs it loses 3 to 40 ms (a busy
    machine, a paused process), on the transport's clock, so that the chip runs on."""

    def __init__(self) -> None:
        self.rng = random.Random(7)
        self.count = 0

    def program_starting(self, transport: Transport, program: Program) -> None:
        self.count += 1
        if self.count % 3 == 0:
            transport.clock.sleep(self.rng.uniform(0.003, 0.040))


@pytest.mark.parametrize("url", ["sim://", "sim+emu://?usb=uno"])
def test_a_late_host_makes_no_false_difference(url):
    with lm629_host.open(url) as chip:
        late = _LateHost()
        chip.transport.add_observer(late)
        r = st.run(chip, st.Options(8e6))
    assert late.count > 50
    assert (r.verdict, r.faults, r.differences) == ("PASS", [], [])


def test_a_chip_whose_positions_are_not_the_models_is_told_as_such():
    """A chip whose registers read 3FFFF000 after its reset (the simulator's reset_position,
    model choice 33) where the model's read 0: no timed read can be matched (the model would
    need 2^30 x 16 samples to reach the chip's desired position), so the core stops after
    the reset's reads and a fault says what is wrong, not a WaitTimeout ("check that the
    motor can follow") from a move that never came; the other checks still run, and the
    chip's motor is left off."""
    with lm629_host.open("sim://?reset_position=0x3FFFF000") as chip:
        r = st.run(chip, st.Options(8e6))
        assert chip.read_status() & 0x80
    assert (r.verdict, r.exit_code, r.error) == ("DIFFERS", 1, None)
    (fault,) = r.faults
    assert fault.line == "positions"
    assert "read 1073737728 and 1073737728 after its reset" in fault.message
    assert "where a reset leaves 0 and 0" in fault.message and "/RST" in fault.fix
    differs = {m.name: (m.measured, m.expected) for m in r.differences}
    assert differs["after reset: RDDP"] == (0x3FFFF000, 0)
    assert not any(m.at is not None for m in r.measurements)  # no timed read was tried
    assert next(m for m in r.measurements if m.check == "clock").measured == \
        pytest.approx(8.0, rel=0.005)


def test_a_shaft_resting_on_the_index_is_no_difference():
    """A bench parked on its index (a move of 1000 counts with the default encoder puts the
    shaft on it: model choice 20, 2 x 500 lines from power-up): SIP latches it at the next
    sample with nothing turning, so after DFH the chip's status has INDEX_PULSE (0C where
    the model, whose index is half a turn away, reads 04).  The selftest sees the shaft on
    the index first and puts the model's index under its shaft: no difference, and a
    report that compares clean."""
    with lm629_host.open("sim://") as chip:
        chip.load_filter(kp=3415, kd=26219)
        chip.update_filter()
        chip.move_to(1000, velocity=65536, acceleration=655).wait()
        r = st.run(chip, st.Options(8e6))
    assert (r.verdict, r.faults, r.differences) == ("PASS", [], [])
    rests = next(m for m in r.measurements if m.name == st.INDEX_AT_REST)
    assert rests.measured is True
    home = next(m for m in r.measurements if m.name == "home: status")
    assert home.measured == home.expected == 0x0C
    assert st.compare(st.Report.from_json(r.to_json())) == []
    with lm629_host.open("sim://") as chip:  # not on it: the model as it always was
        r = st.run(chip, st.Options(8e6))
    assert next(m for m in r.measurements if m.name == st.INDEX_AT_REST).measured is False
    assert next(m for m in r.measurements if m.name == "home: status").measured == 0x04


class _LateAtSIP(BusObserver):
    """A host late by ``late_s`` before each program that sends SIP: the SIP lands at another
    point of the chip's sample period than of the model's (a wait's end, a late host or a
    slow adapter does this on a bench)."""

    def __init__(self, late_s: float) -> None:
        self.late_s, self.seen = late_s, 0

    def program_starting(self, transport: Transport, program: Program) -> None:
        if any(o.op.name == "COMMAND" and o.arg == Cmd.SIP for o in program.ops):
            self.seen += 1
            transport.clock.sleep(self.late_s)


def _parked(url: str, sixteenths: int, chip_fault=None) -> st.Report:
    """The selftest of a shaft resting at angle 1000.61 (on the index count 1000, 2 x 500
    lines from power-up: model choice 20), the SIP late by ``sixteenths`` of a sample."""
    with lm629_host.open(f"{url}{'&' if '?' in url else '?'}start_position=1000.61") as chip:
        if chip_fault is not None:
            chip_fault(chip.transport.model)
        late = _LateAtSIP(sixteenths / 16 * 2048 / 8e6)
        chip.transport.add_observer(late)
        r = st.run(chip, st.Options(8e6))
    assert late.seen == 2  # the probe's SIP and the core's
    return r


@pytest.mark.parametrize("url,sixteenths", [("sim://", k) for k in range(16)]
                         + [("sim+emu://", k) for k in (0, 5, 11)])
def test_a_shaft_resting_on_the_index_is_no_difference_wherever_the_sip_lands(url, sixteenths):
    """The crossings machine's finding (shaft parked at angle 1000.61 with kp 400): SIP
    latches an index under a shaft at rest at the first sample after it, so a status read
    right after SIP (or after the DFH that follows) saw the latch or not by where in its
    sample period the SIP landed, on the chip and on the model alike but not at the same
    point: "home: status" chip 04, model 0C (on sim+emu://, "index armed: status" chip 0C,
    model 04).  The fraction of the count the shaft rests at (0.61, the model's 0.0) plays no
    part.  The reads after SIP wait INDEX_PROBE_SAMPLES samples: 0C on both, at every point
    of the sample period."""
    r = _parked(url, sixteenths)
    assert (r.verdict, r.faults, r.differences) == ("PASS", [], [])
    seen = {m.name: (m.measured, m.expected) for m in r.measurements}
    assert seen[st.INDEX_AT_REST] == (True, True)
    # latched (bit 3) on both; signals bit 0 (SIP armed) cleared by the latch at 0000
    assert seen["index armed: status"] == seen["home: status"] == (0x0C, 0x0C)
    assert not seen["index armed: RDSIGS"][0] & 1 and seen["index armed: RDIP"] == (0, 0)
    wait = next(m for m in r.measurements if m.name == "index armed: status").command
    assert wait == f"SIP; wait {st.latch_wait_us(8e6)} us" == "SIP; wait 768 us"
    assert st.compare(st.Report.from_json(r.to_json())) == []


def _dfh_clears_the_index_flag(model) -> None:
    """A chip that mis-handles the index: DFH clears the latched INDEX_PULSE (status bit 3),
    which only RSTI may clear."""
    execute = model._execute

    def faulty(cmd, words):
        execute(cmd, words)
        if cmd is Cmd.DFH:
            model.flags &= ~0x08

    model._execute = faulty


@pytest.mark.parametrize("sixteenths", [0, 4, 8, 12])
def test_a_chip_that_mishandles_a_latched_index_still_differs_wherever_the_sip_lands(
        sixteenths):
    """The wait after SIP judges every index bit where the model can tell it: a chip whose
    DFH clears the latched index bit reads 04 after DFH where the model reads 0C, the same
    three differences at every point of the sample period.  (Read right after SIP, where the
    latch fell decided it: at half a sample late the chip latched after its DFH, so its fault
    did not show at all, and the one difference told was the model's earlier latch.)"""
    r = _parked("sim://", sixteenths, _dfh_clears_the_index_flag)
    assert (r.verdict, r.exit_code, r.faults) == ("DIFFERS", 1, [])
    assert {m.name: (m.measured, m.expected) for m in r.differences} == {
        "home: status": (0x04, 0x0C), "motor off: status": (0x84, 0x8C),
        "motor off: RDSIGS": (0x584, 0x58C)}  # signals' low byte: the status's flags


def test_an_index_that_never_latches_under_a_parked_shaft_is_named_with_motion():
    """The index not wired, the shaft resting where the index would be: the probe sees no
    index (the model's stays half a turn away, so the core agrees), and --motion's run, whose
    move crosses the index count twice in 2.5 turns, names the index."""
    r = _run("sim://?wiring=index-open&start_position=1000.61", motion=True)
    assert next(m for m in r.measurements if m.name == st.INDEX_AT_REST).measured is False
    assert (r.verdict, r.exit_code, [f.line for f in r.faults]) == ("DIFFERS", 1, ["index"])


@pytest.mark.parametrize("url,profile,found", [("sim://?chip=lm628", "lm629", "LM628"),
                                               ("sim+emu://?chip=lm628", "lm629", "LM628"),
                                               ("sim://", "lm628", "LM629")])
def test_the_other_chip_on_a_profile_is_named(url, profile, found):
    """PORT12, the one command an LM628 takes and an LM629 refuses (command-error bit),
    goes out on either profile, motor off: an LM628 where the profile says LM629 (or the
    other way round) is a fault naming the part, and the same chip on its own profile
    passes."""
    r = _run(url, chip=profile)
    assert r.verdict == "DIFFERS"
    (fault,) = r.faults
    assert fault.line == "chip"
    assert f"it is an {found}, the profile says {profile.upper()}" in fault.message
    assert f'chip to "{found.lower()}"' in fault.fix
    assert {m.name for m in r.differences} <= {"12-bit port: status", "12-bit port: RDSIGS"}
    assert _run(url, chip=found.lower()).verdict == "PASS"


def test_an_axis_with_soft_limits_passes_and_keeps_them():
    """A profile's soft limits (min/max) refuse velocity mode; the core's and the clock's
    velocity runs drive nothing (gains 0), so they run with the limits lifted (the selftest
    of an axis with limits was a ValueError out of run(): "velocity mode runs until it is
    stopped, past any soft limit"); the limits hold again afterwards."""
    limits = SoftLimits(min=-1000, max=1000)
    with lm629_host.open("sim://") as chip:
        chip.limits = limits
        r = st.run(chip, st.Options(8e6))
        assert chip.limits is limits
        with pytest.raises(ValueError, match="soft limit"):
            chip.run_velocity(65536, 6553)
    assert (r.verdict, r.error, r.faults, r.differences) == ("PASS", None, [], [])


def test_compare_a_report_with_todays_model(tmp_path):
    r = _run("sim://")
    path = tmp_path / "r.json"
    st.write_report(r, str(path))
    assert st.compare(st.load_report(str(path))) == []
    data = json.loads(path.read_text())
    edited = next(m for m in data["measurements"] if m["name"] == "after reset: RDSIGS")
    edited["measured"] = 0x01C4
    path.write_text(json.dumps(data))
    (line,) = st.compare(st.load_report(str(path)))
    assert line.startswith("after reset: RDSIGS: the chip read 01C4, today's model gives 01C0")


def test_compare_judges_the_clock(tmp_path):
    """A report whose clock was measured at 6.00 MHz on its 8 MHz profile (edited here) does
    not compare clean: the clock is part of what --compare checks (3 % tolerance)."""
    data = _run("sim://").to_json()
    clock = next(m for m in data["measurements"] if m["name"] == "clock: measured")
    clock["measured"] = 6.0
    (line,) = st.compare(st.Report.from_json(data))
    assert line.startswith("clock: measured: the chip read 6 MHz, today's model gives 8 MHz")
    clock["measured"] = 8.0 * (1 + st.CLOCK_TOLERANCE / 2)
    assert st.compare(st.Report.from_json(data)) == []


def test_compare_judges_busy_times_within_the_stated_resolution():
    """The probe reads busy at a wait 1 us shorter than the one it reads clear at, and its
    status read lands up to the resolution later: a chip that reads m us held busy for m - 1
    to m + resolution.  The model's 20 us, against a report stating 16 us: m = 4 to 21 is
    no difference, 3 and 22 are; a version 1 report (no resolution) shows them only."""
    data = _run("sim://").to_json()
    assert data["busy_resolution_us"] == 1
    data["busy_resolution_us"] = 16
    busy = next(m for m in data["measurements"] if m["name"] == "busy: RSTI")
    for measured, differs in ((4, False), (21, False), (3, True), (22, True)):
        busy["measured"] = measured
        lines = st.compare(st.Report.from_json(data))
        assert bool(lines) is differs, (measured, lines)
    assert lines == ["busy: RSTI: the chip read 22 us (its busy time 21 to 38 us, the "
                     "instrument's resolution), today's model gives 20 us (RSTI, wait, RDSTAT)"]
    old = dict(data, schema=1)
    del old["busy_resolution_us"]
    assert st.validate(old) == []
    assert st.compare(st.Report.from_json(old)) == []


def test_the_model_takes_the_busy_times_a_report_shows():
    """A chip whose busy times differ from the model's 20 us is measured as such, and the
    report's ``sim://?busy=`` option makes a model that measures the same."""
    r = _run("sim://?busy=LTRJ:41,RDSIGS:33")
    busy = {m.name: (m.measured, m.expected) for m in r.measurements if m.check == "busy"}
    assert busy["busy: LTRJ"] == (41, 20) and busy["busy: RDSIGS"] == (33, 20)
    assert busy["busy: MSKI"] == (20, 20)
    assert r.verdict == "PASS"  # busy times are shown, never judged
    option = r.busy_option()
    assert "LTRJ:41" in option and "RDSIGS:33" in option
    again = _run(f"sim://?busy={option}")
    assert again.busy_option() == option


def test_busy_option_is_checked():
    with pytest.raises(ValueError, match="'FOO' is not a command"):
        lm629_host.open("sim://?busy=FOO:20")
    with pytest.raises(ValueError, match="the datasheet's worst case"):
        lm629_host.open("sim://?busy=STT:150")


class _PausedBeforeRead(BusObserver):
    """A host paused for ``pause_s`` just before its ``nth`` timed read (a program that
    starts with RDDP and reads more after it): the chip runs on meanwhile."""

    def __init__(self, nth: int, pause_s: float) -> None:
        self.nth, self.pause_s, self.seen = nth, pause_s, 0

    def program_starting(self, transport: Transport, program: Program) -> None:
        ops = [o for o in program.ops if o.op.name != "SELECT"]
        if len(ops) > 8 and ops[0].op.name == "COMMAND" and ops[0].arg == 0x08:
            self.seen += 1
            if self.seen == self.nth:
                transport.clock.sleep(self.pause_s)


@pytest.mark.parametrize("nth,pause_s", [(1, 0.05), (3, 0.3)])
def test_a_host_paused_past_the_event_it_meant_to_read_makes_no_false_difference(nth, pause_s):
    """Paused past the breakpoint before the read meant for before it (50 ms: 12 counts at
    1/16 count a sample), or past the end of the position move before its mid-cruise read
    (300 ms: the move lasts 40 x 16 samples, 164 ms): the chip is read at a later chip time,
    and the model is compared at that chip time, where the chip's reads are the model's."""
    with lm629_host.open("sim://") as chip:
        paused = _PausedBeforeRead(nth, pause_s)
        chip.transport.add_observer(paused)
        r = st.run(chip, st.Options(8e6))
    assert paused.seen >= nth
    assert (r.verdict, r.faults, r.differences) == ("PASS", [], [])
    late = [m for m in r.measurements if m.at is not None]
    if nth == 3:  # read at rest on the target, 40 counts on: the model there too
        cruise = next(m for m in late if m.name == "position cruising: RDDV")
        assert cruise.measured == cruise.expected == 0


def test_a_timed_read_is_compared_at_the_chips_sample_within_a_whole_count():
    """An acceleration of 16 (16.16: 1/4096 count/sample^2) ramps RDDV by 16 every sample
    while RDDP moves one whole count every ~40 samples around sample 200 (n^2 / 8192 counts):
    a chip read 203 samples into the ramp is on whole count 5, which the model reaches at
    sample 202 (202 x 203 x 8 >= 5 x 65536), at another RDDV.  The model is compared at the
    sample whose reads are the chip's (RDDV 16 x n), not at the first of the count."""
    with lm629_host.open("sim://") as chip, lm629_host.open("sim://") as model:
        ls = st.Lockstep(chip, model)
        for side in ls.sides():
            side.reset()
        ls.step("gains 0", [("p", lambda c: c.filter_program(kp=0, ki=0, kd=0, il=0)),
                            ("w", Cmd.UDF)])
        ls.step("ramp", [("p", lambda c: c.trajectory_program(
            acceleration=16, velocity=st.SLOW, velocity_mode=True)), ("w", Cmd.STT)])
        ls.started()
        chip.clock.sleep(203 * 2048 / 8e6)
        ls.timed("ramp", [("r", Cmd.RDDV)], per_sample=1 / 16)
    rddv = next(m for m in ls.out if m.name == "ramp: RDDV")
    n = rddv.sample  # samples since the STT: the velocity is n x the acceleration
    assert rddv.measured == rddv.expected == 16 * n and n in (203, 204)
    assert rddv.at == (16 * n * (n + 1) // 2) >> 16 == 5


class _SlowCycles(BusObserver):
    """An adapter that takes ``per_cycle_s`` for every bus cycle (simulated: the chip runs on
    meanwhile), so that a sample boundary falls inside a step's program, as on a bench."""

    def __init__(self, per_cycle_s: float) -> None:
        self.per_cycle_s = per_cycle_s
        self.transport: Transport | None = None

    def bus_cycle(self, cycle) -> None:
        assert self.transport is not None
        self.transport.clock.sleep(self.per_cycle_s)


@pytest.mark.parametrize("per_cycle_us", [30, 70])
def test_a_slow_adapter_makes_no_false_difference(per_cycle_us):
    """With 30 or 70 us a bus cycle a step of ten cycles spans one or three samples (256 us):
    every step's reads are ones that no sample in between changes (a read right after UDF
    would see signals bit 13, set for the one sample at which the filter is taken)."""
    with lm629_host.open("sim://") as chip:
        slow = _SlowCycles(per_cycle_us * 1e-6)
        slow.transport = chip.transport
        chip.transport.add_observer(slow)
        r = st.run(chip, st.Options(8e6))
    assert (r.verdict, r.faults, r.differences) == ("PASS", [], [])


class _CtrlC(BusObserver):
    """Ctrl-C at the bus program after the ``nth`` STT (between programs, as the CLI delivers
    it)."""

    def __init__(self, nth: int) -> None:
        self.nth, self.starts, self.raised = nth, 0, False

    def program_starting(self, transport: Transport, program: Program) -> None:
        if self.starts >= self.nth and not self.raised:
            self.raised = True
            raise KeyboardInterrupt
        self.starts += sum(1 for o in program.ops if o.op.name == "COMMAND" and o.arg == 0x01)


@pytest.mark.parametrize("motion,nth", [(False, 1), (False, 3), (True, 7)])
def test_ctrl_c_during_the_selftest_stops_the_motor(motion, nth):
    """After the first STT the core's velocity-mode run is under way (drive on, gains 0),
    after the third its position-mode move; after the seventh (four in the core, two in the
    clock run) the --motion run turns the motor.  Each time Ctrl-C leaves the motor off
    (status bit 7) and is raised on (the CLI's exit 130)."""
    with lm629_host.open("sim://") as chip:
        stop = _CtrlC(nth)
        chip.transport.add_observer(stop)
        with pytest.raises(KeyboardInterrupt):
            st.run(chip, st.Options(8e6, motion=motion))
        chip.transport.remove_observer(stop)
        assert stop.raised and chip.read_status() & 0x80
