"""A bench profile: the board and its named axes in one TOML file, loaded, checked, applied to
the chips, re-applied after a power cycle, and the tuned gains written back into it.

Why: an LM629 keeps nothing through a power cycle (filter, limits, output mode are gone), and a
rig's travel and speed limits belong to the rig, not to each script.  So the file says once::

    [board]
    port = "/dev/ttyACM0"        # any port URL
    chip = "lm629"
    clock = "8MHz"

    [axis.x]                     # the axis's name: `lm629 --axis x`, board["x"]
    cs = 0                       # its chip select
    lines = 500                  # encoder lines: the CLI speaks revolutions and rpm
    kp = 889                     # the filter (LFIL + UDF when applied)
    kd = 12921
    ds = 1                       # derivative interval, samples
    min = -20000                 # soft travel limits, counts
    max = 20000
    max_velocity = 200000        # counts/s
    max_acceleration = 4000000   # counts/s^2
    following_error = 2000       # counts: LPES, the motor stops beyond it

Every key, its type and range are in :data:`BOARD_KEYS` and :data:`AXIS_KEYS`.  A bad
profile is one :class:`ProfileError` (a ``ValueError``) naming the file, the line and the key,
raised by :func:`load_profile` before anything is sent.

**Applied** (:func:`apply_axis`): LFIL with the gains given and the derivative interval, UDF,
LPES with ``following_error`` (7FFF, the reset value, when not given), PORT12 for
``output = 12`` on an LM628.  **Lost** (:func:`settings_lost`): LPES sets bit 9 of the signals
register (turn the motor off on excessive position error) and only LPEI or a reset clears it,
so an applied axis reads it set, and a chip reset or power-cycled since reads it clear (one
RDSIGS, nothing moves).  What this cannot see: gains or a threshold changed by another program
since (``lm629 filter``, ``lm629 limit --stop``) -- the chip cannot report its filter --, and
where the shaft is: after a power cycle positions count from where it was at power-up.  An
LPEI since (``lm629 limit`` without ``--stop``) reads as lost, and the profile is applied
again.

A library module (no click): :func:`lm629_host.open_board` ``(profile=PATH)`` and the CLI
(:mod:`lm629_host.cli.profile`) both use it.
"""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lm629_host.physics.limits import SoftLimits
from lm629_host.bus.opcodes import COEFFICIENT_MAX, DERIVATIVE_INTERVAL_MAX, POSITION_MAX, POSITION_MIN, Signals
from lm629_host.urls import parse_hz

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


class ProfileError(ValueError):
    """A profile that cannot be used: ``FILE:LINE: [table] key ...`` in one line."""


# ---------------------------------------------------------------------------- the keys
@dataclass(frozen=True)
class Key:
    """One key of a profile table: its type, range and what it means (for the template)."""

    kind: str  #: "int", "number" (int or float), "str", "hz" (a frequency: "8MHz" or Hz)
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] = ()
    help: str = ""


BOARD_KEYS: dict[str, Key] = {
    "port": Key("str", help="any port URL (serial:///dev/ttyACM0, ftdi://..., sim://)"),
    "chip": Key("str", choices=("lm628", "lm629"), help="lm628 or lm629"),
    "clock": Key("hz", 1e6, 8e6, help="the chips' clock: 8MHz, 6e6"),
    "note": Key("str", help="free text"),
}

AXIS_KEYS: dict[str, Key] = {
    "cs": Key("int", 0, 15, help="chip select of this axis's chip"),
    "chip": Key("str", choices=("lm628", "lm629"), help="this chip, when not the board's"),
    "output": Key("int", choices=(8, 12), help="8, or 12 for an LM628 with a 12-bit DAC"),
    "lines": Key("int", 1, 1 << 24, help="encoder lines: the CLI speaks revolutions and rpm "
                                         "(the limits stay in counts)"),
    "kp": Key("int", 0, COEFFICIENT_MAX, help="proportional gain"),
    "ki": Key("int", 0, COEFFICIENT_MAX, help="integral gain"),
    "kd": Key("int", 0, COEFFICIENT_MAX, help="derivative gain"),
    "il": Key("int", 0, COEFFICIENT_MAX, help="integration limit"),
    "ds": Key("int", 1, DERIVATIVE_INTERVAL_MAX, help="derivative interval, samples"),
    "min": Key("int", POSITION_MIN, POSITION_MAX, help="soft travel limit, counts"),
    "max": Key("int", POSITION_MIN, POSITION_MAX, help="soft travel limit, counts"),
    "max_velocity": Key("number", 0, 1e12, help="counts/s"),
    "max_acceleration": Key("number", 0, 1e15, help="counts/s^2"),
    "following_error": Key("int", 0, COEFFICIENT_MAX,
                           help="counts: LPES, the motor stops beyond it"),
    "max_move_s": Key("number", 1, 1e9, help="seconds: a move planned longer is refused "
                                             "before it starts (default 600)"),
    "index_velocity": Key("number", -1e9, 1e9,
                          help="counts/s of `index --search` (the sign: towards max or min)"),
    "note": Key("str", help="free text"),
}

