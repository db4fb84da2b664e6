"""The first hour with a new board, as one function: the bring-up of AN-706 2.12 and AN-868.

1. reset check (AN-706 4.4.1): status 00 at once, 84/C4 after 1.5 ms, 80/C0 after MSKI/RSTI;
2. loop phasing, the tuner's check (:func:`lm629_host.bench.phasing.check_phasing`): gentle P-only
   steps up and down; the shaft must follow them.  With the motor leads (or the encoder
   channels) the wrong way round the loop is positive feedback and the shaft heads away:
   "swap the motor leads"; a load that pulls the shaft away is told apart from that by
   watching it coast with the drive off, and the gain raised until the loop holds it;
3. kp = 20 hold: the shaft must come to rest inside the P-only dead band, 256 / kp counts
   (8-bit output: the drive is the top byte of kp x error, AN-706 5.2.4);
4. a small move (1000 counts by default);
5. its largest following error and its settle time into that dead band;
6. what to do next.

:func:`run_bringup` runs the steps (one function each: :func:`reset_step`,
:func:`phasing_step`, :func:`hold_step`, :func:`move_steps`, :func:`next_steps`) and returns a
:class:`BringupReport`; the CLI (``lm629 bringup``) only renders it and chooses the exit code,
so that the sequence is tested without click.  The small move is watched by the rules of every
move (:class:`~lm629_host.chip.move.MoveWatch`) with the dead band as tolerance.  All waiting is on
the chip's clock (simulated time on ``sim://``), and every duration is in seconds, whatever the
poll period.  Any exception while the motor may move stops it first
(:func:`lm629_host.chip.safety.stop_on_error`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace

from lm629_host.errors import MotionError, ResetError
from lm629_host.chip.lm629 import LM629
from lm629_host.bus.opcodes import Status
from lm629_host.physics.plan import plan
from lm629_host.chip.safety import STOP_NOTE, emergency_stop, stop_on_error
from lm629_host.physics.units import FIXED_ONE
from lm629_host.bench.wiring_check import wiring_suspects


@dataclass(frozen=True)
class BringupOptions:
    """The numbers of the sequence (raw chip words and counts, AN-706 2.12 by default)."""

    #: counts the phasing may take the shaft either way (its steps are an eighth of it)
    phasing_travel: int = 4000
    phasing_time_s: float = 0.3  #: seconds each phasing step is watched at most
    hold_kp: int = 20
    hold_time_s: float = 0.5
    move_distance: int = 1000  #: counts
    move_velocity: int = FIXED_ONE // 2  #: 0.5 counts/sample
    move_acceleration: int = FIXED_ONE // 400  #: 200 samples of ramp
    settle_timeout_s: float = 2.0
    #: seconds at rest inside the dead band that count as settled
    still_s: float = 0.05
    poll_s: float = 0.002

    @property
    def dead_band(self) -> int:
        """Counts of error a P-only loop at ``hold_kp`` leaves uncorrected (8-bit output),
        plus one for the encoder's quantisation."""
        return math.ceil(256 / self.hold_kp) + 1


@dataclass
class StepResult:
    """One step's verdict: ``ok`` True (pass), False (fail) or None (information, skipped)."""

    name: str
    ok: bool | None
    summary: str
    details: list[str] = field(default_factory=list)
    data: Mapping[str, object] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        return {True: "PASS", False: "FAIL", None: "----"}[self.ok]


@dataclass
class BringupReport:
    steps: list[StepResult] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(s.ok is not False for s in self.steps) and \
            any(s.name == "settle" and s.ok for s in self.steps)

    @property
    def reset_failed(self) -> bool:
        """The chip did not come out of reset (nothing else was tried)."""
        return bool(self.steps) and self.steps[0].name == "reset" and self.steps[0].ok is False

    def step(self, name: str) -> StepResult | None:
        return next((s for s in self.steps if s.name == name), None)


def reset_with_statuses(chip: LM629) -> tuple[Status, list[int]]:
    """``chip.reset()``, also returning every status byte its programs read."""
    return chip.reset_statuses()


def _hex(statuses: list[int] | tuple[int, ...]) -> str:
    return " ".join(f"{s:02X}" for s in statuses) or "nothing"


