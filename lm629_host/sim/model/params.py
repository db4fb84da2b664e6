"""Parameters of the simulated chip, motor and encoder, settable from a ``sim://`` URL.

Every model choice that is a number lives here, so that it can be changed in one place when
someone measures a real chip; the choices themselves, with their reasons, are listed in one
place, the docstring of :mod:`lm629_host.sim.model` (``[model choice N]`` below is item N there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lm629_host.bus.opcodes import UPDATE_INTERVAL_S


@dataclass
class ChipParams:
    variant: str = "lm629"  #: "lm628" or "lm629"
    clock_hz: int = 8_000_000  #: 1-8 MHz (-8 parts), 1-6 MHz (-6 parts)
    #: [model choice 5] busy time after a command byte or a word
    busy_s: float = 20e-6
    #: busy time after the command byte of the commands named, seconds, in place of
    #: ``busy_s`` (``sim://?busy=LTRJ:24.5,STT:31``, in us: a chip's measured busy times, as
    #: ``lm629 selftest`` reports them); the data words keep ``busy_s``
    command_busy_s: dict[int, float] = field(default_factory=dict)
    #: [model choice 6] a reset completes this long after /RST rises or RESET is written
    reset_s: float = 1.0e-3
    strict: bool = False  #: raise ProtocolViolation on any host protocol violation
    #: None, "reset" (never leaves reset), "busy" (busy stuck high) or "rst" (/RST not connected)
    fault: str | None = None
    record: bool = False  #: keep a record of every command that reached the chip (fault tests)
    #: how many of the latest commands the record keeps (``ChipModel.history``: a bounded window)
    record_window: int = 10_000
    #: the sample loop: "auto" (the C loop if it was built, else "py"), "c", "py" (the
    #: flattened loop of sim/model/fastloop.py) or "0" (only the readable per-sample code)
    fast: str = "auto"
    #: [model choice 33] the position registers after a reset (counts; a test near the wrap)
    reset_position: int = 0
    #: [model choice 34] an STT this soon after the last executed one aborts the trajectory
    #: calculation (AN-706 4.6.2's 10 ms)
    update_s: float = UPDATE_INTERVAL_S
    #: HI (pin 17) connected to the adapter; False (``wiring=hi-open``): the adapter reads it
    #: low whatever the chip raises (the registers still show the interrupt)
    hi_wired: bool = True


@dataclass
class MotorParams:
    """A small bench DC motor (12 V, ~4500 rpm no-load) with a 500-line encoder.

    SI units throughout; :mod:`.motor` uses them.  Why these numbers: [model choice 25].
    """

    lines: int = 500  #: encoder lines per revolution (4x decoding: 4 * lines counts/rev)
    reversed: bool = False  #: motor leads swapped: positive drive turns the shaft backwards
    #: counts from the zero of the revolution to the index pulse; None: half a revolution
    #: (2 x lines), away from the shaft at power-on but within reach [model choice 20]
    index_offset: int | None = None
    #: the index channel (IN, pin 1) connected; False (``wiring=index-open``): never latched
    index_wired: bool = True
    #: the A and B channels (pins 2, 3) connected; False (``wiring=encoder-open``): the chip's
    #: count never changes whatever the shaft does
    encoder_wired: bool = True
    #: amplifier gain: volts across the motor at full-scale output (PWM duty 128/128 or the
    #: DAC's full scale); [model choice 24] linear
    amp_volts: float = 12.0
    resistance: float = 4.0  #: armature resistance, ohm (inductance neglected: tau_e << T)
    torque_constant: float = 0.025  #: N m / A; the back-EMF constant is the same in SI units
    inertia: float = 4e-6  #: rotor + load, kg m^2
    friction: float = 2e-6  #: viscous friction, N m s / rad
    coulomb: float = 2e-4  #: Coulomb (dry) friction, N m; also the breakaway torque
    load_torque: float = 0.0  #: constant external torque (gravity on an arm...), N m
    stall: bool = False  #: rotor locked: the shaft never turns whatever the drive
    #: physical shaft angle at power-on, in counts: mid-count [model choice 25]
    start_position: float = 0.5
    #: The plant as ``lm629 tune``/``identify`` identify it (``[axis.NAME.plant]`` of a
    #: profile, :mod:`lm629_host.bench.twin`), in place of the SI numbers above where given: what a
    #: fit of the shaft's motion can tell, where inertia, torque constant and resistance
    #: cannot be told apart.  ``accel``: counts/s^2 at full-scale output with the shaft at
    #: rest; ``tau``: the mechanical time constant, s (the speed's decay, back-EMF and viscous
    #: friction together); ``dry`` and ``load``: the dry friction and a constant load, as
    #: fractions of full-scale output (``load`` > 0 pulls towards fewer counts).  Mapping onto
    #: the SI parameters: docs/model.md.
    accel: float | None = None
    tau: float | None = None
    dry: float | None = None
    load: float | None = None

    def check(self) -> None:
        """ValueError naming any parameter outside its physical range."""
        if self.lines < 1:
            raise ValueError(f"lines={self.lines}: an encoder has at least 1 line per revolution")
        for name in ("amp_volts", "resistance", "torque_constant", "inertia"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name}={value}: must be > 0")
        for name in ("friction", "coulomb"):
            value = getattr(self, name)
            if value < 0:
                raise ValueError(f"{name}={value}: must be >= 0")
        for name in ("accel", "tau"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name}={value}: must be > 0")
        if self.dry is not None and not 0 <= self.dry < 1:
            raise ValueError(f"dry={self.dry}: a fraction of full-scale output, 0..1")
        if self.load is not None and not -1 < self.load < 1:
            raise ValueError(f"load={self.load}: a fraction of full-scale output, -1..1")
