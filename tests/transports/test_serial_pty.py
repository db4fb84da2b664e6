"""``serial://`` through pyserial on a real pseudo-terminal, served by ``lm629 sim serve``'s
server with the Python far end.  These are the only link tests in real time (a few seconds).
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

import lm629_host
from lm629_host import Status, TransportError
from lm629_host.cli import main as cli
from lm629_host.bus.opcodes import Cmd
from lm629_host.sim.serve import SimServer
from lm629_host.transports import serial as serial_mod
from lm629_host.transports.serial import SerialTransport, options_of


@pytest.fixture
def server(tmp_path):
    srv = SimServer(tmp_path / "lm629", "sim://?record=1").start()
    yield srv
    srv.close()


def test_handshake_and_typed_commands_over_the_pty(server):
    url = f"serial://{server.link}?baud=115200"
    with lm629_host.open(url) as chip:
        t = chip.transport
        assert isinstance(t, SerialTransport)
        assert t.info is not None and t.info.protocol == 1
        assert "round trip" in t.describe() and 0 < t.rtt_s < 0.5
        # a pty has no ASYNC_LOW_LATENCY: the transport says so instead of failing
        assert "not supported" in t.low_latency
        three_commands_once(chip, server.model)


def three_commands_once(chip, model) -> None:
    """Reset, then LFIL kp=10, UDF and RDRP over a bridge link: one round trip each, no
    retry, and each command exactly once in the chip's record (LFIL with kp only: flags 0008,
    kp 10 = 000A)."""
    t = chip.transport
    assert chip.reset() in (Status(0x80), Status(0xC0))
    model.record_clear()
    t.stats.reset()
    chip.load_filter(kp=10)
    chip.update_filter()
    assert chip.read_real_position() == 0
    assert t.stats.round_trips == 3 and t.stats.retries == 0
    assert model.history == [(0x1E, (0x0008, 0x000A)), (0x04, ()), (int(Cmd.RDRP), ())]


def test_several_clients_share_one_chip(server):
    """Like several CLI invocations on one bench: what one client loads, the next one sees."""
    with lm629_host.open(str(server.link)) as a:  # a bare device path means serial://
        a.reset()
        a.set_breakpoint(0x00012345)
    with lm629_host.open(f"serial://{server.link}") as b:
        b.define_home()
        assert b.read_desired_position() == 0
    hist = server.model.history
    assert (int(Cmd.SBPA), (0x0001, 0x2345)) in hist and hist[-2:] == [(int(Cmd.DFH), ()),
                                                                        (int(Cmd.RDDP), ())]


def test_second_client_at_once_is_told_the_port_is_busy(server):
    with lm629_host.open(f"serial://{server.link}"):
        with pytest.raises(TransportError) as e:
            lm629_host.open(f"serial://{server.link}")
    assert "in use by another program" in str(e.value) and "fuser" in str(e.value)


def test_missing_port_says_where_to_look(tmp_path):
    with pytest.raises(TransportError) as e:
        lm629_host.open(f"serial://{tmp_path}/ttyNOPE")
    assert "no serial port" in str(e.value) and "lm629 bridge list" in str(e.value)


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to become 'nobody'")
def test_permission_denied_names_the_group_and_the_command(tmp_path):
    """A user outside the port's group opens it: a forked child drops to 'nobody' (the
    interpreter and pyserial are already loaded, so it needs no file of root's).  The pty is
    not served (no thread runs while forking): the open fails before any byte is sent."""
    import serial  # noqa: F401 - loaded before the child loses access to site-packages

    server = SimServer(tmp_path / "denied", "sim://")
    server.open()
    rd, wr = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        code = 1
        try:
            os.close(rd)
            os.setgroups([])
            os.setgid(65534)
            os.setuid(65534)
            try:
                lm629_host.open(f"serial://{server.device}")
            except TransportError as e:
                os.write(wr, str(e).encode())
                code = 0
        finally:
            os._exit(code)
    os.close(wr)
    with os.fdopen(rd) as f:
        msg = f.read()
    _, status = os.waitpid(pid, 0)
    group = serial_mod._ask_group(server.device)
    server.close()
    assert os.waitstatus_to_exitcode(status) == 0, msg
    assert "permission denied" in msg
    assert f"usermod -aG {group} $USER" in msg


def test_no_answer_says_is_the_firmware_flashed(tmp_path):
    """A port where nothing answers (an unflashed board): HELLO for ``boot`` seconds, then a
    message that names the firmware, the boot delay and the baud rate."""
    master, slave = os.openpty()
    link = tmp_path / "silent"
    link.symlink_to(os.ttyname(slave))
    try:
        t0 = time.monotonic()
        with pytest.raises(TransportError) as e:
            lm629_host.open(f"serial://{link}?boot=0.5")
        assert 0.45 < time.monotonic() - t0 < 3
    finally:
        os.close(master)
        os.close(slave)
    msg = str(e.value)
    assert "lm629 bridge flash" in msg and "~2 s to boot" in msg and "baud" in msg


def test_url_parameters_are_checked():
    assert options_of("/dev/ttyUSB0?baud=57600").baud == 57600
    assert options_of("serial:///dev/ttyACM0").device == "/dev/ttyACM0"
    with pytest.raises(ValueError, match="baud='fast'"):
        options_of("serial:///dev/ttyACM0?baud=fast")
    with pytest.raises(ValueError, match="baud=100 is outside 300..4000000"):
        options_of("serial:///dev/ttyACM0?baud=100")
    with pytest.raises(ValueError, match="unknown serial parameter"):
        options_of("serial:///dev/ttyACM0?speed=9600")


def test_bridge_list_probes_candidates_with_hello(server, monkeypatch):
    """No USB here: the port enumeration is replaced by one entry with an Uno's USB id whose
    device is the pty; the probe itself is the real handshake."""

    class Entry:
        device = server.device
        vid, pid, serial_number = 0x2341, 0x0043, "95530343"

    class Other:  # a port with an unknown id is not a candidate
        device, vid, pid, serial_number = "/dev/ttyS0", 0x1234, 0x5678, None

    monkeypatch.setattr(serial_mod, "_candidates", lambda: [Other(), Entry()])
    r = CliRunner().invoke(cli, ["bridge", "list"])
    assert r.exit_code == 0, r.output
    assert f"ok {server.device}  Arduino Uno R3 [2341:0043] s/n 95530343: bridge firmware 1.4.0" \
        in r.output
    assert "ttyS0" not in r.output


def test_bridge_flash_command_lines(tmp_path):
    hexf = tmp_path / "fw.hex"
    hexf.write_text(":00000001FF\n")
    r = CliRunner().invoke(cli, ["bridge", "flash", "-p", "/dev/ttyUSB0", "--board", "nano-old",
                                 "--hex", str(hexf), "--dry-run"])
    assert r.output.strip() == (f"avrdude -p atmega328p -c arduino -P /dev/ttyUSB0 -b 57600 -D "
                                f"-U flash:w:{hexf}:i")
    r = CliRunner().invoke(cli, ["bridge", "flash", "-p", "/dev/ttyACM0", "--hex", str(hexf),
                                 "--dry-run"])
    assert "-c arduino -P /dev/ttyACM0 -b 115200" in r.output
    r = CliRunner().invoke(cli, ["bridge", "flash", "-p", "/dev/ttyACM0", "--hex", str(hexf),
                                 "--avrdude", "avrdude-not-here"])
    assert r.exit_code != 0 and "apt-get install avrdude" in r.output
    r = CliRunner().invoke(cli, ["bridge", "flash", "-p", "/dev/ttyACM0", "--hex",
                                 str(tmp_path / "missing.hex")])
    assert r.exit_code != 0 and "make -C firmware_bridge" in r.output


def test_sim_serve_cli_serves_until_sigterm(tmp_path):
    link = tmp_path / "bench"
    env = dict(os.environ, PYTHONPATH=str(Path(lm629_host.__file__).parent.parent))
    proc = subprocess.Popen([sys.executable, "-m", "lm629_host", "sim", "serve",
                             "--pty", str(link), "--url", "sim://?chip=lm628"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        deadline = time.monotonic() + 20
        while not link.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "server did not start"
            time.sleep(0.05)
        with lm629_host.open(f"serial://{link}") as chip:
            assert chip.reset() in (Status(0x80), Status(0xC0))
            assert chip.read_real_position() == 0
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0, out
    assert "simulated LM628" in out and "stopped (" in out
    assert not link.exists()  # the link is removed on exit


def test_pipe_far_end_serves_any_simulated_pipe(tmp_path):
    """The adapter that serves the firmware (``--firmware``) works on any simulated pipe: here
    the Python bridge behind an EmuPipe at 115200 baud stands in for the simavr UART."""
    from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
    from lm629_host.sim.far_ends import PipeFarEnd
    from lm629_host.sim.build import build_model

    model = build_model("sim://?record=1")
    far = PipeFarEnd(EmuPipe(BridgeEmulator(model), baud=115200), model, "emu behind a pipe",
                     baud=115200)
    with SimServer(tmp_path / "p", far_end=far).start() as srv:
        with lm629_host.open(f"serial://{srv.link}") as chip:
            chip.reset()
            chip.set_breakpoint(-2)
            assert chip.read_real_position() == 0
    assert model.history[-2:] == [(int(Cmd.SBPA), (0xFFFF, 0xFFFE)), (int(Cmd.RDRP), ())]


def test_sim_serve_firmware(tmp_path):
    """--firmware serves the compiled firmware; without sim+avr:// it says what to build."""
    from firmware_helpers import require_firmware

    require_firmware()  # skips only without the toolchain; a broken build fails
    srv = SimServer(tmp_path / "fw", "sim://?record=1", firmware=True)
    with srv.start():
        with lm629_host.open(f"serial://{srv.link}") as chip:
            assert "simavr" in srv.describe()
            chip.reset()
            chip.load_filter(kp=10)
            chip.update_filter()
    assert srv.model.history[-2:] == [(0x1E, (0x0008, 0x000A)), (0x04, ())]