GAIN_KEYS = ("kp", "ki", "kd", "il", "ds")

#: ``[axis.NAME.plant]``: the axis as ``lm629 tune`` / ``lm629 identify`` identified it, in the
#: units a fit of the shaft's motion can tell (:mod:`lm629_host.bench.twin`); ``sim://?profile=FILE``
#: builds the axis's motor from it (the same names are ``MotorParams`` fields)
PLANT_KEYS: dict[str, Key] = {
    "accel": Key("number", 1e-3, 1e15, help="counts/s^2 at full-scale output, shaft at rest"),
    "tau": Key("number", 1e-6, 1e6, help="mechanical time constant, s"),
    "dry": Key("number", 0, 1, help="dry friction, a fraction of full-scale output"),
    "load": Key("number", -1, 1, help="constant load, a fraction of full-scale output "
                                      "(> 0 pulls towards fewer counts)"),
    "reversed": Key("bool", help="motor leads reversed (the sign of the drive)"),
    "rms": Key("number", 0, 1e9, help="the fit's rms error, counts"),
    "steps": Key("int", 0, 1000, help="identification steps fitted"),
    "date": Key("str", help="when it was identified (ISO 8601)"),
    "port": Key("str", help="the port it was identified on"),
}


# ---------------------------------------------------------------------------- the profile
@dataclass
class AxisProfile:
    """One ``[axis.NAME]`` table, checked."""

    name: str
    cs: int
    chip: str
    output: int = 8
    lines: int | None = None
    kp: int | None = None
    ki: int | None = None
    kd: int | None = None
    il: int | None = None
    ds: int = 1
    min: int | None = None
    max: int | None = None
    max_velocity: float | None = None
    max_acceleration: float | None = None
    following_error: int | None = None
    index_velocity: float | None = None
    max_move_s: float | None = None
    note: str = ""
    key_lines: dict[str, int] = field(default_factory=dict)  #: key -> line in the file
    #: ``[axis.NAME.plant]`` checked against :data:`PLANT_KEYS`, None when the file has none
    plant: dict[str, Any] | None = None

    def gains(self) -> dict[str, int]:
        """The filter as :meth:`LM629.load_filter` takes it (the gains given, and ds)."""
        g = {k: getattr(self, k) for k in ("kp", "ki", "kd", "il") if getattr(self, k) is not None}
        g["derivative_interval"] = self.ds
        return g

    def gains_text(self) -> str:
        return " ".join(f"{k}={getattr(self, k)}" for k in GAIN_KEYS
                        if getattr(self, k) is not None)

    @property
    def threshold(self) -> int:
        """The LPES threshold applied (7FFF, the reset value, when not given)."""
        return COEFFICIENT_MAX if self.following_error is None else self.following_error


@dataclass
class Profile:
    path: Path
    port: str | None
    chip: str
    clock_hz: float
    axes: dict[str, AxisProfile]
    note: str = ""
    given: frozenset[str] = frozenset()  #: the [board] keys the file sets
    lines: dict[str, int] = field(default_factory=dict)  #: [board] key -> line in the file

    def axis(self, name: str) -> AxisProfile:
        try:
            return self.axes[name]
        except KeyError:
            raise ValueError(f"no axis {name!r} in {self.path} (it has "
                             f"{', '.join(self.axes) or 'none'})") from None

    def by_cs(self, cs: int) -> AxisProfile | None:
        return next((a for a in self.axes.values() if a.cs == cs), None)

    def limits(self, axis: AxisProfile) -> SoftLimits | None:
        """The axis's soft limits (None when it sets none)."""
        if all(getattr(axis, k) is None for k in ("min", "max", "max_velocity",
                                                   "max_acceleration")):
            return None
        return SoftLimits(axis.min, axis.max, axis.max_velocity, axis.max_acceleration,
                          self.clock_hz, where=str(self.path), table=f"axis.{axis.name}",
                          lines=tuple(axis.key_lines.items()))


