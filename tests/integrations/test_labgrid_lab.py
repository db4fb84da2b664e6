"""A real labgrid lab on loopback (tests/integrations/labgrid_lab.py): a coordinator, two
exporters (two benches: the Python far end and the firmware in simavr, each a ``lm629 sim
serve --pty`` behind its exporter's ser2net), places made and locked with ``labgrid-client``.

What runs through it: the project's labgrid example against a ``RemotePlace`` (coordinator,
exporter, ser2net, RFC 2217), the driver's URL options passed through, ``lm629 --place NAME``
(acquired, opened as rfc2217://, released however the command ends), a place someone else
holds refused with labgrid's reason naming the holder, and ``lm629 lab selftest PATTERN`` over
every bench.  One lab for the module; at its end nothing it started may still run.

labgrid runs from its own venv (``LM629_LABGRID_PYTHON``, built by .ci/run); without it, or
without ser2net (Debian's, installed by .ci/run), the module is skipped and says why.

Why each test takes over 10 s: every ``labgrid-client`` call is a Python start and a gRPC
round trip (about 0.6 s here), every acquire starts the exporter's ser2net (it waits 0.5 s to
see it live) and every release stops it; the tests run what a lab's users would do at once
(both benches, two users) so that these waits overlap.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from labgrid_lab import SER2NET, cmdline, listening, running_lab
from lm629_host.bench.selftest import Report
from lm629_host.integrations.labgrid_place import parse_env_ports
from served import _console_script

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "labgrid"
PYTHON = os.environ.get("LM629_LABGRID_PYTHON", "")
#: someone else in the lab (labgrid names a user HOST/USER; LG_HOSTNAME, LG_USERNAME)
ALICE = "otherpc/alice"
#: place -> what it matches: the two benches, a spare port with no board behind it, and the
#: firmware bench exported by its link outside /dev/ (which the exporter will not serve)
PLACES = {"lm629-py": "bench-py/lm629-bench/*", "lm629-fw": "bench-fw/lm629-bench/*",
          "lm629-spare": "bench-py/lm629-spare/*", "link-fw": "bench-fw/lm629-link/*"}


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    if not PYTHON or not Path(PYTHON).exists():
        pytest.skip("labgrid lab not run: LM629_LABGRID_PYTHON does not name the python of a "
                    "labgrid venv (.ci/run builds .venv-labgrid)")
    if not Path(SER2NET).exists():
        pytest.skip("labgrid lab not run: ser2net is not installed (apt-get install ser2net; "
                    ".ci/run does)")
    tmp = tmp_path_factory.mktemp("lab")
    # the Python bench's chip runs at 6 MHz, the firmware bench's at 8: a lab selftest that
    # expects 6 MHz passes one and finds the other's clock wrong
    with running_lab(tmp, Path(PYTHON).parent, {"bench-py": ("python", "sim://?clock=6MHz"),
                                                "bench-fw": ("firmware", "sim://")}) as lab:
        lab.add_places(PLACES)
        yield lab


def lm629(lab, *args: str) -> subprocess.Popen[str]:
    """The installed ``lm629`` in this lab (LG_COORDINATOR set), labgrid-client on PATH,
    started (several run at once, as several users of a lab would)."""
    env = lab.env(PATH=f"{lab.bin}:{os.environ['PATH']}")
    return subprocess.Popen([_console_script(), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


def ended(proc: subprocess.Popen[str]) -> subprocess.CompletedProcess[str]:
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def labgrid_pytest(lab, where: Path, env_file: str, *tests: str) -> subprocess.Popen[str]:
    """labgrid's own pytest plugin (``--lg-env``), in labgrid's venv, started."""
    return subprocess.Popen([PYTHON, "-m", "pytest", "-p", "no:cacheprovider", "-q", "--lg-env",
                             env_file, *tests], cwd=where, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=lab.env())


def err_lines(p: subprocess.CompletedProcess[str]) -> list[str]:
    return [ln for ln in p.stderr.splitlines() if ln.strip()]


OPTIONS_TEST = '''
def test_options_reach_the_link(target):
    drv = target.get_driver("LM629Driver")
    assert drv.url.startswith("rfc2217://127.0.0.1:")
    assert "failsafe=0.3" in drv.url
    assert drv.chip().transport.failsafe_state().timeout_ms == 300
'''


def test_the_example_runs_on_remote_places_through_ser2net_on_loopback(lab, tmp_path):
    """examples/labgrid/ through labgrid's pytest plugin on both benches at once: RemotePlace
    -> coordinator -> exporter -> ser2net -> RFC 2217 -> the bench; on the firmware bench
    the driver's ``options:`` too (passed through to the port URL).  The exporter starts each
    bench's ser2net when its place is acquired, on 127.0.0.1 only (the wrapper; unwrapped it
    listens on every interface), and stops it on release."""
    assert not any(lab.ser2nets().values())  # nobody holds a place: no ser2net
    env_yaml = (EXAMPLE / "env-remote.yaml").read_text()
    assert "name: lm629-bench" in env_yaml and "LM629Driver: {}" in env_yaml
    runs, ports = {}, {}
    lab.client("-p", "lm629-py", "lock")
    lab.client("-p", "lm629-fw", "lock")
    try:
        running = lab.ser2nets()
        assert [len(running[e]) for e in ("bench-py", "bench-fw")] == [1, 1], running
        for place, bench in (("lm629-py", "bench-py"), ("lm629-fw", "bench-fw")):
            env_ports = parse_env_ports(lab.client("-p", place, "env").stdout)
            assert len(env_ports) == 1, env_ports
            port = ports[place] = env_ports[0]
            assert (port.host, port.speed, port.protocol) == ("127.0.0.1", 115200, "rfc2217")
            assert listening(port.port) == ["0100007F"]  # 127.0.0.1, and nothing else
            assert f",tcp,127.0.0.1,{port.port}" in cmdline(running[bench][0])
            assert f",{lab.exporters[bench].device}," in cmdline(running[bench][0])
            assert lab.exporters[bench].device.startswith("/dev/pts/")
        for place in ("lm629-py", "lm629-fw"):
            where = tmp_path / place
            where.mkdir()
            shutil.copy(EXAMPLE / "test_lab_bench.py", where)
            text = env_yaml.replace("name: lm629-bench", f"name: {place}")
            tests = ["test_lab_bench.py"]
            if place == "lm629-fw":
                text = text.replace("LM629Driver: {}", "LM629Driver: {options: {failsafe: 0.3}}")
                (where / "test_options.py").write_text(OPTIONS_TEST)
                tests.append("test_options.py")
            (where / "env.yaml").write_text(text)
            runs[place] = (labgrid_pytest(lab, where, "env.yaml", *tests), len(tests) + 1)
        for place, (proc, passed) in runs.items():
            out, _ = proc.communicate(timeout=300)
            assert proc.returncode == 0, f"{place}: {out}"
            assert re.search(rf"\b{passed} passed\b", out), out
    finally:
        for place in ("lm629-py", "lm629-fw"):
            lab.client("-p", place, "unlock")
    assert lab.held() == {}
    deadline = time.monotonic() + 10
    while any(listening(p.port) for p in ports.values()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert [listening(p.port) for p in ports.values()] == [[], []]


def test_a_port_outside_dev_is_not_served(lab):
    """docs/testing.md's /dev/ rule: a RawSerialPort named by a link elsewhere (the one
    ``sim serve --pty`` makes) cannot be acquired: the exporter's assertion marks it broken,
    and labgrid shows it acquired by '<broken>'; ``lm629 --place`` says so in one line."""
    cli = ended(lm629(lab, "--place", "link-fw", "status"))
    assert cli.returncode == 3 and len(err_lines(cli)) == 1, cli.stderr
    assert "already acquired by place '<broken>': the exporter could not serve it" in cli.stderr
    assert "must start with /dev/" in cli.stderr
    exporter_log = lab.exporters["bench-fw"].log.read_text()
    assert "AssertionError" in exporter_log and "marked as broken" in exporter_log
    again = lab.client("-p", "link-fw", "lock", check=False)
    assert again.returncode != 0 and "already acquired by place '<broken>'" in again.stdout
    assert lab.held() == {}


def test_a_place_someone_else_holds_is_refused_naming_them(lab, tmp_path):
    lab.client("-p", "lm629-fw", "lock", user=ALICE)
    try:
        (tmp_path / "env.yaml").write_text((EXAMPLE / "env-remote.yaml").read_text().replace(
            "name: lm629-bench", "name: lm629-fw"))
        shutil.copy(EXAMPLE / "test_lab_bench.py", tmp_path)
        theirs = labgrid_pytest(lab, tmp_path, "env.yaml", "test_lab_bench.py")
        cli = lm629(lab, "--place", "lm629-fw", "status")
        mine = lab.client("-p", "lm629-fw", "lock", check=False)
        assert mine.returncode != 0 and f"already acquired by {ALICE}" in mine.stderr
        p = ended(cli)
        assert p.returncode == 3, p.stdout + p.stderr  # EXIT_CODES: busy is a transport error
        assert p.stdout == ""
        assert len(err_lines(p)) == 1, p.stderr
        assert f"Place lm629-fw is already acquired by {ALICE}" in p.stderr
        # labgrid's own pytest plugin on that place: refused, labgrid's reason
        out, _ = theirs.communicate(timeout=300)
        assert theirs.returncode != 0
        assert f"not acquired by your user, acquired by {ALICE.split('/')[1]}" in out, out
        assert lab.held() == {"lm629-fw": ALICE}  # the refused users' exits left it alone
    finally:
        lab.client("-p", "lm629-fw", "unlock", user=ALICE)


def test_the_cli_on_a_place_releases_it_however_it_ends(lab):
    # a command that ends well, the place's options as a URL's (on one bench), and an error
    # after the place was acquired: a bad URL option, refused before anything moves (the other)
    good = lm629(lab, "--place", "lm629-py?failsafe=0.4", "status", "--json")
    bad = lm629(lab, "--place", "lm629-fw?fast_baud=fast", "status")
    p = ended(good)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["failsafe"]["armed_s"] == 0.4
    p = ended(bad)
    assert p.returncode == 2, p.stdout + p.stderr
    assert "fast_baud" in p.stderr and len(err_lines(p)) == 1, p.stderr
    assert lab.held() == {}
    # Ctrl-C and SIGTERM in a command that runs until stopped (watch), once each bench
    watching = {sig: lm629(lab, "--place", place, "watch")
                for sig, place in ((signal.SIGINT, "lm629-py"), (signal.SIGTERM, "lm629-fw"))}
    for proc in watching.values():
        assert proc.stdout.readline(), proc.stderr.read()  # watching: the port open
    assert set(lab.held()) == {"lm629-py", "lm629-fw"}
    for sig, proc in watching.items():
        proc.send_signal(sig)
    for sig, proc in watching.items():
        p = ended(proc)
        assert p.returncode == 128 + sig, p.stderr
    assert lab.held() == {}


def test_lab_selftest_over_every_bench(lab, tmp_path):
    """Both benches tested at once, as boards whose chips run at 6 MHz (--clock, handed to
    each bench's selftest), one report each, one table: the Python bench (6 MHz) passes, the
    firmware bench's 8 MHz chip differs (its clock, measured 8 MHz: 2048 / 8e6 s a sample,
    not 2048 / 6e6), the place someone else holds is named, not tested; the run's exit is the
    worst bench's (one not tested: 10, selftest FAIL's)."""
    lab.client("-p", "lm629-spare", "lock", user=ALICE)
    try:
        p = ended(lm629(lab, "--clock", "6MHz", "lab", "selftest", "lm629-*", "--reports",
                        str(tmp_path / "r")))
        assert lab.held() == {"lm629-spare": ALICE}
    finally:
        lab.client("-p", "lm629-spare", "unlock", user=ALICE)
    assert p.returncode == 10, p.stdout + p.stderr  # EXIT_CODES: a bench not tested to the end
    rows = {ln.split()[0]: ln for ln in p.stdout.splitlines() if ln.startswith("lm629-")}
    assert sorted(rows) == ["lm629-fw", "lm629-py", "lm629-spare"], p.stdout
    reports = {place: json.loads((tmp_path / "r" / f"{place}.json").read_text())
               for place in ("lm629-fw", "lm629-py")}
    for place, report in reports.items():
        assert report["transport"]["url"].startswith("rfc2217://127.0.0.1:")
        assert report["profile"]["clock_hz"] == 6e6
        assert (tmp_path / "r" / f"{place}.md").read_text().startswith("## lm629 selftest")
    assert reports["lm629-py"]["verdict"] == "PASS", (tmp_path / "r" / "lm629-py.txt").read_text()
    assert re.fullmatch(r"lm629-py\s+LM629\s+PASS\s+0", rows["lm629-py"]), p.stdout
    fw = Report.from_json(reports["lm629-fw"])
    clock = [m for m in fw.measurements if m.check == "clock"]
    assert len(clock) == 1 and abs(clock[0].measured - 8.0) < 0.08  # MHz: the chip's own
    assert fw.verdict == "DIFFERS" and [f.line for f in fw.faults] == ["clock"]
    assert [m.check for m in fw.differences] == ["clock"]  # the fault's own measurement
    assert re.fullmatch(r"lm629-fw\s+LM629\s+DIFFERS\s+1 \(clock\)", rows["lm629-fw"]), p.stdout
    assert re.match(r"lm629-spare\s+-\s+NOT RUN\s+.*already acquired by " + ALICE,
                    rows["lm629-spare"]), p.stdout
    assert re.search(r"^place\s+chip\s+verdict\s+differences$", p.stdout, re.M), p.stdout
