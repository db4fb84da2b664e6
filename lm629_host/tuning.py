"""``lm629_host.tuning``, the path lab scripts already import: the session that tunes a bench
lives in :mod:`lm629_host.bench.tuning` (``autotune`` and ``TuneResult`` are also at the package
root), the arithmetic it runs on in :mod:`lm629_host.physics` (the axis model and gains, the
predictor, the fit and the design)."""

from lm629_host.bench.tuning import (
    Phasing,
    Record,
    TuneResult,
    autotune,
    check_phasing,
    measure_move,
)
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.design import default_profile, design
from lm629_host.physics.fit import fit_model
from lm629_host.physics.metrics import MoveMetrics, score, step_metrics
from lm629_host.physics.pid import PIDState
from lm629_host.physics.predict import (
    MOVE_ACCELERATION,
    MOVE_VELOCITY,
    MoveProfile,
    predict_move,
    simulate,
)

__all__ = [
    "AxisModel",
    "Gains",
    "MOVE_ACCELERATION",
    "MOVE_VELOCITY",
    "MoveMetrics",
    "MoveProfile",
    "PIDState",
    "Phasing",
    "Record",
    "TuneResult",
    "autotune",
    "check_phasing",
    "default_profile",
    "design",
    "fit_model",
    "measure_move",
    "predict_move",
    "score",
    "simulate",
    "step_metrics",
]
