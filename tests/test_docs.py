"""The docs are executed: every Python block and every command line of README.md and docs/*.md.

Python blocks (```python) run through sybil, one namespace per document, in a working
directory of the document's own.  Command lines are transcripts in ```console blocks::

    $ lm629 --lines 500 calc --rpm 3000      # a comment is the shell's
    velocity ... {n} ...                     # expected output, optional; {n} is any number,
    ...                                      # `...` alone any lines, inside a line any text
    [exit 1]                                 # the exit code, when it is not 0

A command whose comment says ``not run by the tests: REASON`` is counted as skipped, with
that reason; so is a block below a line ``*Not run by the tests: REASON.*``.  A ```toml block
is a bench profile and is loaded with :func:`lm629_host.config.profile.load_profile`; a
```yaml block whose first line is ``# NAME.yaml`` (or ``##``) is written to that file for the commands
after it (a labgrid exporter's configuration).  The lab's commands (labgrid-coordinator,
-exporter, -client, ``lm629 --place``) run with labgrid's venv (``LM629_LABGRID_PYTHON``) last
on PATH, an exporter's ser2net kept on loopback (tests/labgrid_lab.py), and the coordinator's
``127.0.0.1:20408`` a free port.

Ports stand in for the bench the block names: ``/dev/ttyACM0`` (and ``/dev/ttyUSB0``) is one
``lm629 sim serve`` for the whole document (two axes, the Python far end), ``socket://H:P`` and
``--tcp P`` a free port (the block starts its own server, as the docs say), ``ftdi://...``
``sim+ftdi://``, ``/tmp/lm629`` a path in the document's directory.  ``sudo``, ``udevadm`` and
``usermod`` are stand-ins that print what they were asked, and /etc/udev/rules.d/ is a
directory of the test's: the docs' udev lines run without changing this machine.
"""

from __future__ import annotations

import os
import re
import signal
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from sybil import Sybil
from sybil.parsers.markdown import CodeBlockParser

from lm629_host.sim.harness import toolchain_missing
from labgrid_lab import SER2NET, SER2NET_LOOPBACK
from served import _console_script

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
NOT_RUN = re.compile(r"not run by the tests: ([^*]+?)\.?\*?\s*$", re.IGNORECASE)
STANDINS = {"sudo": 'exec "$@"', "udevadm": 'echo "udevadm $*"', "usermod": 'echo "usermod $*"'}


