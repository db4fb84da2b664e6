"""The ``lm629`` protocol decoder for sigrok (PulseView, sigrok-cli), shipped in the package.

The decoder itself is the ``lm629/`` directory beside this module: a libsigrokdecode decoder
(API 3), plain Python that runs inside sigrok's own interpreter and imports nothing of
``lm629_host`` (its chip facts are checked against :mod:`lm629_host.opcodes` by the tests).
This module only finds it and copies it where sigrok looks (``lm629 sigrok install``).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

#: the decoder's directory in this package (what SIGROKDECODE_DIR's parent must hold)
DECODER = Path(__file__).resolve().parent / "lm629"
#: the files that make the decoder
FILES = ("__init__.py", "pd.py", "tables.py")


def user_decoders_dir() -> Path:
    """Where libsigrokdecode looks for a user's decoders: ``$XDG_DATA_HOME`` (default
    ``~/.local/share``) ``/libsigrokdecode/decoders``, for PulseView and sigrok-cli alike."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "libsigrokdecode" / "decoders"


def install(directory: Path | None = None) -> Path:
    """Copy the decoder to ``directory``/lm629 (default :func:`user_decoders_dir`), replacing
    an older copy; returns the decoder's new directory."""
    target = (directory if directory is not None else user_decoders_dir()) / DECODER.name
    target.mkdir(parents=True, exist_ok=True)
    for name in FILES:
        shutil.copyfile(DECODER / name, target / name)
    stale = target / "__pycache__"  # an older copy's bytecode must not shadow the new files
    if stale.is_dir():
        shutil.rmtree(stale)
    return target


__all__ = ["DECODER", "FILES", "install", "user_decoders_dir"]
