"""The page's requests as command lines: each form becomes the ``lm629`` command a person would
type (``move``, ``stop``, ``filter``, ``step``), run through the command line's own click
command, so that the panel checks every value as the command line does and an error is the
same one line.  The fields are passed as the person typed them: the command line parses them.

The step test's answer adds the measured response (the CSV ``lm629 step`` writes) and the
prediction of the tuner's model drawn over it (:func:`lm629_host.physics.predict.simulate`):
the profile's identified plant (``[axis.NAME.plant]``, what ``lm629 tune`` / ``identify``
saved: the twin), else on a simulator the simulated motor's own numbers.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from lm629_host.panel.bench import Outcome

GAIN_KEYS = ("kp", "ki", "kd", "il", "ds")
#: the stop modes, as ``lm629 stop`` names them
STOP_MODES = ("abrupt", "smooth", "off")


class PanelRequestError(ValueError):
    """A request the page should never send (a field of the wrong kind, an unknown axis)."""


@dataclass
class PanelJob:
    argv: list[str]
    cs: int
    stop: bool = False
    then: Callable[[Outcome], Outcome] | None = None
    live: bool = False  #: rows read between its programs (a move the panel waits on)


def _text(body: dict[str, Any], key: str) -> str:
    value = body.get(key, "")
    if value is None:
        return ""
    if not isinstance(value, (str, int, float)) or isinstance(value, bool):
        raise PanelRequestError(f"{key}: a number as text")
    return str(value).strip()


def _options(body: dict[str, Any], keys: list[tuple[str, str]]) -> list[str]:
    out = []
    for key, option in keys:
        value = _text(body, key)
        if value:
            out.append(f"{option}={value}")  # '=': a negative value stays the option's
    return out


def build(body: dict[str, Any], worker: Any) -> PanelJob:
    """The command line for a request ``{"cmd": ..., "axis": NAME, ...fields}``."""
    names = {name: cs for cs, name in worker.axes}
    axis = _text(body, "axis") or worker.axes[0][1]
    if axis not in names:
        raise PanelRequestError(f"no axis {axis!r} on this bench (axes: {', '.join(names)})")
    cs = names[axis]
    cmd = body.get("cmd")
    if cmd == "stop":
        mode = _text(body, "mode") or "abrupt"
        if mode not in STOP_MODES:
            raise PanelRequestError(f"stop mode {mode!r}: one of {', '.join(STOP_MODES)}")
        return PanelJob(["stop", f"--{mode}"], cs, stop=True)
    if cmd == "clear":
        return PanelJob(["clear"], cs)
    if cmd == "move":
        shape = _text(body, "shape") or "trapezoid"
        argv = ["move", *_options(body, [("vel", "--vel"), ("acc", "--acc")])]
        if shape == "trapezoid":
            argv.append("--no-wait")  # the panel watches the move; stop ends it
        else:
            argv += [f"--shape={shape}", *_options(body, [("jerk", "--jerk")])]
        if body.get("relative"):
            argv.append("--relative")
        return PanelJob([*argv, "--", _text(body, "target")], cs, live=shape != "trapezoid")
    gains = {k: _text(body, k) for k in GAIN_KEYS if _text(body, k)}
    if cmd == "filter":
        return PanelJob(["filter", *_options(body, [(k, f"--{k}") for k in GAIN_KEYS])], cs,
                        then=_remember(worker, cs, gains))
    if cmd == "step":
        fd, path = tempfile.mkstemp(prefix="lm629-panel-step-", suffix=".csv")
        os.close(fd)
        argv = ["step", *_options(body, [(k, f"--{k}") for k in GAIN_KEYS]),
                *_options(body, [("vel", "--vel"), ("acc", "--acc"), ("time", "--time")]),
                f"--csv={path}", "--no-png", "--", _text(body, "distance") or "200"]
        remember = _remember(worker, cs, gains)
        return PanelJob(argv, cs, then=lambda o: _step_answer(path, worker, cs)(remember(o)))
    raise PanelRequestError(f"unknown command {cmd!r}: move, stop, filter, step or clear")


def _remember(worker: Any, cs: int, gains: dict[str, str]) -> Callable[[Outcome], Outcome]:
    """After a command that loaded ``gains`` (checked by it: whole numbers), keep them: no
    register reads the gains back, and the prediction needs them."""
    def then(outcome: Outcome) -> Outcome:
        worker.gains.setdefault(cs, {}).update({k: int(v) for k, v in gains.items()})
        return outcome
    return then


def _step_answer(path: str, worker: Any, cs: int) -> Callable[[Outcome], Outcome]:
    def then(outcome: Outcome) -> Outcome:
        from lm629_host.bench.capture import read_csv
        try:
            rows = read_csv(path)
        finally:
            os.unlink(path)
        t = [float(r["t_s"]) for r in rows]
        desired = [int(r["desired_position"]) for r in rows]
        actual = [int(r["real_position"]) for r in rows]
        before = [a for x, a in zip(t, actual) if x <= 0]  # where the shaft was at the STT
        prediction = predict(worker, cs, t, desired, (before or actual or [0])[-1])
        text = outcome.text.strip().splitlines()
        text = [ln for ln in text if not ln.startswith("wrote ")]
        outcome.text = "\n".join(text)
        outcome.data = {"t": t, "desired": desired, "actual": actual, **prediction}
        return outcome
    return then


def predict(worker: Any, cs: int, t: list[float], desired: list[int], x0: int) -> dict[str, Any]:
    """The tuner's model's answer to the recorded desired positions from ``x0``, on the chip's
    samples: {"predicted": positions at ``t``, "basis": where the model came from}, or
    {"predicted": None, "basis": why there is none}."""
    from lm629_host.physics.predict import simulate
    model, whence = plant_model(worker.session, cs, worker.sample_s)
    if model is None or not t:
        return {"predicted": None, "basis": whence}
    known = worker.gains.get(cs)
    if not known:
        return {"predicted": None, "basis": "the loaded gains are unknown (no register reads "
                                            "them back): apply gains from the panel first"}
    from lm629_host.physics.axis import Gains
    gains = Gains(known.get("kp", 0), known.get("ki", 0), known.get("kd", 0), known.get("il", 0),
                  known.get("ds", 1))
    sample_s = worker.sample_s
    # from the STT (t = 0): the desired position at each sample is the row's at or after it
    # (exact for a step, which jumps at the STT; at most a row early on a ramp)
    n = max(1, math.ceil(t[-1] / sample_s) + 1)
    per_sample, j = [], 0
    for k in range(n):
        while j + 1 < len(t) and t[j] < k * sample_s - 1e-12:
            j += 1
        per_sample.append(desired[j])
    counts, _ = simulate(model, gains, per_sample, x0=x0 + 0.5)
    predicted = [x0 if x < 0 else counts[min(n - 1, round(x / sample_s))] for x in t]
    return {"predicted": predicted, "basis": whence}


def plant_model(session: Any, cs: int, sample_s: float) -> tuple[Any, str]:
    """(the tuner's AxisModel, where it came from) or (None, why there is none)."""
    from lm629_host.bench.twin import Plant
    prof = session.profile
    ax = prof.by_cs(cs) if prof is not None else None
    if ax is not None and ax.plant:
        return Plant.from_values(ax.plant).model(sample_s), f"the twin: [axis.{ax.name}.plant]"
    if session.is_sim:
        from lm629_host.cli.sim import simulated_plant
        plant = simulated_plant()
        return plant.model(sample_s), "the simulated motor's numbers"
    return None, "no plant in the profile: `lm629 identify` or `lm629 tune --save` records one"


__all__ = ["PanelJob", "PanelRequestError", "STOP_MODES", "build", "plant_model", "predict"]
