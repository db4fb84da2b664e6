"""The chip model's flattened sample loops as a bare filter, for the tests that check other
code (:mod:`lm629_host.physics.pid`, the tuner's predictor) against them: the loops are the model's
fast path, written apart from :mod:`lm629_host.physics.pid`, so they are an independent reference."""

from __future__ import annotations

from lm629_host.physics.pid import output_shift
from lm629_host.sim.model import fastloop

try:
    from lm629_host.sim.model import _fastloop
    LOOPS = {"py": fastloop.py_loop, "c": _fastloop.run}
except ImportError:  # no C compiler when the package was installed (as test_model_fastloop)
    LOOPS = {"py": fastloop.py_loop}


def loop_filter(loop, errors, kp, ki, kd, il, ds, twelve):
    """``errors`` through one of the model's flattened loops, one sample per call: the shaft
    stalled at 0 (so the error is the desired position), the trajectory idle; the filter's
    memory carried from call to call.  Returns (u, output code, memory) at each sample."""
    mem = dict(esum=0, elast=0, dterm=0, countdown=0, iterm=0, u=0)
    out = []
    for e in errors:
        ints = dict(n=1, kp=kp, ki=ki, kd=kd, il=il, ds=ds, shift=output_shift(twelve), stall=1,
                    cpr=2000, index_k=0, count=0, home=0, out=0, p=e << 16, v=0, a=0, vmax=0,
                    target=e, done=1, vmode=0, fwd=1, stopping=0, motor_off=0, bp=1 << 30,
                    threshold=0x7FFF, stop_on_error=0, flags=0, armed=0, rp=0, rv=0, **mem)
        floats = dict(volts_per_code=0.1, apv=1.0, load=0.0, coul=0.0, rate=1.0, decay=0.5,
                      gain=0.5, ts=1.0, angle=0.5, speed=0.0)
        r = dict(zip(fastloop.RESULTS, loop(tuple(ints[k] for k in fastloop.INT_ARGS),
                                            tuple(floats[k] for k in fastloop.FLOAT_ARGS))))
        assert r["ran"] == 1 and r["rp"] == 0
        mem = {k: r[k] for k in mem}
        out.append((r["u"], r["out"], mem))
    return out