def run_bringup(chip: LM629, options: BringupOptions = BringupOptions(), *,
                confirm: Callable[[str], bool] = lambda question: True,
                announce: Callable[[str], None] = lambda text: None,
                report: Callable[[StepResult], None] = lambda step: None,
                clock_hz: float | None = None) -> BringupReport:
    """Run the sequence; stop at the first failed step.  ``confirm`` is asked before the motor
    first turns (False ends the sequence there); ``announce`` gets a line before each step,
    ``report`` each :class:`StepResult` as soon as it is known.  ``clock_hz`` (for the expected
    move time) defaults to the chip's (:attr:`LM629.clock_hz`)."""
    o = options
    out = BringupReport()

    def done(step: StepResult) -> bool:
        out.steps.append(step)
        report(step)
        return step.ok is not False

    announce("reset check (AN-706 4.4.1)")
    if not done(reset_step(chip)):
        return out
    check_room(chip, o)  # before anything turns: the whole sequence inside the soft limits
    if not confirm(f"The motor will now turn (gentle steps of +/-{o.phasing_travel // 8} counts). "
                   "Is the shaft free to turn?"):
        done(StepResult("phasing", None, "skipped at your request: nothing moved"))
        return out
    with stop_on_error(chip):
        announce(f"loop phasing: P-only steps of +/-{o.phasing_travel // 8} counts (AN-706 2.12)")
        if not done(phasing_step(chip, o)):
            return out
        announce(f"hold at kp = {o.hold_kp}")
        if not done(hold_step(chip, o)):
            return out
        announce(f"small move: {o.move_distance:+d} counts")
        for step in move_steps(chip, o, clock_hz or chip.clock_hz, announce):
            if not done(step):
                return out
    done(next_steps(o))
    return out


def reset_step(chip: LM629) -> StepResult:
    """1. The reset check (AN-706 4.4.1), with every status byte read."""
    try:
        status, seen = reset_with_statuses(chip)
    except ResetError as exc:
        # name the wire, not only the bytes: the wiring check moves nothing (lm629_host.bench.wiring_check)
        wires = wiring_suspects(chip)
        return StepResult("reset", False, f"status bytes seen: {_hex(exc.statuses)}",
                          [f"wiring check: {w}" for w in wires] + [str(exc)],
                          {"statuses": list(exc.statuses), "wiring": wires})
    expected = "00, 84/C4, 80/C0" if chip.uses_reset_line else "84/C4, 80/C0"
    return StepResult("reset", True, f"status bytes seen: {_hex(seen)} (expected {expected})",
                      data={"statuses": seen, "status": int(status)})


