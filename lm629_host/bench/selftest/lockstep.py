"""The chip and the model driven alike: a step's items as one bus program on each
(:func:`_program`), its reads decoded (:func:`_values`) and compared (:class:`Lockstep`), and
the reads that change with time taken at one *chip* time on both (:meth:`Lockstep.timed`:
the desired position of a slow run is the chip's own clock).

Why a module of its own: this is the instrument, the same for every check of the script
(:mod:`.checks`), and what a test drives step by step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from lm629_host.bus.opcodes import (
    BUSY_BIT,
    COMMANDS,
    FIXED_ONE,
    SAMPLE_CLOCKS,
    Cmd,
    s32_words,
)
from lm629_host.bus.program import Op, Program, ProgramResult
from lm629_host.chip.lm629 import LM629
from lm629_host.errors import LM629Error
from lm629_host.bench.selftest.report import Measurement

#: the time base of the timed reads: 1/16 count per sample, so that the desired position
#: holds each whole count for 16 samples (4 ms at 8 MHz), longer than any one bus program
SLOW = FIXED_ONE // 16


#: how many samples of one whole count of the desired position the model is searched for the
#: chip's reads (four of the 16-sample counts, or as long after the end of a move)
PLATEAU_SAMPLES = 64


#: how many times the profile's sample rate a chip may run at when the model is run to the
#: chip's desired position: a chip clocked up to twice the profile's (a 6 MHz profile on an
#: 8 MHz chip is 1.33) is still caught up with; a desired position further on than that
#: since the STT is not where the model's time leads (the chip's differs), and the model is
#: compared where that time left it instead of being run to it (2^30 counts at 1/16 count a
#: sample would be hours of model time)
CHIP_RATE_MAX = 2.0


_READ_SIGNED16 = (Cmd.RDRV, Cmd.RDSUM)


#: a step's items: ("w", Cmd, *words) a command with its words; ("r", Cmd) a read command;
#: ("s",) the status once busy is clear; ("t", us) a far-side wait of at least ``us``
#: microseconds; ("p", builder) a program piece built from the chip
Item = tuple[Any, ...]


def words_of(cmd: Cmd) -> int:
    return COMMANDS[cmd].words


def _program(chip: LM629, items: Sequence[Item]) -> tuple[Program, list[tuple[str, str]]]:
    """The step as one bus program, and (label, command text so far) of each value read."""
    p = chip.program()
    labels: list[tuple[str, str]] = []
    said: list[str] = []
    for item in items:
        kind = item[0]
        if kind == "w":
            p.command(item[1])
            for w in item[2:]:
                p.write(w)
            said.append(" ".join([item[1].name, *(f"{w:04X}" for w in item[2:])]))
        elif kind == "r":
            p.command(item[1]).read(words_of(item[1]))
            said.append(item[1].name)
            labels.append((item[1].name, "; ".join(said)))
        elif kind == "s":
            p.sync()
            labels.append(("status", "; ".join(said) or "RDSTAT"))
        elif kind == "t":
            p.wait(item[1])
            said.append(f"wait {item[1]} us")
        else:
            piece: Program = item[1](chip)
            p.extend(piece)
            said.append(_render(piece))
    return p, labels


def _render(piece: Program) -> str:
    out: list[str] = []
    for o in piece.ops:
        if o.op is Op.COMMAND:
            out.append(Cmd(o.arg).name)
        elif o.op is Op.WRITE and out:
            out[-1] += f" {o.arg:04X}"
    return "; ".join(out)


def _values(items: Sequence[Item], result: ProgramResult) -> list[int]:
    """The values a step read, in its labels' order (32-bit reads as signed counts)."""
    words = iter(result.words)
    statuses = iter(result.statuses)
    out = []
    for item in items:
        if item[0] == "r":
            n = words_of(item[1])
            ws = [next(words) for _ in range(n)]
            if n == 2:
                out.append(s32_words(ws[0], ws[1]))
            elif item[1] in _READ_SIGNED16:
                out.append(ws[0] - 0x10000 if ws[0] & 0x8000 else ws[0])
            else:
                out.append(ws[0])
        elif item[0] == "s":
            out.append(next(statuses) & ~BUSY_BIT)
    return out


