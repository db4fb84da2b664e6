"""``lm629 selftest``: the chip and the board against the profile and the model
(:mod:`lm629_host.bench.selftest`; docs/selftest.md), ``--report FILE`` and ``--compare FILE``."""

from __future__ import annotations

import click

from lm629_host.bench.selftest import (
    EXIT,
    Options,
    Report,
    compare,
    load_report,
    run,
    write_report,
)
from lm629_host.cli.app import _session, axis_name, log, main
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
    encoder and the index).  Exit 0 PASS, 1 DIFFERS (a difference or a bench fault, each
    named), 2 FAIL (it could not finish)."""
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
        ctx.exit(1 if lines else 0)
    s = _session()
    chip = s.open(prepare=False)
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
    if motion and not yes and not _abort_is_interrupt(lambda: click.confirm(
            "--motion turns the motor slowly for up to two revolutions: go?", default=False)):
        click.echo("nothing moved")
        ctx.exit(1)
    report = run(chip, options, progress=lambda text: log.info("selftest: %s", text))
    show(report)
    if report_path is not None:
        md = write_report(report, report_path)
        click.echo(f"report: {report_path} (summary to paste into an issue: {md})")
    ctx.exit(report.exit_code)


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
    busy = report.busy_option()
    _line(None, "busy", f"after the command byte, us: {busy.replace(',', ' ')}" if busy
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
