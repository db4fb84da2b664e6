"""The bundled software model of the LM628/LM629 (and of a motor and encoder).

The model knows nothing of the driver: it is driven one bus cycle at a time through
:class:`ChipModel`, by the ``sim://`` transport, the simavr harness or the emulated FT232H.
"""

from .chip import ChipModel
from .params import ChipParams, MotorParams

__all__ = ["ChipModel", "ChipParams", "MotorParams"]