class Lockstep:
    """The chip and the model, the same steps on both.  ``chip`` None: the model alone,
    replaying the chip times of a saved report (``replay``: name -> measurement)."""

    def __init__(self, chip: LM629 | None, model: LM629,
                 replay: dict[str, Measurement] | None = None) -> None:
        self.chip = chip
        self.model = model
        self.replay = replay or {}
        self.out: list[Measurement] = []
        self._stt_sample = 0
        self._stt_time = 0.0  #: the chip's clock at the last STT

    def sides(self) -> list[LM629]:
        return [self.model] if self.chip is None else [self.chip, self.model]

    def pause(self, seconds: float) -> None:
        """Let time pass on both (the 10 ms between two STTs, AN-706 4.6.2)."""
        for side in self.sides():
            side.clock.sleep(seconds)

    def _record(self, name: str, labels: list[tuple[str, str]], got: list[int] | None,
                want: list[int], at: int | None = None, sample: int | None = None) -> None:
        for k, (label, command) in enumerate(labels):
            unit = "counts" if label in ("RDDP", "RDRP", "RDIP") else "hex"
            self.out.append(Measurement("core", f"{name}: {label}", command,
                                        None if got is None else got[k], want[k], at, sample,
                                        unit=unit))

    def step(self, name: str, items: Sequence[Item]) -> list[int]:
        """Run ``items`` on both; every read compared.  Returns the model's values."""
        got = None
        if self.chip is not None:
            program, labels = _program(self.chip, items)
            got = _values(items, self.chip.run(program))
        program, labels = _program(self.model, items)
        want = _values(items, self.model.run(program))
        self._record(name, labels, got, want)
        return want

    def started(self) -> None:
        """An STT just went to both: the model's samples count from here."""
        self._stt_sample = self._samples()
        if self.chip is not None:
            self._stt_time = self.chip.clock.now()

    def _samples(self) -> int:
        return int(self.model.clock.now() * self.model.clock_hz) // SAMPLE_CLOCKS

    def _bracketed(self, chip: LM629, items: Sequence[Item]) -> tuple[int, list[int], bool | None]:
        """``items`` between two RDDP reads, until both read the same whole count (no sample
        boundary changed the time base in between): (desired position, values, HI)."""
        whole = [("r", Cmd.RDDP), *items, ("r", Cmd.RDDP)]
        for _attempt in range(8):
            program, _labels = _program(chip, whole)
            result = chip.run(program)
            values = _values(whole, result)
            if values[0] == values[-1]:
                return values[0], values[1:-1], result.hi
        raise LM629Error("the desired position changed within every one of 8 bracketed reads: "
                         "the time base is not slow enough for this adapter")

    def _run_model_to(self, at: int, per_sample: float, most: float) -> None:
        """Run the model to the first sample at which its desired position reads ``at``: in
        strides that end at least a count short (at most ``per_sample`` counts a sample),
        then a sample at a time; no further than ``most`` samples since the STT (where the
        chip could have got by then: a chip that reads further on differs)."""
        period = SAMPLE_CLOCKS / self.model.clock_hz
        for _ in range(100_000):
            gap = at - self.model.read_desired_position()
            left = most - (self._samples() - self._stt_sample)
            if gap <= 0 or left < 1:
                return
            stride = min(int((gap - 1) / per_sample), int(left))
            if stride > 1:
                self.model.clock.sleep(stride * period)
            else:
                self._next_sample(period)
        raise LM629Error(f"the model never reached the desired position {at}")

    def _next_sample(self, period: float) -> None:
        """Run the model just past its next sample (a bracketed read lasts less than a
        sample, so the next one then reads that sample alone)."""
        now = self.model.clock.now()
        self.model.clock.sleep((math.floor(now / period) + 1.05) * period - now)

    def timed(self, name: str, items: Sequence[Item], *, per_sample: float,
              hi: bool = False) -> tuple[list[int], bool | None, bool | None]:
        """``items`` at one chip time on both: read on the chip, then on the model run to
        the same desired position.  The chip may have been read at any sample of that whole
        count (16 of them at 1/16 count a sample, or any time after the end of a move, if
        the host was late): the model is compared at the first of those samples whose reads
        are the chip's, else at the first.  Returns the model's values and HI on chip and
        model."""
        _unused, labels = _program(self.model, items)
        got: list[int] | None = None
        chip_hi: bool | None = None
        period = SAMPLE_CLOCKS / self.model.clock_hz
        most = math.inf
        if self.chip is not None:
            at, got, chip_hi = self._bracketed(self.chip, items)
            most = (self.chip.clock.now() - self._stt_time) / period * CHIP_RATE_MAX
        else:
            saved = self.replay.get(f"{name}: RDDP")
            at = saved.at if saved is not None and saved.at is not None else 0
            if saved is not None and saved.sample is not None:
                most = saved.sample
            kept = [self.replay.get(f"{name}: {label}") for label, _ in labels]
            got = [m.measured for m in kept if m is not None] if all(kept) else None
        self._run_model_to(at, per_sample, most + PLATEAU_SAMPLES)
        plateau: list[tuple[int, list[int], bool | None, int]] = []
        for _ in range(PLATEAU_SAMPLES):
            at_model, want, model_hi = self._bracketed(self.model, items)
            reading = (at_model, want, model_hi, self._samples() - self._stt_sample)
            if at_model != at:  # the model left (or never reached) the chip's whole count
                break
            plateau.append(reading)
            if got is None or want == got:
                break
            self._next_sample(period)
        if plateau and (got is None or plateau[-1][1] != got):
            reading = plateau[0]  # no sample matched: the differences are shown at the first
        elif plateau:
            reading = plateau[-1]
        at_model, want, model_hi, sample = reading
        self._record(name, [("RDDP", "RDDP"), *labels],
                     None if got is None or self.chip is None else [at, *got],
                     [at_model, *want], at, sample)
        if hi:
            self.out.append(Measurement("wiring", f"{name}: HI pin", "HI after the reads",
                                        chip_hi, model_hi, at, sample,
                                        judged=chip_hi is not None))
        return want, chip_hi, model_hi


__all__ = ["CHIP_RATE_MAX", "Item", "Lockstep", "PLATEAU_SAMPLES", "SLOW", "words_of"]
