"""The bridge's far side in Python, over a :class:`~lm629_host.sim.model.ChipModel`.

An independent implementation of what ``firmware_bridge/`` does, written from PROTOCOL.md:
it reads frames, answers HELLO and PING, runs RUN programs with the busy discipline against the
model's clock, keeps the last RUN's ``seq``/CRC/reply and answers a repeat from that cache.
It serves two benches that need no AVR toolchain:

* :class:`EmuPipe`, an in-process :class:`~lm629_host.bridge.protocol.Pipe` whose clock is the model's
  clock, with the serial wire's byte time at a chosen baud rate: the link tests and the fault
  tests run on it without ever sleeping on the wall clock;
* ``lm629 sim serve --pty PATH`` (:mod:`lm629_host.sim.serve`), where it answers a real
  pseudo-terminal in real time.

A package that mirrors the host link's parts (:mod:`lm629_host.transports`): :mod:`.link`
(frames, dispatch, the reply cache), :mod:`.runner` (programs on the model), :mod:`.failsafe`,
:mod:`.recorder`, :mod:`.profiles`, and :mod:`.pipe` (the in-process line).  The chip model knows
nothing of it; it only strobes the model's pins.
"""

from __future__ import annotations

from lm629_host.sim.bridge.link import EMU_FIRMWARE, MULTI_AXIS_INFO, ONE_CHIP_INFO, BridgeEmulator
from lm629_host.sim.bridge.pipe import EmuPipe, ModelClock
from lm629_host.sim.bridge.parts import EmuStats
from lm629_host.sim.bridge.runner import BUS_CYCLE_S, FIRMWARE_BUSY_TIMEOUT_S, HOST_LOOK_S, RESET_PULSE_S

__all__ = ["BridgeEmulator", "EmuPipe", "EmuStats", "ModelClock", "EMU_FIRMWARE", "BUS_CYCLE_S",
           "FIRMWARE_BUSY_TIMEOUT_S", "HOST_LOOK_S", "MULTI_AXIS_INFO", "ONE_CHIP_INFO",
           "RESET_PULSE_S"]