def test_doctor_reports_handshake_and_round_trip(server):
    checks = {c.name: c for c in serial_mod.doctor(port=str(server.link))}
    assert checks["pyserial"].ok
    c = checks[f"bridge {server.link}"]
    assert c.ok, c.message
    assert "round trip" in c.message and "bridge firmware 1.4.0" in c.message
    assert "low latency not supported" in c.message


def test_every_pipe_is_a_pipe(server):
    from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
    from lm629_host.sim.faults import FaultPipe
    from lm629_host.bridge.protocol import Pipe
    from lm629_host.sim.build import build_model

    emu = EmuPipe(BridgeEmulator(build_model("sim://")))
    with lm629_host.open(f"serial://{server.link}") as chip:
        for p in (emu, FaultPipe(emu), chip.transport.pipe):
            assert isinstance(p, Pipe)


def test_server_keeps_the_chip_level_with_the_wall_clock(server):
    """The served chip lives in real time: between clients its clock moves with the wall clock
    (the motor keeps moving), and a client's WAIT is answered no earlier than it would be."""
    t0_model, t0_wall = server.model.now(), time.monotonic()
    time.sleep(0.3)
    moved = server.model.now() - t0_model
    assert 0.25 <= moved <= time.monotonic() - t0_wall + 0.05
    from lm629_host.bus.program import Program
    with lm629_host.open(f"serial://{server.link}") as chip:
        w0 = time.monotonic()
        chip.run(Program().wait(60000).wait(60000).status())  # 120 ms on the chip
        assert time.monotonic() - w0 >= 0.12


class _HandlerPort:
    """A pyserial URL handler's port (no descriptor) whose write raises ``error``."""

    port = "rfc2217://localhost:7000"
    timeout = 0.0
    in_waiting = 0

    def __init__(self, error: Exception) -> None:
        self.error = error

    def fileno(self) -> int:
        raise io.UnsupportedOperation("fileno")

    def write(self, data: bytes) -> int:
        raise self.error


def test_a_port_error_is_a_lost_link_and_a_bug_is_a_bug():
    """A port that went away (pyserial's SerialException is an OSError) is told as the link
    lost; a TypeError is a bug in the host and reaches the caller as it is, never "the server
    closed the connection" or "was the board unplugged?"."""
    import serial

    from lm629_host.transports.serial import SerialPipe

    lost = SerialPipe(_HandlerPort(serial.SerialException("connection reset")),
                      device="rfc2217://localhost:7000")
    with pytest.raises(TransportError, match="write failed .*server closed the connection"):
        lost.write(b"\x00")
    buggy = SerialPipe(_HandlerPort(TypeError("a bytes-like object is required")),
                       device="rfc2217://localhost:7000")
    with pytest.raises(TypeError, match="bytes-like"):
        buggy.write(b"\x00")