# ---------------------------------------------------------------------------- loading
_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")
_PART = r"""(?:"[^"]*"|'[^']*'|[A-Za-z0-9_-]+)"""
_KEY = re.compile(rf"^\s*({_PART}(?:\s*\.\s*{_PART})*)\s*=")


def _unquote_path(text: str) -> str:
    parts = re.findall(r"""("[^"]*"|'[^']*'|[^.\s]+)""", text)
    return ".".join(p.strip("\"'") for p in parts)


def _place(out: dict[tuple[str, str], int], table: str, path: str, n: int) -> None:
    """Line ``n`` for each part of the dotted ``path`` within ``table``, as a key of the table
    before it (first seen wins)."""
    parts = path.split(".")
    for i, part in enumerate(parts):
        out.setdefault((".".join(p for p in (table, *parts[:i]) if p), part), n)


def key_lines(text: str) -> dict[tuple[str, str], int]:
    """(table, key) -> line number, and (table, "") -> its header's line, read from the text
    (tomllib keeps no positions).  Enough for the plain tables and dotted keys a profile
    uses."""
    out: dict[tuple[str, str], int] = {}
    table = ""
    for n, line in enumerate(text.splitlines(), 1):
        h = _HEADER.match(line)
        if h:
            table = _unquote_path(h.group(1))
            out.setdefault((table, ""), n)
            _place(out, "", table, n)  # [axis.x] also makes [axis]
            continue
        k = _KEY.match(line)
        if k:  # a dotted key (axis.x.cs = 0) also places the tables it makes
            _place(out, table, _unquote_path(k.group(1)), n)
    return out


def _parses(text: str) -> bool:
    try:
        tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError):
        return False
    return True


def _toml_error(text: str, exc: Exception) -> tuple[int, str]:
    """(line, what is wrong) of a text tomllib refused.  Its error carries the line as an
    attribute only from Python 3.14 (tomli 2.1 before 3.11), and a value nested too deep is a
    bare RecursionError.  Otherwise tomllib itself is asked: the line is the one after the
    longest run of leading lines it takes.  A later line cannot make an earlier error good, so
    that is where the text stops being TOML for the parser that reads it (an unclosed string
    or array: the line that opens it).  tomlkit's ParseError has a line too, but that parser
    takes some texts tomllib refuses (TOML 1.1 escapes) and places others elsewhere (a table
    declared twice: at the end of the second)."""
    why = ("a value nested too deep (arrays or inline tables)" if isinstance(exc, RecursionError)
           else getattr(exc, "msg", str(exc)))
    line = getattr(exc, "lineno", None)
    if isinstance(line, int):
        return line, why
    lines = text.splitlines(keepends=True)
    good = next(n for n in range(len(lines), -1, -1) if _parses("".join(lines[:n])))
    return good + 1, why


class _Checker:
    def __init__(self, path: Path, lines: dict[tuple[str, str], int]):
        self.path = path
        self.lines = lines

    def line(self, table: str, key: str) -> int:
        """The line of ``key`` in ``table``, else of the table's header, else of the key that
        made the table in its parent (``x = 1`` under ``[axis]`` for ``[axis.x]``), and so on
        up; 0 when the text shows none."""
        found = self.lines.get((table, key)) or self.lines.get((table, ""))
        while not found and table:
            table, _, key = table.rpartition(".")
            found = self.lines.get((table, key)) or self.lines.get((table, ""))
        return found or 0

    def fail(self, table: str, key: str, text: str) -> ProfileError:
        line = self.line(table, key)
        where = f"{self.path}:{line}" if line else str(self.path)
        what = f"[{table}] {key}" if key else f"[{table}]"
        return ProfileError(f"{where}: {what}: {text}")

    def value(self, table: str, key: str, spec: Key, v: Any) -> Any:
        def bad(text: str) -> ProfileError:
            return self.fail(table, key, f"{v!r} {text}")

        if spec.kind == "str":
            if not isinstance(v, str):
                raise bad("must be text (in quotes)")
            if spec.choices and v.lower() not in spec.choices:
                raise bad(f"must be one of {', '.join(map(str, spec.choices))}")
            return v.lower() if spec.choices else v
        if spec.kind == "bool":
            if not isinstance(v, bool):
                raise bad("must be true or false")
            return v
        if spec.kind == "hz":
            if isinstance(v, bool) or not isinstance(v, (str, int, float)):
                raise bad("must be a frequency (\"8MHz\" or a number of Hz)")
            try:
                hz = parse_hz(str(v))
            except ValueError:
                raise bad("is not a frequency (\"8MHz\", 6e6)") from None
            if not spec.lo <= hz <= spec.hi:  # type: ignore[operator]  # hz keys have a range
                raise bad("is outside the chip's 1-8 MHz")
            return hz
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise bad("must be a number" if spec.kind == "number" else "must be a whole number")
        if spec.kind == "int" and not isinstance(v, int):
            raise bad("must be a whole number")
        if isinstance(v, float) and not math.isfinite(v):
            raise bad("must be finite")
        if spec.choices and v not in spec.choices:
            raise bad(f"must be one of {', '.join(map(str, spec.choices))}")
        if spec.lo is not None and spec.hi is not None and not spec.lo <= v <= spec.hi:
            lo = int(spec.lo) if float(spec.lo).is_integer() else spec.lo
            hi = int(spec.hi) if float(spec.hi).is_integer() else spec.hi
            raise bad(f"is outside {lo}..{hi}")
        return v

    def table(self, table: str, data: Any, keys: Mapping[str, Key]) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(table, "", "must be a table ([" + table + "])")
        out = {}
        for k, v in data.items():
            if k not in keys:
                raise self.fail(table, k, f"unknown key; known: {', '.join(keys)}")
            out[k] = self.value(table, k, keys[k], v)
        return out


