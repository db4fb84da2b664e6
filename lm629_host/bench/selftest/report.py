"""The selftest's report: what was measured against what the model expects
(:class:`Measurement`), the bench faults named with their fix (:class:`Fault`), the verdict
and its exit code (:class:`Report`, :data:`EXIT`), its JSON form (:data:`SCHEMA`,
:func:`validate`), the files a user sends (:func:`write_report`, :func:`summary_markdown`) and
reads back (:func:`load_report`).

Why a module of its own: the report is data that outlives the run; ``--compare`` and
``lm629 lab`` read it with no chip and no model anywhere near.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any


#: the version of the report's JSON form (:data:`SCHEMA`); 2 added ``busy_resolution_us``
#: (a version 1 report is still read: its busy times are then shown, never compared)
SCHEMA_VERSION = 2

#: a measured clock further than this from the profile's is a bench fault (crystals are
#: within 0.01 %; the measurement within 0.5 % on a busy host)
CLOCK_TOLERANCE = 0.03

#: the verdicts and their exit codes (rows of the CLI's one table, ``lm629_host.cli.EXIT_CODES``:
#: 1 is every check's "found a problem", 10 the selftest's own "could not finish"; 2 is bad
#: usage, never a verdict)
EXIT = {"PASS": 0, "DIFFERS": 1, "FAIL": 10}


@dataclass
class Measurement:
    """One thing measured, with what the model expects.  ``name`` is unique in a report (the
    step and the read); ``command`` the bus commands of the step up to this read; ``at`` the
    chip time base of a timed read (the desired position both sides were read at) and
    ``sample`` the model's samples since the step's STT there.  ``judged`` False: shown, never
    a difference (busy times: the transport's own overhead is in them)."""

    check: str  #: "core", "clock", "wiring", "busy"
    name: str
    command: str
    measured: Any
    expected: Any
    at: int | None = None
    sample: int | None = None
    judged: bool = True
    unit: str = ""

    @property
    def differs(self) -> bool:
        if not self.judged or self.measured is None:
            return False
        if self.check == "clock":
            return abs(self.measured - self.expected) > CLOCK_TOLERANCE * self.expected
        return bool(self.measured != self.expected)

    def show(self, value: Any) -> str:
        if isinstance(value, bool) or value is None:
            return str(value)
        if isinstance(value, int) and self.unit == "hex":
            return f"{value & 0xFFFF:04X}" if -0x8000 <= value <= 0xFFFF else f"{value:X}"
        if isinstance(value, float):
            return f"{value:.6g}{(' ' + self.unit) if self.unit else ''}"
        return f"{value}{(' ' + self.unit) if self.unit and self.unit != 'hex' else ''}"


@dataclass
class Fault:
    """A bench fault named with its fix: ``line`` is "clock", "HI", "index", "encoder" or
    "cs N"."""

    line: str
    message: str
    fix: str


@dataclass
class Report:
    """Everything one selftest found (its JSON form: :data:`SCHEMA`)."""

    versions: dict[str, str]
    transport: dict[str, str]
    profile: dict[str, Any]
    motion: bool
    measurements: list[Measurement] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)
    #: why the script could not run to its end (None: it did)
    error: str | None = None
    schema: int = SCHEMA_VERSION
    #: the busy instrument's resolution, us: a busy time measured as ``command; wait;
    #: status`` is the shortest wait that reads busy clear, and the transport's own time
    #: between the wait and the status read (``Transport.busy_probe_us``) is in it, so the
    #: chip's busy time lies within [measured - 1, measured + this] (None: not stated)
    busy_resolution_us: int | None = None

    @property
    def differences(self) -> list[Measurement]:
        return [m for m in self.measurements if m.differs]

    @property
    def verdict(self) -> str:
        if self.error is not None:
            return "FAIL"
        return "DIFFERS" if self.faults or self.differences else "PASS"

    @property
    def exit_code(self) -> int:
        return EXIT[self.verdict]

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["verdict"] = self.verdict
        return d

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Report:
        """The report of :meth:`to_json`; ValueError listing what does not fit :data:`SCHEMA`."""
        problems = validate(data)
        if problems:
            raise ValueError("not a selftest report: " + "; ".join(problems[:5]))
        return cls(data["versions"], data["transport"], data["profile"], data["motion"],
                   [Measurement(**m) for m in data["measurements"]],
                   [Fault(**f) for f in data["faults"]], data["error"], data["schema"],
                   data.get("busy_resolution_us"))

    def busy_option(self) -> str:
        """The measured busy times as ``sim://?busy=`` takes them ("": none seen)."""
        seen = [m for m in self.measurements if m.check == "busy" and m.measured is not None]
        return ",".join(f"{m.name.split(': ')[1]}:{m.measured:g}" for m in seen)


def worst(verdicts: Sequence[str]) -> str:
    """The verdict of several selftests (a profile's axes): FAIL before DIFFERS before PASS."""
    order = ["PASS", "DIFFERS", "FAIL"]
    return max(verdicts, key=order.index, default="PASS")


