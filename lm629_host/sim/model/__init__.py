"""The bundled software model of the LM628/LM629 (and of a motor and encoder).

The model knows nothing of the driver: it is driven one bus cycle at a time through
:class:`ChipModel`, by the ``sim://`` transport, the simavr harness or the emulated FT232H.

Modules: :mod:`.chip` (host interface and registers), :mod:`.commands` (what a finished command
does: LTRJ, LFIL, STT, interrupts, reads), :mod:`.motion` (what happens at each sample),
:mod:`.trajectory`, :mod:`.motor`, :mod:`.params` (every number), :mod:`.fastloop` and
``_fastloop.c`` (the same sample loop flattened, for speed).  The PID filter's arithmetic is
the driver's :mod:`lm629_host.physics.pid` (the tuner and the step plot use it too).

Model choices
=============
Every place where the datasheet and the notes (``shared/spec/lm628-lm629-reference.md``) are
silent and the model had to choose, in this one list; ``[model choice N]`` in the code and in
the other modules' docstrings refers to item N here.  A choice that is a number keeps its
number in :mod:`.params` (the field is named here), so that it can be changed in one place
when someone measures a real chip.

Host interface (:mod:`.chip`)

1. A strobe that the chip ignores (busy) does not advance the byte phase.  (A write while busy
   is ignored and a read while busy returns the stale byte of the I/O register, neither
   setting the command-error bit: that part is the spec.)
2. A data byte with no command expecting one, and an unknown opcode, set the command-error
   bit, as a data transfer in the wrong direction does; the transfer is ignored.
3. After the RESET command busy stays set until the reset completes (see the spec's
   "Observed on real chips").  Its duration is ``ChipParams.reset_s`` (choice 6), so a host's
   busy poll after RESET must last 1.5 ms: a poll bounded by 5000 reads at 250 ns (1.25 ms)
   outlasts the model's default 1 ms but not the documented worst case.
4. The LM629 has no 12-bit port: PORT12 sent to an LM629 is refused with a command error
   (not a host protocol violation: ``lm629 selftest`` sends it, motor off, to tell an LM628
   from an LM629; a driver's normal operation never does).
5. Busy time after a command byte or a word (``ChipParams.busy_s``): the datasheet says
   typically 15-25 us, never more than 100 us; the model uses the middle of the typical range.
6. Reset time (``ChipParams.reset_s``, default 1 ms; ``sim://?reset_s=0.0015`` is the
   documented worst case): a hardware or software reset completes this long after /RST rises
   (or the RESET command is written); the datasheet only promises "within 1.5 ms".

Trajectory generator (:mod:`.motion`, :mod:`.trajectory`)

7. Deceleration point: at each sample the generator picks the largest velocity (within +/- one
   acceleration step of the last one, and not above the programmed maximum) from which a ramp
   down at the acceleration still stops on or before the target; when none does, it takes the
   velocity whose ramp ends *exactly* on the target (see
   :func:`.trajectory.landing_velocity`).  The profile is therefore symmetric to within one
   sample, never undershoots and ends exactly on the target; the spec's v^2/(2a) is the
   continuous limit of the same rule.
8. The desired position's 16-bit fraction is kept; only the whole counts (floor) reach the
   summing junction and RDDP.
9. Positions live modulo 2^31 counts in C0000000..3FFFFFFF; a position-mode move goes the
   short way round that circle, so a relative move across the wraparound boundary works;
   WRAPAROUND (status bit 4) is raised when the *desired* position crosses it, either way.  The
   real position register wraps the same way (without a flag).
10. A target moved on the fly to a point the ramp can no longer stop before is overshot at the
    programmed deceleration and approached again from the other side.
11. Acceleration 0: the velocity cannot change, so a move never starts and the generator never
    reports on-target.
12. Stop abruptly: velocity 0 at once, the desired position held where it is; stop smoothly:
    ramp down at the acceleration.  Both report on-target (trajectory complete) when stopped;
    the original target, mode, direction and parameters are kept, so a plain STT resumes the
    move, in velocity mode too (AN-706 6.3.1; see 27).
13. STT refused (command error): acceleration loaded since the last accepted
    STT while the generator is moving and the drive is on (see 28); a velocity or acceleration
    that would come out negative or above 3FFFFFFF (see 30).  The refused STT is ignored: the
    input buffer keeps everything loaded since the last accepted STT (signals bit 14 stays
    set) for the next STT that can execute it (AN-706 3.3: "can be loaded ... but cannot be
    executed by the STT command until the trajectory has completed or the drive to the motor
    is turned off"; the double-buffered input registers, and "the command ignored", leave
    nothing to drop).  The one exception is the value that came out of range: AN-706 6.6.6
    puts that error "when loading" the value, so it counts as never loaded (otherwise one bad
    relative velocity would get every later STT, even a stop, refused).  So while an
    acceleration change is pending during a move, every STT but a motor-off one is refused
    until the move completes.  A stop bit acts once.  The refusal (command-error bit) is
    raised while the chip processes the STT byte, so it is visible once busy clears
    (``LM629.start`` reads it there).
14. A stop bit with other parameters in the same LTRJ: the stop wins and the parameters are
    loaded into the working registers for the next STT (no movement now).
15. DFH: the desired position's whole counts and the real position both become 0 at once; the
    target moves by the desired position's counts, so the move still ends at the same place
    relative to the desired position (AN-706 6.4.1).
16. After a reset the generator is idle but not "on target" (signals bit 10 clear: the
    published run reads 01C0 after reset, and 8544 once a move has ended); the status's
    trajectory-complete bit after reset comes from the motor being off.

Motor off and the chip's events (:mod:`.motion`, ``ChipModel._sample``)

17. Motor off (LTRJ bit 8 or LPES): output 0 (LM628 DAC code 80/800, LM629 PWM magnitude 0:
    the amplifier applies 0 V, which brakes through the back EMF); the desired position follows
    the real one each sample (AN-706 6.3.2) and the filter's memory (error sum, derivative) is
    cleared.  The next STT starts from the real position with velocity 0; a plain STT resumes
    an interrupted trajectory or holds the shaft where it is (AN-706 6.3.3; see 27).
18. Turning the motor off (LTRJ bit 8, LPES) raises trajectory complete at once (status bit 2 =
    motor off OR on target).
19. Breakpoint: set at every sample where the desired position has reached the breakpoint,
    i.e. the breakpoint lies between the previous and the current desired position (the short
    way round the wraparound circle, so that a wrap does not sweep everything), so after reset
    (breakpoint 0, position 0) bit 6 reads 1 (C4 / C0).  The condition is level-held: an RSTI
    that clears bit 6 while the desired position sits on the breakpoint leaves it reading 1 at
    once (a real LM629 read C0, three reads of three, ~78 us after RSTI 0000 following a reset;
    with the bit back only at the next sample that would read 80 about 70 % of the time).
20. Index: A, B and IN are all low together at exactly one count per revolution,
    ``MotorParams.index_offset`` counts past a multiple of 4 x lines; the index is seen if the
    encoder stood on that count at either sample or passed it in between
    (:meth:`.motor.Motor.index_between`).  SIP arms it; the latched value is the real position
    register at that count, INDEX_PULSE is raised and signals bit 0 cleared at that sample.
    By default (``index_offset`` unset) the index is half a revolution (2 x lines counts) from
    where the shaft powers up: reachable within half a turn either way, never under the shaft
    at start, so a SIP without motion latches nothing (an index under the shaft would latch
    at the first sample, which no real index search sees).

Filter, output and registers (:mod:`lm629_host.physics.pid`, :mod:`.motion`)

21. PID arithmetic: a 16 x 16 product that overflows 16 bits saturates to 7FFF / 8000 (AN-706
    5.2.5's "all the lower bits are set ... a predictable saturated output", read as signed
    saturation: a wrapped product would reverse the drive), as does the sum of the three terms;
    the derivative difference is saturated to 16 bits before kd; the 24-bit error sum
    saturates, and once the ki term has reached il (il = 0 included) an error that would push
    the sum further is not summed (AN-706 4.5.2); RDSUM reads the limited ki term; UDF keeps
    the error sum and the derivative memory.
22. The 8-bit output is the top byte of u by arithmetic shift (floor): e = -1 at kp = 20 gives
    -1, e = +1..12 gives 0.  The dead band is one-sided: any negative error (real above the
    target) still drives down at 1/128, a positive one below 256/kp does not drive at all.  So
    a P-only loop at kp = 20 rests with the real position 0..12 counts *below* its target
    whichever way it came: short of it after a move up, up to 12 counts past it after a move
    down (a move from 1000 down to 0 rests at -11, e = +11).
23. RDRV is the change of the real position over the last sample (whole counts).

Motor, amplifier and encoder (:mod:`.motor`, ``MotorParams``)

24. The amplifier (``MotorParams.amp_volts``: volts across the motor at full-scale output) is
    linear, with no dead band and no current limit.
25. The motor's numbers (the ``MotorParams`` defaults) are a plausible small brushed motor with
    a light load, chosen so that the AN-706 2.12 bring-up (kp = 20, acceleration and velocity
    about 100, a 1000-count move) settles within a few counts of the target and reversed leads
    at kp = 1 run away within a fraction of a second; the armature inductance is neglected
    (tau_e << T) and the shaft starts mid-count (``start_position``) so that the encoder does
    not sit on an edge (and half a revolution from the index: 20).
26. The encoder's 1 M counts/s limit is not modelled; the motor cannot get near it with the
    default parameters.

Restarts, buffered parameters, ranges, reset

27. Mode of a restart.  An LTRJ with a stop bit only stops: its bits 11/12 do not replace the
    running trajectory's mode; any LTRJ without a stop bit sets the mode (and cancels a stop
    loaded but not yet started).  A plain STT therefore restarts with the mode, direction and
    parameters of the trajectory that was running: after a smooth or abrupt stop (AN-706
    6.3.1: "restart the trajectory toward the original target") and after motor off in the
    middle of a trajectory or of a stop (6.3.3: "restart and move to the target position in
    position mode, or resume movement in velocity mode").  After motor off once the last
    trajectory had *completed* (or after a reset, before any move), STT makes the current
    position the target (6.3.3: "the motor will be held in the current position"); a position
    loaded with that STT still counts (relative ones from there).  "Completed" is the
    generator finishing a move by itself; a stop leaves the trajectory resumable.
28. An STT whose own stop bit is 8 (motor off) is executed even with an acceleration change
    pending during a move: it turns the drive off, the condition AN-706 3.3 names for
    executing the acceleration, and without it a velocity-mode move with a pending change
    could never be stopped.  Smooth and abrupt stops are refused like any STT then (drive on).
29. Relative values are relative to "those previously loaded" (AN-706 3.3): to the value
    loaded by an earlier LTRJ not yet started, else to the working value (relative position:
    to the current target).  Two relative LTRJs before one STT therefore add up (velocity
    V + X1 + X2, not X2 alone; positions likewise); absolute then
    relative gives the absolute plus the relative.  The reading "loaded" = written by LTRJ (not yet executed)
    follows 3.3's own use of the word ("can be loaded with LTRJ ... but cannot be executed").
30. Velocity and acceleration words are 30-bit unsigned (AN-706 2.7: bit 31 would be the sign,
    bit 30 detects overflow): an absolute word above 3FFFFFFF makes the STT that would execute
    it refused with a command error and ignored (the word dropped: 13), as for a relative
    value that would make the velocity negative (6.5.1: "a negative absolute velocity which is
    not allowed"; FDF0A3D8, what AN-868's program sends when its clock scalar overflows, is
    negative as a 32-bit word).  The same for a relative sum outside 0..3FFFFFFF.  The word itself is a host
    protocol violation (``strict`` raises at the LTRJ); it is not clamped, which would hide
    the host's mistake.
31. Through /RST and the RESET command the motor and encoder go on: the output is zero drive
    from the moment the reset begins and the shaft coasts (or is driven by its load); only the
    chip's registers, trajectory and filter wait.  When the reset completes, wherever the
    shaft then is becomes real position 0.

Several chips on one bus (:mod:`.bus`)

32. The chips of one :class:`ChipBus` share one clock and one /RST, so they sample at the same
    ticks (a real board shares the oscillator; after one /RST their sample counts agree).  A
    strobe on a /CS line with no chip on it reaches nothing, and a read there finds the data
    bus floating: it reads FF (busy set), so a host's busy check times out on an unwired axis,
    as it would on a bench with pull-ups on the data bus.

Test aids and update rate

33. ``ChipParams.reset_position`` (``sim://?reset_position=0x3FFFF000``, default 0): the
    position registers (desired, real, target) read this after every reset instead of 0, so
    that a test reaches the wraparound (AN-706 6.5.2) without minutes of simulated travel.  A
    real chip always resets them to 0; DFH still makes them 0.
34. The command update rate (AN-706 4.6.2: "aborts the current trajectory calculation when it
    receives a new STT command, resulting in the output staying at the value of the previous
    sample ... not ... more than once every 10 ms").  The note gives no duration for the
    calculation; the model takes the 10 ms it recommends (``ChipParams.update_s``): an STT
    executed less than ``update_s`` after the last executed one aborts the calculation in
    progress, and the output word at the next sample stays at the previous sample's value (the
    filter is not run for that sample; the trajectory generator steps with the new parameters
    as usual, since the note names only the output).  Under ``strict`` such an STT is a host
    protocol violation, unless it carries a stop or motor-off bit: stopping must always be
    possible, and a one-sample hold does not delay a stop.
"""

from lm629_host.sim.model.bus import ChipBus, chips_of
from lm629_host.sim.model.chip import ChipModel, Violation
from lm629_host.sim.model.params import ChipParams, MotorParams

__all__ = ["ChipBus", "chips_of", "ChipModel", "ChipParams", "MotorParams", "Violation"]
