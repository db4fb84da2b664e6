"""A lab's benches from the command line (labgrid; docs/testing.md "A lab of benches").

``lm629 --place NAME COMMAND``: any command on the bench of a labgrid place instead of a port.
The place is acquired (locked) from the coordinator that ``LG_COORDINATOR`` names, its
``NetworkSerialPort`` (the exporter's ser2net) is opened as ``rfc2217://``, and the place is
released when the command ends, whichever way it ends (done, an error, Ctrl-C, SIGTERM).  A
place someone else holds is refused in one line naming the holder (labgrid's reason), exit 3,
before anything is sent.  ``NAME?fast_baud=115200&failsafe=0.5`` adds port URL options.

``lm629 lab selftest PATTERN``: the production test over a lab: ``lm629 --place NAME selftest
--report DIR/NAME.json`` on every place whose name matches the shell pattern, all at once (one
process per bench, each holding its own place; ``--chip``, ``--clock``, ``--lines`` and
``--profile`` given to ``lm629`` say what every bench should be), then one table: place, chip
(what the bench should be), verdict, differences.  The exit code is the worst bench's, as ``lm629 selftest``'s: 0 every bench
passed, 1 one differs, 10 one could not be tested to the end (FAIL, or NOT RUN: held by
someone else, no answer; each named in the table).

labgrid is driven through ``labgrid-client`` (:mod:`lm629_host.integrations.labgrid_place`):
labgrid lives in a virtual environment of its own.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import click

from lm629_host.bench.selftest import EXIT, Report
from lm629_host.cli.app import main
from lm629_host.integrations import labgrid_place

#: the columns of ``lab selftest``'s table
COLUMNS = ("place", "chip", "verdict", "differences")


@main.group()
def lab() -> None:
    """A labgrid lab's benches: the production test over every place (docs/testing.md)."""


@dataclass
class BenchRun:
    """One place's selftest: its process's end and the report it wrote."""

    place: str
    report: Path
    code: int | None = None
    output: str = ""

    def row(self) -> tuple[str, str, str, str]:
        if self.report.exists():
            data = json.loads(self.report.read_text())
            rep = Report.from_json(data)
            # a bench fault and the measurement it is judged on are one difference
            named = [f.line for f in rep.faults]
            named += [m.name for m in rep.differences if m.check not in named]
            diffs = str(len(named)) + (f" ({', '.join(named[:3])}"
                                       f"{', ...' if len(named) > 3 else ''})" if named else "")
            chip = str(data.get("profile", {}).get("chip", "?")).upper()
            return self.place, chip, rep.verdict, diffs
        last = [ln for ln in self.output.splitlines() if ln.strip()]
        why = last[-1].removeprefix("lm629: ") if last else f"exit {self.code}"
        return self.place, "-", "NOT RUN", why


#: the global options a lab's selftest hands to each bench's (what the benches are: their chip,
#: clock, encoder, profile), when given on the command line (LM629_PROFILE is inherited)
FORWARDED = (("chip_name", "--chip"), ("clock", "--clock"), ("lines", "--lines"),
             ("profile_path", "--profile"))


def _forwarded(ctx: click.Context) -> list[str]:
    root = ctx.find_root()
    out: list[str] = []
    for name, flag in FORWARDED:
        if root.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE:
            out += [flag, str(root.params[name])]
    return out


def _run_bench(run: BenchRun, options: list[str]) -> None:
    argv = [sys.executable, "-m", "lm629_host", *options, "--place", run.place, "selftest",
            "--report", str(run.report)]
    p = subprocess.run(argv, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    run.code, run.output = p.returncode, p.stdout + p.stderr
    run.report.with_suffix(".txt").write_text(run.output)


@lab.command("selftest")
@click.argument("pattern")
@click.option("--reports", "report_dir", default="lab-selftest", show_default=True,
              metavar="DIR", help="Where each bench's report goes: DIR/PLACE.json, .md (the "
                                  "summary to paste) and .txt (what the selftest printed).")
def lab_selftest(pattern: str, report_dir: str) -> None:
    """`lm629 selftest --report` on every place matching PATTERN (a shell pattern, quoted:
    'lm629-*'), in parallel, then one table: place, chip, verdict, differences.  --chip,
    --clock, --lines and --profile given before `lab` say what every bench should be."""
    names = labgrid_place.places(pattern)
    if not names:
        raise click.UsageError(f"no place matches {pattern!r} on the coordinator "
                               f"{labgrid_place.coordinator()} (labgrid-client places lists "
                               "them)")
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = [BenchRun(n, out / f"{n}.json") for n in names]
    for r in runs:  # a report of an earlier run is not this run's
        for suffix in (".json", ".md", ".txt"):
            r.report.with_suffix(suffix).unlink(missing_ok=True)
    click.echo(f"selftest on {len(runs)} place(s): {', '.join(names)}")
    options = _forwarded(click.get_current_context())
    threads = [threading.Thread(target=_run_bench, args=(r, options), daemon=True) for r in runs]
    for t in threads:
        t.start()
    try:
        for t in threads:
            t.join()
    except KeyboardInterrupt:
        # each bench's process had the signal too (one process group): it stops its motor and
        # releases its place; wait for that before this ends
        for t in threads:
            t.join(timeout=30)
        raise
    rows = [COLUMNS, *(r.row() for r in runs)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(COLUMNS) - 1)]
    for row in rows:
        click.echo("  ".join(c.ljust(w) for c, w in zip(row, widths)) + "  " + row[-1])
    click.echo(f"reports: {out}/PLACE.json (.md: the summary to paste)")
    # the worst bench's: PASS 0, DIFFERS 1, FAIL 10; a bench not tested (NOT RUN) is a FAIL
    code = max(EXIT.get(row[2], EXIT["FAIL"]) for row in rows[1:])
    if code:
        click.get_current_context().exit(code)


__all__ = ["lab", "lab_selftest"]