def parse_profile(text: str, path: str | os.PathLike[str] = "<profile>") -> Profile:
    """A profile from its text; :class:`ProfileError` naming ``path``, the line and the key."""
    path = Path(path)
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:  # RecursionError: nested deep
        line, why = _toml_error(text, exc)
        raise ProfileError(f"{path}:{line}: not TOML: {why}") from None
    chk = _Checker(path, key_lines(text))
    for top in data:
        if top not in ("board", "axis"):
            raise chk.fail(top, "", "unknown table; a profile has [board] and [axis.NAME]")
    board = chk.table("board", data.get("board", {}), BOARD_KEYS)
    chip = board.get("chip", "lm629")
    clock_hz = board.get("clock", 8e6)
    axes_data = data.get("axis", {})
    if not isinstance(axes_data, dict):
        raise chk.fail("axis", "", "must be tables [axis.NAME]")
    axes: dict[str, AxisProfile] = {}
    seen_cs: dict[int, str] = {}
    for name, raw in axes_data.items():
        table = f"axis.{name}"
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_-]*", name) or name.lower() == "all":
            raise chk.fail(table, "", f"{name!r} is not an axis name (a letter, then letters, "
                                      "digits, _ or -; not 'all')")
        plant = None
        if isinstance(raw, dict) and "plant" in raw:
            raw = dict(raw)
            plant = chk.table(f"{table}.plant", raw.pop("plant"), PLANT_KEYS)
        values = chk.table(table, raw, AXIS_KEYS)
        if "cs" not in values:
            raise chk.fail(table, "", "has no cs = N (the chip select of its chip)")
        cs = values["cs"]
        if cs in seen_cs:
            raise chk.fail(table, "cs", f"{cs} is also the chip select of [axis.{seen_cs[cs]}]: "
                                        "one axis per chip")
        seen_cs[cs] = name
        values.setdefault("chip", chip)
        lines = {k: chk.lines[(table, k)] for k in values if (table, k) in chk.lines}
        ax = AxisProfile(name=name, key_lines=lines, plant=plant, **values)
        if ax.min is not None and ax.max is not None and ax.min > ax.max:
            raise chk.fail(table, "min", f"{ax.min} is above max = {ax.max}")
        if ax.output == 12 and ax.chip != "lm628":
            raise chk.fail(table, "output", "12 (a 12-bit DAC) is for an LM628; this axis's "
                                            f"chip is an {ax.chip.upper()}")
        if ax.index_velocity == 0:
            raise chk.fail(table, "index_velocity", "0 would never find the index")
        axes[name] = ax
    return Profile(path, board.get("port"), chip, clock_hz, axes, board.get("note", ""),
                   frozenset(board), {k: chk.lines[("board", k)] for k in board
                                      if ("board", k) in chk.lines})


