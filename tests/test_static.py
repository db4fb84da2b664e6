"""Every remaining ``type: ignore`` and ``noqa`` says which check it silences and why (ruff's
RUF100/PGH004 and mypy's ``warn_unused_ignores``/``ignore-without-code``, run by ``.ci/run``,
keep them needed and coded; this keeps them explained)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: a type-ignore with its [code] and ``# why``; a noqa with its codes and `` - why`` (or
#: ``# why``, ``(why)``)
_IGNORE = re.compile(r"#\s*type:\s*ignore(\[[\w\-, ]+\])?(.*)$")
_NOQA = re.compile(r"#\s*noqa(:\s*[A-Z]+[0-9]+(?:\s*,\s*[A-Z]+[0-9]+)*)?(.*)$")
_REASON = re.compile(r"^\s*(#|-|\()\s*\S")


def _unexplained() -> list[str]:
    out = []
    for folder in ("lm629_host", "tools", "tests"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for n, line in enumerate(path.read_text().splitlines(), 1):
                for rx in (_IGNORE, _NOQA):
                    m = rx.search(line)
                    if m and (m.group(1) is None or not _REASON.match(m.group(2))):
                        out.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    return out


def test_every_ignore_and_noqa_names_its_code_and_says_why():
    assert _unexplained() == []


def test_the_checker_sees_a_bare_one():
    assert _REASON.match("  # pyusb names it") and _REASON.match(" - why")
    m = _NOQA.search("x = 1  #" + " noqa: E501")
    assert m and not _REASON.match(m.group(2))
    assert _IGNORE.search("y  # type" + ": ignore").group(1) is None
