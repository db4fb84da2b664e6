"""The ``lm629`` protocol decoder for sigrok (PulseView, sigrok-cli), shipped in the package.

The decoder itself is the ``lm629/`` directory beside this module: a libsigrokdecode decoder
(API 3), plain Python that runs inside sigrok's own interpreter and imports nothing of
``lm629_host`` (its chip facts are checked against :mod:`lm629_host.bus.opcodes` by the tests).
This module finds it, copies it where sigrok looks (``lm629 sigrok install``), and runs it
with sigrok's own tool over a VCD (:func:`decode`: the tests, ``tools/render_decode.py``).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from dataclasses import dataclass
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


#: Debian 12's libsigrokdecode 0.5.3 aborts at interpreter finalization, after the decode has
#: been printed, whenever a decoder ran: sigrok bug 1671 (fixed upstream by libsigrokdecode
#: 234cbf50, 2021).  Exactly this abort is the tool's; any other failure is a real one.
BUG_1671 = "Fatal Python error: bool_dealloc"
#: its exit: SIGABRT, which a shell reports as 134 and subprocess as -6
BUG_1671_EXITS = (128 + signal.SIGABRT, -signal.SIGABRT)

#: the decoder's channels, in its order (required, then optional)
CHANNELS = tuple(f"d{i}" for i in range(8)) + ("cs", "rd", "wr", "ps")
OPTIONAL_CHANNELS = ("rst", "hi")


@dataclass(frozen=True)
class Annotation:
    """One annotation of the decoder: its row's name (``Commands``, ``Protocol warnings``...),
    its text (the longest form), and where it lies in the capture, in microseconds."""

    row: str
    text: str
    start_us: float
    end_us: float


class SigrokError(RuntimeError):
    """sigrok-cli failed (anything but the known abort after the decode, :data:`BUG_1671`)."""


def failed(returncode: int, stderr: str) -> bool:
    """Whether a sigrok-cli run failed: any non-zero exit except exactly sigrok bug 1671's
    abort at finalization (SIGABRT, exit 134 in a shell, with :data:`BUG_1671` on stderr), which comes after the
    whole decode has been printed."""
    return returncode != 0 and not (returncode in BUG_1671_EXITS and BUG_1671 in stderr)


def vcd_signals(path: Path | str) -> list[str]:
    """The signal names a VCD declares (``$var wire 1 ! d0 $end``)."""
    names = []
    with open(path) as f:
        for line in f:
            if line.startswith("$enddefinitions"):
                break
            m = re.match(r"\s*\$var\s+\S+\s+\d+\s+\S+\s+(\S+)", line)
            if m:
                names.append(m.group(1))
    return names


def channel_map(signals: list[str], chip: int = 0) -> str:
    """``-P lm629:...`` channel assignments for chip ``chip`` of a capture whose signals are
    named as the decoder's channels (chip k's /CS and HI as ``csK`` and ``hiK``)."""
    suffix = "" if chip == 0 else str(chip)
    pairs = []
    for name in CHANNELS + OPTIONAL_CHANNELS:
        signal = name + suffix if name in ("cs", "hi") else name
        if signal in signals:
            pairs.append(f"{name}={signal}")
        elif name not in OPTIONAL_CHANNELS:
            raise ValueError(f"the capture has no signal {signal!r} for the decoder's {name} "
                             f"(it has {', '.join(signals)})")
    return ":".join(pairs)


def decode(vcd: Path | str, *, chip: int = 0, decoders: Path | None = None,
           sigrok_cli: str = "sigrok-cli", timeout_s: float = 300) -> list[Annotation]:
    """Run the ``lm629`` decoder with sigrok-cli over the VCD ``vcd`` (the decoder of this
    package unless ``decoders``, a decoders directory, is given) and return every annotation,
    in the order sigrok printed them (by end time)."""
    env = dict(os.environ, SIGROKDECODE_DIR=str(decoders or DECODER.parent))
    cmd = [sigrok_cli, "-I", "vcd", "-i", str(vcd),
           "-P", "lm629:" + channel_map(vcd_signals(vcd), chip),
           "-A", "lm629", "--protocol-decoder-jsontrace"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout_s)
    if failed(r.returncode, r.stderr):
        raise SigrokError(f"{' '.join(cmd)} exited {r.returncode}: {r.stderr.strip()[-2000:]}")
    begun: dict[tuple[str, str], list[float]] = {}
    out = []
    for line in r.stdout.splitlines():
        line = line.strip().rstrip(",")
        if not line.startswith("{\"ph\""):
            continue
        e = json.loads(line)
        key = (e["tid"], e["name"])
        if e["ph"] == "B":
            begun.setdefault(key, []).append(e["ts"])
        elif e["ph"] == "E" and begun.get(key):
            out.append(Annotation(e["tid"], e["name"], begun[key].pop(0), e["ts"]))
    if "lm629" not in r.stdout and not out:
        raise SigrokError(f"{' '.join(cmd)} printed no decode: {r.stderr.strip()[-2000:]}")
    return out


def commands(annotations: list[Annotation]) -> list[str]:
    """The Commands row as ``NAME WORD WORD...`` (hex words, as the chip got or gave them)."""
    return [a.text.split(":")[0] for a in annotations if a.row == "Commands"]


def warnings(annotations: list[Annotation]) -> list[str]:
    return [a.text for a in annotations if a.row == "Protocol warnings"]


__all__ = ["Annotation", "BUG_1671", "BUG_1671_EXITS", "CHANNELS", "DECODER", "FILES",
           "OPTIONAL_CHANNELS", "SigrokError", "channel_map", "commands", "decode", "failed", "install",
           "user_decoders_dir", "vcd_signals", "warnings"]