def load_profile(path: str | os.PathLike[str]) -> Profile:
    """Read and check the profile at ``path`` (see :func:`parse_profile`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ProfileError(f"{p}: cannot read the profile: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ProfileError(f"{p}: not UTF-8 text ({exc.reason})") from None
    return parse_profile(text, p)


# ---------------------------------------------------------------------------- the chips
def attach(chip: Any, profile: Profile, axis: AxisProfile) -> None:
    """Give ``chip`` (an :class:`LM629`) the axis's soft limits and chip variant; nothing is
    sent."""
    chip.limits = profile.limits(axis)
    if axis.max_move_s is not None:  # MoveRules.max_duration: the longest plan a move may have
        from dataclasses import replace
        chip.move_rules = replace(chip.move_rules, max_duration=float(axis.max_move_s))
    chip.variant = axis.chip
    chip.profile_axis = axis.name


def name_axes(board: Any, profile: Profile, only: Iterable[int] | None = None) -> dict[str, Any]:
    """Give each axis of ``board`` (a :class:`~lm629_host.Board`) the profile's name, soft
    limits, chip variant and clock, and the board the profile (``board["x"]``); nothing is
    sent.  The profile's axes by name; :class:`~lm629_host.AxisError` for an axis whose chip
    select the board does not have, among the chip selects ``only`` (default: every axis of
    the profile): a command that drives x need not find y's chip."""
    from dataclasses import replace

    from lm629_host.errors import AxisError
    wanted = None if only is None else set(only)
    named = {}
    for name, ax in profile.axes.items():
        if ax.cs >= len(board.axes) and wanted is not None and ax.cs not in wanted:
            continue
        if ax.cs >= len(board.axes):
            raise AxisError(ax.cs, len(board.axes), f"{board.transport.describe()} (axis "
                                                    f"{name} of {profile.path})")
        chip = board.axes[ax.cs]
        attach(chip, profile, ax)
        chip.move_rules = replace(chip.move_rules, clock_hz=profile.clock_hz)
        named[name] = chip
    board.profile = profile
    return named


def settings_lost(chip: Any) -> Signals | None:
    """The signals register when the chip has lost the profile's settings (reset or powered
    up since they were applied: LPES's bit 9 clear), else None.  One RDSIGS."""
    sig = chip.read_signals()
    return None if sig & Signals.STOP_ON_ERROR else sig


def apply_axis(chip: Any, axis: AxisProfile) -> str:
    """Load the axis's settings into its chip: LFIL + UDF, LPES, PORT12/PORT8 (LM628).
    Refuses (ValueError, nothing sent) while the motor moves: gains never change mid-move.
    Returns what was applied, in words."""
    chip.filter_program(**axis.gains())  # validate before any traffic
    if chip.is_moving():
        raise ValueError(f"axis {axis.name} (cs {axis.cs}) is moving: the profile is applied "
                         "only at rest (`lm629 stop` first)")
    chip.load_filter(**axis.gains())
    chip.update_filter()
    chip.load_position_error(axis.threshold, stop=True)
    if chip.variant == "lm628" and axis.output == 12:
        chip.port12()
    elif chip.variant == "lm628":
        chip.port8()
    parts = [axis.gains_text(), f"LPES {axis.threshold}"]
    if axis.output == 12:
        parts.append("PORT12")
    return ", ".join(parts)


def apply_profile(chips: Mapping[str, Any], profile: Profile) -> list[str]:
    """:func:`apply_axis` on every named chip; one line per axis."""
    return [f"axis {name} (cs {profile.axes[name].cs}): {apply_axis(chip, profile.axes[name])}"
            for name, chip in chips.items()]


def ensure_applied(chips: Mapping[str, Any], profile: Profile,
                   say: Callable[[str], None]) -> list[str]:
    """Apply the profile to every named chip that has lost its settings
    (:func:`settings_lost`), saying so in one line each; a chip that moves is left alone (its
    settings are never changed mid-move) and said so.  Returns the names applied."""
    done = []
    for name, chip in chips.items():
        sig = settings_lost(chip)
        if sig is None:
            continue
        ax = profile.axes[name]
        if not sig & (Signals.ON_TARGET | Signals.MOTOR_OFF):
            say(f"axis {name} (cs {ax.cs}) reads signals {int(sig):04X} (LPES not armed) but is "
                f"moving: {profile.path} not applied (`lm629 profile apply` once it rests)")
            continue
        # reset or powered up behind the driver's back: its registers count from the reset,
        # and the driver's own record of them (the turns of the position register it
        # extended, the derivative interval) is forgotten as after its own reset
        chip.reset_done()
        what = apply_axis(chip, ax)
        say(f"axis {name} (cs {ax.cs}) had lost its settings (signals {int(sig):04X}: reset or "
            f"powered up since): applied {profile.path} ({what}); positions count from where "
            "the shaft was at the reset")
        done.append(name)
    return done


