"""The motor step: one sample of a shaft driven by a held drive against dry friction.

A DC motor with its armature inductance neglected, a viscous/back-EMF decay and dry
(Coulomb) friction obeys, between the sticking points of the friction,

    dw/dt = drive - coulomb sign(w) - rate w

with ``drive`` the acceleration the amplifier's held output gives, less any constant load.
That is linear, so one sample is integrated exactly (an exponential), not stepped: stable at
any sample time.  A shaft at rest stays stuck while ``|drive| <= coulomb``; a moving shaft
that the friction would turn round within the sample stops where its speed reaches zero and
sticks there.

The units are the caller's: the tuner's model runs in counts and samples (``dt = 1``), the
chip model's motor in counts and seconds.  Knowing nothing of the driver or of the chip model,
this is the one place the step is written in Python, and ``sample_c.h`` the one place in C,
for both compiled loops (the chip model's ``_fastloop.c`` and the tuner's predictor
``_predict.c``); the chip model's flattened Python loop (``sim/model/fastloop.py``) writes it
inline for speed.  ``tests/physics/test_plant.py`` checks the chip model's loops against
:func:`motor_step` bit for bit, ``tests/physics/test_predict_fast.py`` the C predictor against
the Python one that calls it.
"""

from __future__ import annotations

from math import exp, log


def decay_and_gain(rate: float, dt: float) -> tuple[float, float]:
    """The step's constants for a speed decay ``rate`` (per time unit) and a sample ``dt``:
    the speed's decay over a sample, ``exp(-rate dt)``, and its integral over the sample,
    ``(1 - decay) / rate`` (the distance a unit of speed above the final speed adds)."""
    decay = exp(-rate * dt)
    return decay, (1.0 - decay) / rate


def motor_step(x: float, w: float, drive: float, coulomb: float, rate: float, decay: float,
               gain: float, dt: float) -> tuple[float, float]:
    """(position, speed) after one sample of ``dt`` from ``x`` at speed ``w`` with ``drive``
    held (``decay`` and ``gain`` from :func:`decay_and_gain`).  A shaft stuck by the friction
    comes back as it went in: ``w == 0`` before and after."""
    if w == 0.0:
        if -coulomb <= drive <= coulomb:
            return x, w  # stuck: the drive does not break the dry friction
        force = drive - coulomb if drive > 0 else drive + coulomb
    else:
        force = drive - coulomb if w > 0 else drive + coulomb
    w_inf = force / rate
    w1 = w_inf + (w - w_inf) * decay
    if w != 0.0 and (w1 > 0) != (w > 0):
        # the dry friction stops the shaft within this sample: it sticks there
        return x + (w_inf * (-log(-w_inf / (w - w_inf)) / rate) + w / rate), 0.0
    return x + (w_inf * dt + (w - w_inf) * gain), w1


__all__ = ["decay_and_gain", "motor_step"]