#: the report's JSON form: every key, its type, and for the lists the keys of an item (types:
#: "str", "int", "bool", "dict", "list", "any", "str|null"...); :func:`validate` checks it
SCHEMA: dict[str, Any] = {
    "schema": "int",  # SCHEMA_VERSION
    "verdict": "str",  # PASS, DIFFERS or FAIL
    "versions": "dict",  # lm629_host, python, platform
    "transport": "dict",  # url, describe
    "profile": "dict",  # chip, clock_hz, cs, lines, path
    "motion": "bool",
    "error": "str|null",
    "busy_resolution_us": "int|null",  # us (schema 2 on; a version 1 report has none)
    "faults": [{"line": "str", "message": "str", "fix": "str"}],
    "measurements": [{"check": "str", "name": "str", "command": "str", "measured": "any",
                      "expected": "any", "at": "int|null", "sample": "int|null",
                      "judged": "bool", "unit": "str"}],
}


#: the keys a version 1 report does not have
_ADDED_IN_2 = ("busy_resolution_us",)


_TYPES: dict[str, tuple[type, ...]] = {"str": (str,), "int": (int,), "bool": (bool,),
                                       "dict": (dict,), "null": (type(None),)}


def _fits(value: Any, kind: str) -> bool:
    if kind == "any":
        return True
    ok = any(isinstance(value, _TYPES[k]) for k in kind.split("|"))
    return ok and not (kind.startswith("int") and isinstance(value, bool))


def validate(data: Any) -> list[str]:
    """What in ``data`` does not fit :data:`SCHEMA` (empty: a valid report)."""
    if not isinstance(data, dict):
        return ["the report is not a JSON object"]
    optional = _ADDED_IN_2 if data.get("schema") == 1 else ()
    problems = [f"missing key {k!r}" for k in SCHEMA if k not in data and k not in optional]
    problems += [f"unknown key {k!r}" for k in data if k not in SCHEMA]
    for key, kind in SCHEMA.items():
        if key not in data:
            continue
        if isinstance(kind, list):
            if not isinstance(data[key], list):
                problems.append(f"{key} is not a list")
                continue
            for i, item in enumerate(data[key]):
                if not isinstance(item, dict) or set(item) != set(kind[0]):
                    problems.append(f"{key}[{i}] does not have the keys {sorted(kind[0])}")
                    continue
                problems += [f"{key}[{i}].{k} is not {t}" for k, t in kind[0].items()
                             if not _fits(item[k], t)]
        elif not _fits(data[key], kind):
            problems.append(f"{key} is not {kind}")
    if not problems and data["schema"] not in (1, SCHEMA_VERSION):
        problems.append(f"schema {data['schema']}: this version reads 1 and {SCHEMA_VERSION}")
    if not problems and data["verdict"] not in EXIT:
        problems.append(f"verdict {data['verdict']!r} is not one of {', '.join(EXIT)}")
    return problems


def summary_markdown(report: Report) -> str:
    """A short Markdown summary a user can paste into an issue."""
    out = [f"## lm629 selftest: {report.verdict}", "",
           f"* lm629_host {report.versions['lm629_host']}, Python {report.versions['python']}",
           f"* transport: `{report.transport['describe']}`",
           f"* profile: {report.profile['chip'].upper()} at {report.profile['clock_hz'] / 1e6:g} "
           f"MHz, cs {report.profile['cs']}, motion {'on' if report.motion else 'off'}",
           f"* {len(report.measurements)} measurements, {len(report.differences)} differ"]
    if report.error:
        out.append(f"* could not finish: {report.error}")
    for f in report.faults:
        out.append(f"* **{f.line}**: {f.message}; fix: {f.fix}")
    if report.differences:
        out += ["", "| measurement | commands | chip | model |", "|---|---|---|---|"]
        out += [f"| {m.name} | `{m.command}` | {m.show(m.measured)} | {m.show(m.expected)} |"
                for m in report.differences[:20]]
    busy = report.busy_option()
    if busy:
        within = ("" if report.busy_resolution_us is None else
                  f" (each -1 to +{report.busy_resolution_us} us: this transport's resolution)")
        out += ["", f"The model with this chip's busy times{within}: `sim://?busy={busy}`"]
    return "\n".join(out) + "\n"


def write_report(report: Report, path: str) -> str:
    """Write the JSON report to ``path`` and the Markdown summary beside it (``.md``);
    returns the summary's path."""
    from pathlib import Path
    target = Path(path)
    target.write_text(json.dumps(report.to_json(), indent=1) + "\n")
    md = target.with_suffix(".md")
    md.write_text(summary_markdown(report))
    return str(md)


def load_report(path: str) -> Report:
    """A report written by :func:`write_report`; ValueError naming the file and what is wrong."""
    from pathlib import Path
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    try:
        return Report.from_json(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


__all__ = ["CLOCK_TOLERANCE", "EXIT", "Fault", "Measurement", "Report", "SCHEMA", "SCHEMA_VERSION",
           "load_report", "summary_markdown", "validate", "worst", "write_report"]
