"""``lm629 selftest``: the chip and the board against the profile and the model
(:mod:`lm629_host.bench.selftest`; docs/selftest.md), ``--report FILE`` and ``--compare FILE``."""

from __future__ import annotations

from pathlib import Path

import click

from lm629_host.bench.selftest import (
    EXIT,
    INDEX_AT_REST,
    Options,
    Report,
    compare,
    load_report,
    run,
    worst,
    write_report,
)
from lm629_host.chip.lm629 import LM629
from lm629_host.cli.app import EXIT_DECLINED, Session, _session, axes_of, axis_name, board, log, main, several
from lm629_host.cli.common import _abort_is_interrupt

#: how many differences the one-screen verdict lists (the report holds them all)
SHOWN = 8


@main.command()
@click.option("--motion", is_flag=True,
              help="Also turn the motor (slowly, about two turns at most): the encoder "
                   "counting and the index pulse.")
@click.option("--yes", "-y", is_flag=True, help="With --motion: do not ask before the motor "
                                                "turns (scripts).")
@click.option("--report", "report_path", default=None, metavar="FILE",
              help="Write the JSON report to FILE and a Markdown summary beside it (.md).")
@click.option("--compare", "compare_path", default=None, metavar="FILE",
              help="Show a saved report against today's model (opens no port).")
def selftest(motion: bool, yes: bool, report_path: str | None,
             compare_path: str | None) -> None:
    """Is this chip and this board what the profile says: the digital core command by command
    against the model, the clock, HI, the chip selects, busy times (and with --motion the
    encoder and the index).  A profile's axes are each tested in turn (or the one --axis
    names; --report FILE then writes FILE-NAME.json per axis).  Exit 0 PASS, 1 DIFFERS (a
    difference or a bench fault, each named), 10 FAIL (it could not finish); several axes:
    the worst.  --motion's prompt answered no: 130, nothing moved."""
    ctx = click.get_current_context()
    if compare_path is not None:
        if report_path is not None or motion:
            raise click.UsageError("--compare reads a saved report: give it alone")
        try:
            saved = load_report(compare_path)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--compare") from None
        lines = compare(saved)
        click.echo(f"{compare_path} ({saved.verdict} on {saved.transport['describe']}) against "
                   "today's model:")
        for line in lines:
            click.echo(f"  {line}")
        click.echo("  no differences" if not lines else f"{len(lines)} difference(s)")
        ctx.exit(EXIT["DIFFERS"] if lines else EXIT["PASS"])
    s = _session()
    if several(s):  # a profile's (or --axis's) axes, one after the other
        s.prepare = False
        chips = [board(s).axis(k) for k in axes_of(s)]
    else:
        chips = [s.open(prepare=False)]
    if motion and not yes and not _abort_is_interrupt(lambda: click.confirm(
            f"--motion turns the motor{'s' if len(chips) > 1 else ''} slowly for up to two "
            "revolutions: go?", default=False)):
        click.echo("nothing moved")
        ctx.exit(EXIT_DECLINED)
    verdicts = []
    for chip in chips:
        path = report_path
        if report_path is not None and len(chips) > 1:
            path = _axis_path(report_path, axis_name(s, chip.chip_select))
        verdicts.append(_one(s, chip, motion, path))
    ctx.exit(EXIT[worst(verdicts)])


def _axis_path(path: str, name: str) -> str:
    """The report of one of several axes: ``bench.json`` -> ``bench-x.json``."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{name}{p.suffix or '.json'}"))


def _one(s: Session, chip: LM629, motion: bool, report_path: str | None) -> str:
    """The selftest of one axis, shown; its verdict."""
    prof = s.profile
    ax = prof.by_cs(chip.chip_select) if prof is not None else None
    gains = {k: v for k, v in (ax.gains() if ax is not None else {}).items() if v is not None}
    if "kp" not in gains:
        gains["kp"] = 20
    lines_ = s.lines or (ax.lines if ax is not None and ax.lines else None) or 500
    options = Options(s.clock_hz, s.chip_name,
                      tuple(sorted({a.cs for a in prof.axes.values()})) if prof else (),
                      motion, lines_, gains, str(prof.path) if prof is not None else None)
    on = f"axis {axis_name(s, chip.chip_select)} (cs {chip.chip_select}), " if prof else ""
    click.echo(f"selftest of {on}{s.chip_name.upper()} on {chip.transport.describe()}; "
               f"profile: {s.chip_name.upper()} at {s.clock_hz / 1e6:g} MHz"
               f"{'' if motion else '; motor off'}")
    report = run(chip, options, progress=lambda text: log.info("selftest: %s", text))
    show(report)
    if report_path is not None:
        md = write_report(report, report_path)
        click.echo(f"report: {report_path} (summary to paste into an issue: {md})")
    return report.verdict


def _line(ok: bool | None, name: str, text: str) -> None:
    mark = {True: ("ok", "green"), False: ("!!", "red"), None: ("--", "yellow")}[ok]
    click.echo(f"  [{click.style(mark[0], fg=mark[1])}] {name:8s} {text}")


def show(report: Report) -> None:
    """The one-screen verdict."""
    ms = report.measurements
    core = [m for m in ms if m.check == "core"]
    differ = [m for m in core if m.differs]
    _line(not differ if core else None, "core",
          f"{len(core)} reads compared with the model: "
          f"{'all equal' if not differ else f'{len(differ)} differ'}" if core else "not run")
    clock = next((m for m in ms if m.check == "clock"), None)
    _line(None if clock is None else not clock.differs, "clock",
          "not measured" if clock is None else
          f"measured {clock.measured:.3f} MHz, profile {clock.expected:g} MHz")
    hi = next((m for m in ms if m.name.endswith("past the breakpoint: HI pin")), None)
    _line(None if hi is None or hi.measured is None else not hi.differs, "HI",
          "not seen by this adapter" if hi is not None and hi.measured is None else
          "not checked" if hi is None else
          "seen on the breakpoint interrupt" if hi.measured else "low on the breakpoint interrupt")
    for m in ms:
        if m.check == "wiring" and (m.name.startswith("cs ") or m.name.startswith("motion: ")):
            what, _, check = m.name.partition(": ")
            _line(not m.differs, what, check + ("" if m.measured else ": NO"))
    if not report.motion:
        _line(None, "motion", "encoder and index not checked (--motion turns the motor)")
    if any(m.name == INDEX_AT_REST and m.measured for m in ms):
        _line(None, "index", "the shaft rests on the index (the model's is put under its shaft)")
    busy = report.busy_option()
    res = report.busy_resolution_us
    _line(None, "busy", f"after the command byte, us: {busy.replace(',', ' ')}"
          f"{'' if res is None else f' (each -1/+{res})'}" if busy
          else "not seen by this transport (it waits out busy itself)")
    for f in report.faults:
        click.echo(f"  {f.line}: {f.message}")
        click.echo(f"    fix: {f.fix}")
    for m in report.differences[:SHOWN]:
        if m.check != "core":
            continue
        when = f" at sample {m.sample} (desired position {m.at})" if m.at is not None else ""
        click.echo(f"  differs: {m.name}{when}: chip {m.show(m.measured)}, model "
                   f"{m.show(m.expected)} after `{m.command}`")
    if report.error:
        click.echo(f"  could not finish: {report.error}")
    click.echo(f"verdict: {report.verdict}")


__all__ = ["EXIT", "selftest", "show"]
