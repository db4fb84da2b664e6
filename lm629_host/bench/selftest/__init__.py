"""``lm629 selftest``: is this chip and this board what the profile says, and where does the
model differ from silicon (docs/selftest.md says what each check proves).

Why: everything the project knows about the LM629 comes from documents and a model.  A bench
whose crystal is not the profile's makes every velocity and time wrong without an error; an HI
or index line that is not wired makes interrupts and homing wait for ever.  The selftest runs a
fixed script, motor off unless ``motion``:

* **core**: the same command sequence on the chip and, in lockstep, on a fresh chip model
  (a ``sim://`` transport with the profile's chip and clock); every read is compared.  Reads
  that change with time are taken at a known *chip* time: the desired position of a slow
  velocity-mode or cruising run (filter gains 0, so nothing drives the motor) is the chip's
  own clock, so the model is run to the same desired position before its reads, and a late
  host makes no false difference;
* **clock**: the sample period against the transport's clock (the bridge's timer stamps of a
  recording, the simulated clock, the host's clock on an FT232H), over :data:`CLOCK_RUN_S`:
  the median of many slopes, so that a paused host moves no figure;
* **wiring**: HI seen on a breakpoint interrupt, the chip selects of the profile's axes
  answering, and with ``motion`` the encoder counting and the index pulse;
* **busy**: the busy time after each of :data:`BUSY_COMMANDS`' command bytes, as far as the
  transport shows it (a far-side wait, then a status read), in the form ``sim://?busy=``
  takes, so the model can take what a chip shows.

The report (:class:`Report`) holds every measurement with the model's expected value; its JSON
form is :data:`SCHEMA` (checked by :func:`validate`), and :func:`compare` shows a saved report
against today's model.

The parts, by job: :mod:`.report` (the findings and their files), :mod:`.lockstep` (the chip
and the model driven alike, at one chip time), :mod:`.checks` (the script, check by check),
:mod:`.runner` (:func:`run` and :func:`compare`).  Every public name is importable from here.
"""

from lm629_host.bench.selftest.checks import (
    BREAKPOINT_AT,
    BUSY_COMMANDS,
    CLOCK_ROWS,
    CLOCK_RUN_S,
    CRUISE_TO,
    INDEX_AT_REST,
    INDEX_PROBE_SAMPLES,
    index_at_rest,
    latch_wait_us,
)
from lm629_host.bench.selftest.lockstep import CHIP_RATE_MAX, PLATEAU_SAMPLES, SLOW, Item, Lockstep
from lm629_host.bench.selftest.report import (
    CLOCK_TOLERANCE,
    EXIT,
    SCHEMA,
    SCHEMA_VERSION,
    Fault,
    Measurement,
    Report,
    load_report,
    summary_markdown,
    validate,
    worst,
    write_report,
)
from lm629_host.bench.selftest.runner import Options, compare, reference, run

__all__ = ["BREAKPOINT_AT", "BUSY_COMMANDS", "CHIP_RATE_MAX", "CLOCK_ROWS", "CLOCK_RUN_S",
           "CLOCK_TOLERANCE", "CRUISE_TO", "EXIT", "Fault", "INDEX_AT_REST", "INDEX_PROBE_SAMPLES",
           "Item", "Lockstep", "Measurement", "Options", "PLATEAU_SAMPLES", "Report", "SCHEMA",
           "SCHEMA_VERSION", "SLOW", "compare", "index_at_rest", "latch_wait_us", "load_report",
           "reference", "run", "summary_markdown", "validate", "worst", "write_report"]