# ---------------------------------------------------------------------------- writing
def _set_keeping_column(table: Any, key: str, value: Any) -> None:
    """``table[key] = value`` in a tomlkit table, the comment after it kept in its column: a
    value that grows or shrinks takes its width from the spaces before the comment (one at
    least), so that a file's comments stay aligned as the user wrote them."""
    old = table.item(key).as_string() if key in table else None
    table[key] = value
    trivia = table.item(key).trivia
    if old is not None and trivia.comment:
        grow = len(table.item(key).as_string()) - len(old)
        trivia.comment_ws = " " * max(1, len(trivia.comment_ws) - grow)


def save_gains(path: str | os.PathLike[str], axis: str, gains: Mapping[str, int],
               plant: Mapping[str, Any] | None = None) -> Path:
    """Write ``gains`` (kp, ki, kd, il, ds: ds in samples) into ``[axis.NAME]`` of the profile
    at ``path``, and ``plant`` (:data:`PLANT_KEYS`) into ``[axis.NAME.plant]`` in place of
    the one there, keeping everything else, comments included (tomlkit), by writing a new
    file beside it and renaming it over the old one.  The result is checked before it replaces
    the file (ProfileError: the file is left as it was)."""
    import tempfile  # here, as tomlkit: only a save writes (every profile's reader loads this module)

    import tomlkit

    p = Path(path)
    text = p.read_text(encoding="utf-8")
    parse_profile(text, p).axis(axis)  # a valid profile that has the axis
    doc = tomlkit.parse(text)
    table = doc["axis"][axis]  # checked above: [axis.NAME] exists
    for k in GAIN_KEYS:
        if k in gains:
            _set_keeping_column(table, k, int(gains[k]))
    if plant is not None:
        sub = table.get("plant")
        if sub is None:
            sub = tomlkit.table()
            table["plant"] = sub
        for k in PLANT_KEYS:
            if k in plant:
                _set_keeping_column(sub, k, plant[k])
            elif k in sub:
                del sub[k]  # a key of the plant identified before, not measured this time
    new = tomlkit.dumps(doc)
    parse_profile(new, p)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(new)
        os.chmod(tmp, p.stat().st_mode & 0o7777)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return p


#: the names a template gives to chip selects 0, 1, 2, 3
AXIS_NAMES = ("x", "y", "z", "a")


def template(*, port: str | None, chip: str = "lm629", clock: str = "8MHz",
             lines: int | None = None, axes: Iterable[int] = (0,)) -> str:
    """A commented profile for a board on ``port`` with the chip selects ``axes``: the gains
    the CLI loads on a fresh simulator (kp = 20), no limits set (commented examples)."""
    out = ["# lm629 bench profile: `lm629 --profile FILE ...`, lm629_host.open_board(profile=FILE).",
           "# Counts are encoder counts (4 per line); velocities counts/s, accelerations counts/s^2.",
           "", "[board]",
           f"port = \"{port}\"" if port else "# port = \"/dev/ttyACM0\"      # any port URL",
           f"chip = \"{chip}\"", f"clock = \"{clock}\"", ""]
    for cs in axes:
        name = AXIS_NAMES[cs] if cs < len(AXIS_NAMES) else f"axis{cs}"
        out += [f"[axis.{name}]                   # `lm629 --axis {name}`, board[\"{name}\"]",
                f"cs = {cs}                       # its chip select",
                (f"lines = {lines}" if lines else "# lines = 500") +
                "                 # encoder lines: the CLI speaks revolutions and rpm",
                "kp = 20                      # filter: `lm629 tune --save` writes these",
                "ki = 0", "kd = 0", "il = 0",
                "ds = 1                       # derivative interval, samples",
                "# min = -20000               # soft travel limits, counts",
                "# max = 20000",
                "# max_velocity = 200000      # counts/s",
                "# max_acceleration = 4000000 # counts/s^2",
                "following_error = 2000       # counts: LPES, the motor stops beyond it",
                "# index_velocity = 2000      # counts/s for `index --search` (sign: direction)",
                "# note = \"\"", ""]
    return "\n".join(out)


__all__ = ["AXIS_KEYS", "BOARD_KEYS", "PLANT_KEYS", "AxisProfile", "Profile", "ProfileError", "apply_axis",
           "apply_profile", "attach", "ensure_applied", "key_lines", "load_profile", "name_axes",
           "parse_profile", "save_gains", "settings_lost", "template"]