@dataclass
class DocState:
    """One document's bench: its directory, environment, served board and background jobs."""

    path: Path
    tmp: Path
    env: dict[str, str]
    bench: subprocess.Popen | None = None
    link: Path | None = None
    ports: dict[str, str] = field(default_factory=dict)
    jobs: list[subprocess.Popen] = field(default_factory=list)

    def serial(self) -> str:
        """The served two-axis bench standing in for /dev/ttyACM0 (started on first use)."""
        if self.bench is None:
            self.link = self.tmp / "bench"
            self.bench = subprocess.Popen(
                [_console_script(), "sim", "serve", "--pty", str(self.link), "--url", "sim://?axes=2"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=self.env)
            banner = self.bench.stdout.readline()
            assert banner.startswith("serving "), banner + self.bench.stderr.read()
        return f"serial://{self.link}"

    def tcp_port(self, number: str) -> str:
        if number not in self.ports:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                self.ports[number] = str(s.getsockname()[1])
        return self.ports[number]

    def rewrite(self, text: str) -> str:
        """The block's text with this machine's stand-ins for the ports it names."""
        if re.search(r"/dev/tty(ACM|USB)0", text):
            text = re.sub(r"(serial://)?/dev/tty(ACM|USB)0", self.serial(), text)
        text = re.sub(r"ftdi://ftdi:232h[^\s'\")]*", "sim+ftdi://", text)
        text = re.sub(r"(socket://[\w.]+:|--tcp |127\.0\.0\.1:(?=20408\b))(\d+)",
                      lambda m: m[1] + self.tcp_port(m[2]), text)
        text = text.replace("/tmp/lm629", str(self.tmp / "lm629"))
        return text.replace("/etc/udev/rules.d/", str(self.tmp / "rules.d") + "/")

    def close(self) -> None:
        """Every process told first, then each waited for: a labgrid exporter takes seconds
        to stop its ser2net ("about a second to react", labgrid's own comment), and the
        page's other servers stop meanwhile instead of after it."""
        procs = [*self.jobs, *([self.bench] if self.bench else [])]
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.communicate()


_STATES: dict[Path, DocState] = {}
#: the user property each block's report carries: (examples run, examples not run); the run's
#: summary line adds them up from the reports (tests/conftest.py), on every xdist worker's
DOCS_PROPERTY = "docs_examples"


def _state(path: Path, tmp_factory: pytest.TempPathFactory) -> DocState:
    if path not in _STATES:
        tmp = tmp_factory.mktemp(path.stem)
        bin_dir = tmp / "bin"
        bin_dir.mkdir()
        for name, body in STANDINS.items():
            (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
            (bin_dir / name).chmod(0o755)
        (tmp / "rules.d").mkdir()
        for name in ("examples", "firmware_bridge"):
            (tmp / name).symlink_to(ROOT / name)
        if Path(SER2NET).exists():  # a labgrid exporter's ser2net, on loopback (docs/testing.md)
            (bin_dir / "ser2net").write_text(SER2NET_LOOPBACK)
            (bin_dir / "ser2net").chmod(0o755)
        env = {k: v for k, v in os.environ.items()
               if not k.startswith(("LM629_", "PYTEST_", "LG_"))}
        lab_bin = (f":{Path(os.environ['LM629_LABGRID_PYTHON']).parent}"
                   if os.environ.get("LM629_LABGRID_PYTHON") else "")  # after the main venv's
        env.update(PATH=f"{bin_dir}:{Path(_console_script()).parent}:{env.get('PATH', '')}{lab_bin}",
                   EDITOR="true", HOME=str(tmp), PYTEST_ADDOPTS="-p no:cacheprovider",
                   MPLBACKEND="Agg", COLUMNS="100")
        env["LM629_DOCS_TEST"] = "1"
        _STATES[path] = DocState(path, tmp, env)
    return _STATES[path]


# ------------------------------------------------------------------ transcripts
def _line_pattern(expected: str) -> re.Pattern[str]:
    out = re.escape(expected.rstrip())
    out = out.replace(r"\{n\}", r"[-+]?\d[\d.,]*(e[-+]?\d+)?").replace(r"\.\.\.", ".*")
    return re.compile(out + r"\s*$")


def _matches(expected: list[str], actual: list[str]) -> bool:
    """``expected`` (``...`` alone: any lines) against every line of ``actual``."""
    if not expected:
        return not actual
    head, rest = expected[0], expected[1:]
    if head.strip() == "...":
        return any(_matches(rest, actual[i:]) for i in range(len(actual) + 1))
    return bool(actual) and bool(_line_pattern(head).match(actual[0])) and _matches(rest, actual[1:])


@dataclass
class Command:
    line: int
    text: str
    expected: list[str]
    exit: int = 0
    skip: str | None = None


def parse_transcript(text: str, first_line: int) -> list[Command]:
    commands: list[Command] = []
    for i, raw in enumerate(text.splitlines()):
        if raw.startswith("$ "):
            cmd = raw[2:]
            while cmd.endswith("\\"):
                raise AssertionError(f"line {first_line + i}: join continued lines into one command")
            m = NOT_RUN.search(cmd)
            commands.append(Command(first_line + i, cmd, [], skip=m[1] if m else None))
        elif m := re.fullmatch(r"\[exit (\d+)\]\s*", raw):
            commands[-1].exit = int(m[1])
        elif commands:
            commands[-1].expected.append(raw)
        elif raw.strip():
            raise AssertionError(f"line {first_line + i}: a console block starts with `$ `")
    return commands


def _cannot_run(text: str) -> str | None:
    """Why a command cannot run on this machine (tools the docs name as needed), else None."""
    if text.startswith("make ") or "--firmware" in text or "sim+avr://" in text:
        missing = toolchain_missing()
        if missing:
            return f"the AVR toolchain is missing ({', '.join(missing)})"
    if LAB_WORDS.search(text) and not os.environ.get("LM629_LABGRID_PYTHON"):
        return "labgrid needs its own venv (LM629_LABGRID_PYTHON, built by .ci/run)"
    if LAB_WORDS.search(text) and not Path(SER2NET).exists():
        return f"a labgrid exporter needs ser2net ({SER2NET}: apt-get install ser2net)"
    return None


#: commands that need labgrid (its own venv) and a labgrid exporter's ser2net
LAB_WORDS = re.compile(r"--lg-env|\blabgrid-|--place\b|\blab selftest\b|\bser2net\b")
#: what a server started in the background (``&``) prints once it serves: ``lm629 sim serve``,
#: labgrid's coordinator and exporter (once it is connected to the coordinator)
READY = re.compile(r"^serving |Coordinator ready|connected to coordinator")


def _start_job(st: DocState, cmd: Command, text: str) -> None:
    """A server the next lines use, its output in a file (a labgrid exporter logs on every
    acquire: a pipe nobody reads would fill); ready once it prints :data:`READY`."""
    log = st.tmp / f"job{len(st.jobs)}.log"
    with log.open("w") as out:
        job = subprocess.Popen(["bash", "-c", "exec " + text.split("&")[0]], cwd=st.tmp,
                               env=st.env, stdout=out, stderr=subprocess.STDOUT, text=True)
    st.jobs.append(job)
    deadline = time.monotonic() + 60
    while not any(READY.search(ln) for ln in log.read_text().splitlines()):
        assert job.poll() is None and time.monotonic() < deadline, (
            f"{st.path.name}:{cmd.line}: {cmd.text}: not serving: {log.read_text()}")
        time.sleep(0.05)


def run_command(st: DocState, cmd: Command) -> None:
    if re.search(r"#\s*run by CI \(\.ci/run\)\s*$", cmd.text):  # CI runs this very line
        ci = re.sub(r"\\\n\s*", "", (ROOT / ".ci" / "run").read_text())
        line = cmd.text.split("#")[0].strip()
        assert line in ci, f"{st.path.name}:{cmd.line}: .ci/run no longer runs `{line}`"
        return
    text = st.rewrite(cmd.text)
    if "--lg-env" in text:  # labgrid's pytest, in its venv; the example's port is this bench's
        lab = st.tmp / "labgrid"
        if not lab.exists():
            shutil.copytree(ROOT / "examples" / "labgrid", lab)
            env_file = lab / "env-sim.yaml"
            env_file.write_text(env_file.read_text().replace("5629", st.tcp_port("5629")))
        text = text.replace("cd examples/labgrid", f"cd {lab}").replace(
            "pytest ", f"{os.environ['LM629_LABGRID_PYTHON']} -m pytest ")
    if m := re.fullmatch(r"export (\w+)=(\S+)(\s+#.*)?", text.strip()):
        st.env[m[1]] = m[2]
        return
    argv = ["bash", "-o", "pipefail", "-c", text]
    if text.rstrip().split("#")[0].rstrip().endswith("&"):  # a server the next lines use
        if any(job.args[-1] == "exec " + text.split("&")[0] for job in st.jobs):
            return  # still serving from an earlier block, as in the reader's shell
        _start_job(st, cmd, text)
        return
    serves = cmd.expected[:1] and cmd.expected[0].startswith("http://127.0.0.1:")  # lm629 panel
    if re.search(r"\bsim serve\b", text) or serves:  # serves until Ctrl-C: its banner (the
        # panel's: its address), then Ctrl-C
        job = subprocess.Popen(argv, cwd=st.tmp, env=st.env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, start_new_session=True)
        banner = job.stdout.readline()
        os.killpg(job.pid, signal.SIGINT)
        rest, _ = job.communicate(timeout=20)
        served = banner.startswith(("serving ", "http://127.0.0.1:"))
        out, code = banner + rest, 0 if served else job.returncode
    else:
        p = subprocess.run(argv, cwd=st.tmp, env=st.env, input="y\n" * 8, capture_output=True,
                           text=True, timeout=120)
        out, code = p.stdout + p.stderr, p.returncode
    where = f"{st.path.name}:{cmd.line}: $ {cmd.text}"
    assert code == cmd.exit, f"{where}\nexit {code}, the doc says {cmd.exit}:\n{out}"
    if cmd.expected:
        actual = [ln for ln in out.splitlines() if not ln.startswith("lm629: no --port")]
        expected = [ln for ln in cmd.expected]
        assert _matches(expected, actual), (f"{where}\nthe output differs from the doc's:\n"
                                            + "\n".join(expected) + "\n---- got:\n" + out)


# ------------------------------------------------------------------ the blocks
@dataclass
class Block:
    doc: Path
    line: int
    kind: str  # python | console | toml | yaml
    text: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.doc.relative_to(ROOT)}:{self.line}"


def _collect() -> list[Block]:
    blocks: list[Block] = []
    parsers = [CodeBlockParser(language=k) for k in ("python", "console", "toml", "yaml")]
    for doc in DOCS:
        document = Sybil(parsers=parsers).parse(doc)
        lines = document.text.splitlines()
        for example in document:
            header = lines[example.line - 1]
            kind = header.strip("`").strip()
            before = next((ln for ln in reversed(lines[:example.line - 1]) if ln.strip()), "")
            m = NOT_RUN.search(before) if before.startswith("*") else None
            if kind == "yaml" and not YAML_FILE.match(example.parsed):
                continue  # a YAML block shown, not a file the commands below it use
            blocks.append(Block(doc, example.line + 1, kind, example.parsed, m[1] if m else None))
    return blocks


#: a ```yaml block whose first line is ``# NAME.yaml`` (``##``: labgrid's comment) is that file in the document's directory
#: (a labgrid exporter's configuration: its ``/dev/ttyACM0`` is the served bench's pty)
YAML_FILE = re.compile(r"##? ([\w.-]+\.yaml)\s*\n")


BLOCKS = _collect()


@pytest.fixture(scope="module", autouse=True)
def _teardown(request):
    yield
    # what the examples left open (as a script may: its process would end here) is closed
    # while its bench still runs, so no keep-alive thread outlives the bench into later tests
    for namespace in _NAMESPACES.values():
        for value in list(namespace.values()):
            if hasattr(value, "transport") and callable(getattr(value, "close", None)):
                try:
                    value.close()
                except Exception:  # noqa: BLE001 - a far end already gone: nothing to close
                    pass
    _NAMESPACES.clear()
    for st in _STATES.values():
        st.close()


def _python(st: DocState, block: Block, namespace: dict) -> None:
    code = compile(st.rewrite(block.text), f"{block.id}", "exec")
    cwd = os.getcwd()
    os.chdir(st.tmp)
    old_env, old_path = dict(os.environ), list(sys.path)
    sys.path.insert(0, str(ROOT / "examples" / "lab"))  # a test's own modules beside it
    try:
        os.environ.pop("LM629_PORT", None)
        exec(code, namespace)
    finally:
        os.chdir(cwd)
        os.environ.clear()
        os.environ.update(old_env)
        sys.path[:] = old_path


_NAMESPACES: dict[Path, dict] = {}


#: a document's blocks share its bench and namespace, in order: one xdist group per document
#: (``--dist loadgroup``), the documents spread over the workers.  A console block of many
#: commands takes over 10 s on an idle machine (README.md's bench hour: 17 processes, each
#: importing the package, a tune and a 5 s scope among them): each command is a reader's.
@pytest.mark.parametrize("block", [
    pytest.param(b, id=b.id, marks=pytest.mark.xdist_group(f"docs:{b.doc.name}")) for b in BLOCKS])
def test_doc_block(block: Block, tmp_path_factory, request: pytest.FixtureRequest) -> None:
    st = _state(block.doc, tmp_path_factory)
    counts = [0, 0]  # examples run, not run
    request.node.user_properties.append((DOCS_PROPERTY, counts))
    if block.skip:
        counts[1] += 1
        pytest.skip(f"{block.id}: {block.skip}")
    if block.kind == "python":
        _python(st, block, _NAMESPACES.setdefault(block.doc, {"__name__": "__doc_example__"}))
        counts[0] += 1
    elif block.kind == "yaml":
        text = block.text
        if "/dev/ttyACM0" in text:  # the exporter wants the pty's own path, under /dev/
            text = text.replace("/dev/ttyACM0", os.path.realpath(st.serial().split("://")[1]))
        (st.tmp / YAML_FILE.match(text)[1]).write_text(text)
        counts[0] += 1
    elif block.kind == "toml":
        from lm629_host.config.profile import load_profile
        path = st.tmp / f"block{block.line}.toml"
        path.write_text(block.text)
        load_profile(path)
        counts[0] += 1
    else:
        skipped = []
        for cmd in parse_transcript(block.text, block.line):
            reason = cmd.skip or _cannot_run(cmd.text)
            if reason:
                counts[1] += 1
                skipped.append(f"{cmd.line}: {reason}")
                continue
            run_command(st, cmd)
            counts[0] += 1
        if skipped:
            pytest.skip("; ".join(skipped))


def test_every_command_line_is_in_a_transcript() -> None:
    """A command shown outside a ```console block (an indented or a bare fenced one) is not
    run: the docs put every command where the tests run it."""
    stray = []
    for doc in DOCS:
        fence = None
        for n, line in enumerate(doc.read_text().splitlines(), 1):
            if line.lstrip().startswith("```"):
                fence = None if fence is not None else line.strip("` ")
                continue
            if fence in ("console", "python", "toml", "yaml"):
                continue
            if re.match(r"\s*(\$ )?(lm629 (?!\()|python3? -m |pytest |make -C |sudo |labgrid-)", line):
                stray.append(f"{doc.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not stray, "commands outside a ```console transcript:\n" + "\n".join(stray)


def test_at_most_a_tenth_of_the_examples_is_not_run() -> None:
    total = skipped = 0
    for block in BLOCKS:
        if block.kind == "console":
            commands = parse_transcript(block.text, block.line)
            total += len(commands)
            skipped += len(commands) if block.skip else sum(1 for c in commands if c.skip)
        else:
            total += 1
            skipped += bool(block.skip)
    assert skipped <= total // 10, f"{skipped} of {total} docs examples are marked not run"
    assert total >= 60, f"only {total} docs examples found: the parser lost some"


if sys.platform != "linux":  # the served bench is a pseudo-terminal
    pytestmark = pytest.mark.skip("the docs' bench stand-ins need Linux ptys")
