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

from labgrid_lab import SER2NET, listening, running_lab
from lm629_host.integrations.labgrid_place import parse_env_ports
from served import _console_script

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "labgrid"
PYTHON = os.environ.get("LM629_LABGRID_PYTHON", "")
#: someone else in the lab (labgrid names a user HOST/USER; LG_HOSTNAME, LG_USERNAME)
ALICE = "otherpc/alice"
#: place -> what it matches: the two benches, and a spare port with no board behind it
PLACES = {"lm629-py": "bench-py/lm629-bench/*", "lm629-fw": "bench-fw/lm629-bench/*",
          "lm629-spare": "bench-py/lm629-spare/*"}


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    if not PYTHON or not Path(PYTHON).exists():
        pytest.skip("labgrid lab not run: LM629_LABGRID_PYTHON does not name the python of a "
                    "labgrid venv (.ci/run builds .venv-labgrid)")
    if not Path(SER2NET).exists():
        pytest.skip("labgrid lab not run: ser2net is not installed (apt-get install ser2net; "
                    ".ci/run does)")
    tmp = tmp_path_factory.mktemp("lab")
    with running_lab(tmp, Path(PYTHON).parent,
                     {"bench-py": "python", "bench-fw": "firmware"}) as lab:
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


def test_ser2net_serves_a_locked_place_on_loopback_only(lab):
    """The exporter starts ser2net when the place is acquired (the wrapper keeps it on
    127.0.0.1; unwrapped it listens on every interface) and stops it on release."""
    assert not any(lab.ser2nets().values())  # nobody holds a place: no ser2net
    lab.client("-p", "lm629-py", "lock")
    try:
        ports = parse_env_ports(lab.client("-p", "lm629-py", "env").stdout)
        assert len(ports) == 1 and ports[0].host == "127.0.0.1" and ports[0].speed == 115200
        assert ports[0].protocol == "rfc2217"
        assert listening(ports[0].port) == ["0100007F"]  # 127.0.0.1, and nothing else
        running = lab.ser2nets()
        assert len(running["bench-py"]) == 1 and running["bench-fw"] == []
        exp = lab.exporters["bench-py"]
        show = lab.client("-p", "lm629-py", "show").stdout
        assert f"'path': '{exp.device}'" in show and exp.device.startswith("/dev/pts/")
    finally:
        lab.client("-p", "lm629-py", "unlock")
    deadline = time.monotonic() + 10
    while listening(ports[0].port) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert listening(ports[0].port) == []


OPTIONS_TEST = '''
def test_options_reach_the_link(target):
    drv = target.get_driver("LM629Driver")
    assert drv.url.startswith("rfc2217://127.0.0.1:")
    assert "failsafe=0.3" in drv.url
    assert drv.chip().transport.failsafe_state().timeout_ms == 300
'''


def test_the_example_runs_on_a_remote_place(lab, tmp_path):
    """examples/labgrid/ through labgrid's pytest plugin on both benches at once: RemotePlace
    -> coordinator -> exporter -> ser2net -> RFC 2217 -> the bench; on the firmware bench
    the driver's ``options:`` too (passed through to the port URL)."""
    env_yaml = (EXAMPLE / "env-remote.yaml").read_text()
    assert "name: lm629-bench" in env_yaml and "LM629Driver: {}" in env_yaml
    runs = {}
    lab.client("-p", "lm629-py", "lock")
    lab.client("-p", "lm629-fw", "lock")
    try:
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
    """Both benches tested at once, one report each, one table; a place someone else holds
    is named in the table, not tested, and the run's exit says a bench was not passed."""
    lab.client("-p", "lm629-spare", "lock", user=ALICE)
    try:
        p = ended(lm629(lab, "lab", "selftest", "lm629-*", "--reports", str(tmp_path / "r")))
        assert lab.held() == {"lm629-spare": ALICE}
    finally:
        lab.client("-p", "lm629-spare", "unlock", user=ALICE)
    assert p.returncode == 1, p.stdout + p.stderr
    rows = {ln.split()[0]: ln for ln in p.stdout.splitlines() if ln.startswith("lm629-")}
    assert sorted(rows) == ["lm629-fw", "lm629-py", "lm629-spare"], p.stdout
    for place in ("lm629-fw", "lm629-py"):
        assert re.fullmatch(rf"{place}\s+LM629\s+PASS\s+0", rows[place]), p.stdout
        report = json.loads((tmp_path / "r" / f"{place}.json").read_text())
        assert report["verdict"] == "PASS" and report["transport"]["url"].startswith("rfc2217://")
        assert (tmp_path / "r" / f"{place}.md").read_text().startswith("## lm629 selftest")
    assert re.match(r"lm629-spare\s+-\s+NOT RUN\s+.*already acquired by " + ALICE,
                    rows["lm629-spare"]), p.stdout
    assert re.search(r"^place\s+chip\s+verdict\s+differences$", p.stdout, re.M), p.stdout
