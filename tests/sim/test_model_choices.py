"""The model choices are listed in one place (lm629_host/sim/model/__init__.py's docstring).

Every ``[model choice N]`` elsewhere in the model refers to an item of that list, and no
module keeps an unnumbered ``[model choice]`` (a second, hand-kept description) of its own.
"""

from __future__ import annotations

import re
from pathlib import Path

import lm629_host.sim.model

MODEL = Path(lm629_host.sim.model.__file__).parent


def items() -> list[int]:
    doc = lm629_host.sim.model.__doc__
    section = doc[doc.index("Model choices\n============="):]
    return [int(n) for n in re.findall(r"^(\d+)\. ", section, re.MULTILINE)]


def test_the_list_is_numbered_1_to_n():
    numbers = items()
    assert numbers == list(range(1, len(numbers) + 1))


def test_every_reference_names_an_item_of_the_list():
    known = set(items())
    for path in sorted(MODEL.glob("*.py")) + sorted(MODEL.glob("*.c")):
        text = path.read_text()
        for tag in re.findall(r"\[model choices? ?([^\]]*)\]", text):
            if tag == "N":  # the docstrings explaining the notation
                continue
            n = re.match(r"\d+", tag)
            assert n, (f"{path.name}: [model choice {tag}] names no item "
                       "(describe it in the list in __init__.py and refer to it by number)")
            assert int(n.group()) in known, f"{path.name}: [model choice {tag}] is not in the list"
        if path.name != "__init__.py":
            assert "Model choices\n=====" not in text, f"{path.name}: a second list of choices"
