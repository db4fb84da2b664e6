"""The bundled software model of the LM628/LM629 (and of a motor and encoder).

The model knows nothing of the driver: it is driven one bus cycle at a time through
:class:`ChipModel`, by the ``sim://`` transport, the simavr harness or the emulated FT232H.

Modules: :mod:`.chip` (host interface and command decoder), :mod:`.motion` (what happens at
each sample), :mod:`.trajectory`, :mod:`.pid`, :mod:`.motor`, :mod:`.params` (every number),
:mod:`.fastloop` and ``_fastloop.c`` (the same sample loop flattened, for speed).

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
   "Observed on real chips").
4. The LM629 has no 12-bit port: PORT12 sent to an LM629 is refused with a command error.
5. Busy time after a command byte or a word (``ChipParams.busy_s``): the datasheet says
   typically 15-25 us, never more than 100 us; the model uses the middle of the typical range.
6. Reset time (``ChipParams.reset_s``): a hardware or software reset completes this long after
   /RST rises (or the RESET command is written); the datasheet only promises "within 1.5 ms".

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
    the original target is kept, so a plain STT resumes the move (AN-706 6.3.1).
13. STT refused (command error, nothing changes): acceleration loaded since the last STT while
    the generator is moving and the drive is on; a relative velocity or acceleration that makes
    the working value negative.  The refused STT is ignored and the parameters loaded since the
    last STT are dropped (signals bit 14 cleared): otherwise every later STT, even a stop, would
    be refused until the move ends.  Relative position is relative to the current target;
    relative velocity and acceleration to the working values.  A stop bit acts once: the next
    plain STT resumes the move (AN-706 6.3.1, 6.3.3).  The refusal (command-error bit) is
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
    cleared.  The next STT starts from the real position with velocity 0 and resumes the
    interrupted move (AN-706 6.3.3).
18. Turning the motor off (LTRJ bit 8, LPES) raises trajectory complete at once (status bit 2 =
    motor off OR on target).
19. Breakpoint: set at every sample where the desired position has reached the breakpoint,
    i.e. the breakpoint lies between the previous and the current desired position (the short
    way round the wraparound circle, so that a wrap does not sweep everything), so after reset
    (breakpoint 0, position 0) bit 6 reads 1 (C4 / C0).
20. Index: A, B and IN are all low together at exactly one count per revolution,
    ``MotorParams.index_offset`` counts past a multiple of 4 x lines; the index is seen if the
    encoder stood on that count at either sample or passed it in between
    (:meth:`.motor.Motor.index_between`).  SIP arms it; the latched value is the real position
    register at that count, INDEX_PULSE is raised and signals bit 0 cleared at that sample.

Filter, output and registers (:mod:`.pid`, :mod:`.motion`)

21. PID arithmetic: a 16 x 16 product that overflows 16 bits saturates to 7FFF / 8000 (AN-706
    5.2.5's "all the lower bits are set ... a predictable saturated output", read as signed
    saturation: a wrapped product would reverse the drive), as does the sum of the three terms;
    the derivative difference is saturated to 16 bits before kd; the 24-bit error sum
    saturates, and once the ki term has reached il (il = 0 included) an error that would push
    the sum further is not summed (AN-706 4.5.2); RDSUM reads the limited ki term; UDF keeps
    the error sum and the derivative memory.
22. The 8-bit output is the top byte of u by arithmetic shift (floor): e = -1 at kp = 20 gives
    -1, e = +1..12 gives 0, so a P-only loop rests 0..12 counts short of its target, never past
    it.
23. RDRV is the change of the real position over the last sample (whole counts).

Motor, amplifier and encoder (:mod:`.motor`, ``MotorParams``)

24. The amplifier (``MotorParams.amp_volts``: volts across the motor at full-scale output) is
    linear, with no dead band and no current limit.
25. The motor's numbers (the ``MotorParams`` defaults) are a plausible small brushed motor with
    a light load, chosen so that the AN-706 2.12 bring-up (kp = 20, acceleration and velocity
    about 100, a 1000-count move) settles within a few counts of the target and reversed leads
    at kp = 1 run away within a fraction of a second; the armature inductance is neglected
    (tau_e << T) and the shaft starts mid-count (``start_position``) so that the encoder does
    not sit on an edge.
26. The encoder's 1 M counts/s limit is not modelled; the motor cannot get near it with the
    default parameters.
"""

from .chip import ChipModel
from .params import ChipParams, MotorParams

__all__ = ["ChipModel", "ChipParams", "MotorParams"]
