"""Build hook for the two compiled parts, both optional: the chip model's sample loop in C and
the tuner's predictor loop in C.

Everything else is in pyproject.toml.  If no C compiler is at hand the build goes on without
them and the same loops run in Python (lm629_host/sim/model/fastloop.py,
lm629_host/physics/predict.py), only slower.  -ffp-contract=off: no fused multiply-add, so
that the C loops compute float for float what the Python ones do.
"""

from setuptools import Extension, setup

FLAGS = ["-O2", "-ffp-contract=off"]
#: one sample's filter and motor, one C home for both loops (pid.py's pid_step and plant.py's
#: motor_step in C)
SAMPLE_C = "lm629_host/physics/sample_c.h"

setup(ext_modules=[
    Extension("lm629_host.sim.model._fastloop", ["lm629_host/sim/model/_fastloop.c"],
              depends=[SAMPLE_C], extra_compile_args=FLAGS, optional=True),
    Extension("lm629_host.physics._predict", ["lm629_host/physics/_predict.c"],
              depends=[SAMPLE_C], extra_compile_args=FLAGS, optional=True),
])
