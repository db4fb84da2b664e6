"""Shared by the generators in tools/: write a generated file, or with ``--check`` fail when the
committed copy differs from what the generator makes now (the tests run ``--check``); save a
plotting tool's figure."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any


def write_or_check(out: Path, text: str, argv: list[str], generator: str) -> int:
    if "--check" in argv:
        if not out.exists() or out.read_text() != text:
            print(f"{out} is stale: run python3 {generator}", file=sys.stderr)
            return 1
        return 0
    out.write_text(text)
    print(f"wrote {out}")
    return 0


def save_figure(fig: Any, out: str | Path, dpi: int = 80) -> int:
    """Lay out and save a matplotlib figure, and say where (a plotting tool's last step)."""
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    print(f"wrote {out}")
    return 0