def check_room(chip: LM629, o: BringupOptions) -> None:
    """The bring-up's targets, as absolute positions from where the desired position is now,
    against the axis's soft limits (``chip.limits``): the phasing steps' targets either way,
    then the small move.  ValueError naming the limit and the
    room left, before anything moves."""
    limits = getattr(chip, "limits", None)
    if limits is None or not limits.has_travel:
        return
    origin = chip.read_desired_position()
    step = max(8, o.phasing_travel // 8)  # the phasing steps' targets (tuning.check_phasing)
    points = [origin - step, origin + step, origin + o.move_distance]
    for point in (min(points), max(points)):
        try:
            limits.check_position(point, what="bring-up goes to")
        except ValueError as exc:
            lo, hi = limits.min, limits.max
            room = (f"{hi - origin:+d} counts up to max" if hi is not None else "") + \
                (", " if hi is not None and lo is not None else "") + \
                (f"{lo - origin:+d} down to min" if lo is not None else "")
            raise ValueError(
                f"{exc}: from {origin} it needs phasing steps of +/-{step} counts and "
                f"then a {o.move_distance:+d}-count move; room left from {origin}: {room}. "
                "Move the axis so that the room is there, or give a smaller move "
                "(`lm629 bringup --move N`)") from None


def phasing_step(chip: LM629, o: BringupOptions) -> StepResult:
    """2. The tuner's phasing check inside ``+/- phasing_travel`` counts
    (:func:`lm629_host.bench.phasing.check_phasing`, the one set of phasing rules): P-only steps of
    an eighth of it up and down, from a gain whose first output is 1/8 of full scale.  Its
    fault (RUNAWAY: reversed leads; STALL: a shaft that does not turn, or a load the drive
    cannot hold) has stopped the motor already; a load it saw and held is said so."""
    from lm629_host.bench.phasing import check_phasing  # the tuner loads on first use
    start = chip.snapshot()
    step = max(8, o.phasing_travel // 8)
    try:
        found = check_phasing(chip, travel=o.phasing_travel, time_s=o.phasing_time_s,
                              poll_s=o.poll_s)
    except MotionError as exc:
        note = getattr(exc, STOP_NOTE, None) or ""
        text = exc.detail
        if note and text.endswith(f"; {note}"):
            text = text[:-len(note) - 2]
        text = text.removeprefix("phasing: ")
        moved = None if exc.position is None else exc.position - start.real_position
        data: dict[str, object] = {"desired_moved": step, "real_moved": moved,
                                   "reason": str(exc.reason),
                "seconds": round(chip.clock.now() - start.time, 4)}
        if exc.reason is MotionError.RUNAWAY:
            return StepResult("phasing", False, f"RUNAWAY: {text}", [note], data)
        if exc.reason is MotionError.STALL and "did not turn" not in text:
            text = f"STALL: {text}"
        return StepResult("phasing", False, text, [note], data)
    way = "up" if found.pulled > 0 else "down"
    sagged = (f" (a load pulled it back first, {way}; the loop holds it at kp={found.kp})"
              if found.pulled else "")
    data = {
        "desired_moved": found.step, "real_moved": found.first_moved, "kp": found.kp,
        "followed": found.followed, "load": found.pulled,
        "seconds": round(chip.clock.now() - start.time, 4)}
    return StepResult("phasing", True,
                      f"the shaft follows: steps of {found.step:+d} and {-found.step:+d} counts "
                      f"at kp={found.kp}, the shaft followed {found.followed[0]:+d} and "
                      f"{found.followed[1]:+d}{sagged}", data=data)


def hold_step(chip: LM629, o: BringupOptions) -> StepResult:
    """3. Stop, then hold at ``hold_kp``: the shaft must rest inside the P-only dead band."""
    chip.load_trajectory(stop="abrupt", start=True)
    chip.load_filter(kp=o.hold_kp)
    chip.update_filter()
    chip.clock.sleep(o.hold_time_s)
    a = chip.snapshot()
    chip.clock.sleep(0.1)
    b = chip.snapshot()
    err = b.following_error
    data = {"following_error": err, "drift": b.real_position - a.real_position,
            "dead_band": o.dead_band}
    if abs(err) > o.dead_band or b.real_position != a.real_position:
        _ok, note = emergency_stop(chip)
        if b.real_position != a.real_position:
            hint = "the shaft is still moving: an oscillation (lower kp or add kd)"
        else:
            hint = ("a steady error beyond the dead band: a load torque or friction holds "
                    "the shaft off (add ki with a small il)")
        return StepResult(
            "hold", False,
            f"does not hold: error {err:+d} counts (dead band +/-{o.dead_band}), moved "
            f"{b.real_position - a.real_position:+d} counts in 0.1 s: {hint}", [note], data)
    return StepResult("hold", True, f"holds {err:+d} counts from the desired position "
                                    f"(dead band +/-{o.dead_band})", data=data)


def move_steps(chip: LM629, o: BringupOptions, clock_hz: float,
               announce: Callable[[str], None] = lambda text: None) -> Iterator[StepResult]:
    """4 and 5. The small move, watched by :class:`~lm629_host.chip.move.MoveWatch` with the dead
    band as tolerance and ``still_s`` as settle time: the "move" step when the trajectory has
    completed (or failed to in the profile's time plus ``settle_timeout_s``), then the
    "settle" step: the largest following error and the time from the trajectory's end to the
    start of the final rest inside the dead band."""
    origin = chip.snapshot().desired_position
    target = origin + o.move_distance
    p = plan(o.move_distance, o.move_velocity, o.move_acceleration)
    ramp_s, move_s = p.accel_seconds(clock_hz), p.seconds(clock_hz)
    rules = replace(chip.move_rules, tolerance=o.dead_band, settle_time=o.still_s,
                    settle_timeout=o.settle_timeout_s, poll=o.poll_s)
    # absolute: a relative position counts from the last target (the phasing move's), not
    # from where the abrupt stop left it.  move_to clears trajectory complete in the program
    # that starts the move, so only this move's completion counts
    move = chip.move_to(target, velocity=o.move_velocity, acceleration=o.move_acceleration)
    watch = move.watch(timeout=move_s + 2 * o.settle_timeout_s, rules=rules)
    complete_by = move.t0 + move_s + o.settle_timeout_s
    worst = 0
    s = move.start
    try:
        while True:
            chip.clock.sleep(o.poll_s)
            s = chip.snapshot()
            if abs(s.following_error) > abs(worst):
                worst = s.following_error
            completed = watch.complete_at is not None
            result = watch.check(s)
            if not completed and watch.complete_at is not None:
                took = watch.complete_at - move.t0
                yield StepResult("move", True,
                                 f"trajectory complete after {took:.3f} s (profile "
                                 f"{move_s:.3f} s, ramps {ramp_s:.3f} s)",
                                 data={"seconds": round(took, 4),
                                       "profile_s": round(move_s, 4), "ramp_s": round(ramp_s, 4)})
                announce("following error and settle time")
            if result is not None:
                break
            if watch.complete_at is None and s.time > complete_by:
                _ok, note = emergency_stop(chip)
                yield StepResult("move", False,
                                 f"the move did not complete in {move_s + o.settle_timeout_s:.2f} s "
                                 f"(profile {move_s:.2f} s); the shaft is at "
                                 f"{s.real_position - origin:+d} counts", [note])
                return
    except MotionError as exc:  # stopped already (MoveWatch)
        if watch.complete_at is None:
            yield StepResult("move", False, f"motion fault ({exc.reason}) during the move: "
                                            f"the shaft is at {exc.position - origin:+d} counts"
                             if exc.position is not None else
                             f"motion fault ({exc.reason}) during the move", [exc.detail])
            return
        final = target - (exc.position if exc.position is not None else s.real_position)
        yield StepResult("settle", False,
                         f"did not settle in {o.settle_timeout_s:g} s (error now {final:+d}, "
                         f"dead band +/-{o.dead_band}, largest following error {worst:+d}; "
                         "what was still wrong below): add kd for damping, or lower kp",
                         [getattr(exc, STOP_NOTE, None) or exc.detail],
                         {"max_following_error": worst, "final_error": final,
                          "dead_band": o.dead_band, "settle_s": None, "reason": str(exc.reason)})
        return
    t_done = watch.complete_at if watch.complete_at is not None else s.time  # done: completed
    settled_at = max(watch.quiet_since or s.time, t_done)
    final = target - s.real_position
    yield StepResult("settle", True,
                     f"largest following error {worst:+d} counts; settled "
                     f"{settled_at - t_done:.3f} s after the trajectory ended, "
                     f"{final:+d} counts from the target",
                     data={"max_following_error": worst, "final_error": final,
                           "dead_band": o.dead_band, "settle_s": round(settled_at - t_done, 4)})


def next_steps(o: BringupOptions) -> StepResult:
    """6. What to do next: the loop works, now tune it, with the room this move showed."""
    travel = o.move_distance
    return StepResult("next", None, f"the loop works; now tune it:  lm629 tune --travel {travel}", [
        f"lm629 tune --travel {travel} finds the gains (phasing, identification, design, then a "
        f"checked step and trapezoid move) inside +/-{travel} counts of where the shaft is now: "
        f"give it the room the axis has either way (this bring-up's move went "
        f"{o.move_distance:+d} counts)",
        "set a following-error limit that stops the motor:  lm629 limit 2000 --stop",
        f"the motor is left holding position at kp = {o.hold_kp}"])


__all__ = ["BringupOptions", "BringupReport", "StepResult", "run_bringup", "reset_with_statuses",
           "reset_step", "phasing_step", "hold_step", "move_steps", "next_steps"]
