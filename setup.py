"""Build hook for the one compiled part: the chip model's sample loop in C (optional).

Everything else is in pyproject.toml.  If no C compiler is at hand the build goes on without
it and the model uses the same loop in Python (lm629_host/sim/model/fastloop.py), only slower.
"""

from setuptools import Extension, setup

setup(ext_modules=[Extension(
    "lm629_host.sim.model._fastloop", ["lm629_host/sim/model/_fastloop.c"],
    extra_compile_args=["-O2", "-ffp-contract=off"], optional=True)])
