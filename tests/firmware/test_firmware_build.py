"""The firmware's build and its C tests, run from pytest: the generated header is current,
``make`` reports flash and RAM inside the ATmega328P (with the Uno's bootloader and a stack),
the host-side C unit tests pass on the shared golden vectors, and the fuzz run of the frame
parser ends without a failure."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path


from lm629_host.wiring import uno as pins
from lm629_host.bridge.protocol import MAX_FRAME, RUN_OVERHEAD, RUN_REPLY_OVERHEAD
from lm629_host.bus.program import OP_ARG_BYTES, Op


ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_bridge"


def test_generated_tables_are_current():
    """firmware_bridge/lm629_tables.h is what tools/gen_tables.py makes from the Python
    definitions today (run the script after changing opcodes, Op or the pin map)."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_tables.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    header = (FW / "lm629_tables.h").read_text()
    for op in Op:
        assert f"#define OP_{op.name} 0x{int(op):02X}u  /* {OP_ARG_BYTES[op]} argument" in header
    assert "#define PIN_WR 0x08u" in header and "#define DATA_LO_SHIFT 2" in header


def test_pin_map_spans_two_ports_around_uart_and_crystal():
    assert [pins.join_byte(*pins.split_byte(b)) for b in range(256)] == list(range(256))
    assert pins.split_byte(0xFF) == (0xFC, 0x03)  # PD2..PD7, PB0..PB1: PD0/PD1 stay the UART
    assert {w.chip_pin for w in pins.WIRING} == {f"D{i}" for i in range(8)} | {
        "/CS", "/PS", "/RD", "/WR", "/RST", "HI", "/CS1", "/CS2", "/CS3", "HI1"}
    # four chip selects: A0 (chip 0, the one-chip wiring) and PB2-PB4; HI of chip 1 on PB5
    assert [(w.port, w.bit) for w in pins.CHIP_SELECTS] == [("C", 0), ("B", 2), ("B", 3), ("B", 4)]
    assert [(w.port, w.bit) if w else None for w in pins.HI_LINES] == [("C", 5), ("B", 5), None, None]


def test_documented_wiring_table_matches_the_pin_map():
    section = (ROOT / "docs" / "bridge.md").read_text()  # the wiring table for the bench
    rows = set(re.findall(r"^\| (D\d+|A\d) \| P([BCD])(\d) \| (\S+) \(pin \d+\)(?: of chip (\d))? \|",
                          section, re.M))
    # the table names the /CS and HI of chip k as that chip's pins (/CS1 is /CS of chip 1)
    want = set()
    for w in pins.WIRING:
        k = w.chip_pin[-1] if w.chip_pin[0] != "D" and w.chip_pin[-1].isdigit() else ""
        want.add((w.board_pin, w.port, str(w.bit), w.chip_pin.rstrip("123") if k else w.chip_pin, k))
    assert rows == want


def test_make_reports_flash_and_ram_within_the_part(firmware_built):
    r = subprocess.run(["make", "-C", str(FW), "size"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    m = re.search(r"flash (\d+) of 32768 bytes .*RAM (\d+) of 2048 bytes", r.stdout)
    assert m, r.stdout
    flash, ram = int(m[1]), int(m[2])
    print(f"\nfirmware: flash {flash} bytes, RAM {ram} bytes (static)")
    assert flash <= 32768 - 512  # the Uno's optiboot keeps the top 512 bytes
    # static RAM holds the receive, reply and cache buffers (3 frames); leave 512 bytes of stack
    assert 3 * MAX_FRAME <= ram <= 2048 - 512


def test_c_unit_tests_and_fuzz_run(firmware_built):
    """``make test``: the host build of link.c against the golden vectors and a scripted chip,
    then 100,000 fuzz inputs under AddressSanitizer/UBSan."""
    r = subprocess.run(["make", "-s", "-C", str(FW), "test", "FUZZ_ITER=100000"],
                       capture_output=True, text=True, timeout=300)
    print(r.stdout)
    assert r.returncode == 0, r.stdout + r.stderr
    m = re.search(r"test_link: (\d+) checks passed", r.stdout)
    assert m and int(m[1]) >= 100
    m = re.search(r"fuzz_link: (\d+) inputs, (\d+) replies checked, (\d+) good frames, "
                  r"(\d+) bad frames dropped, (\d+) programs run, 0 failures", r.stdout)
    assert m and int(m[1]) == 100000
    # the run must exercise both sides: frames that pass and run, frames that are dropped
    assert int(m[2]) > 10000 and int(m[4]) > 10000 and int(m[5]) > 5000


def test_firmware_limits_match_the_protocol_constants():
    """HELLO_REPLY's largest program and reads follow from MAX_FRAME (PROTOCOL.md), in C via
    the generated header: the golden hello_reply carries 243 and 120."""
    link_h = (FW / "link.h").read_text()
    assert "#define LINK_MAX_PROGRAM (LINK_MAX_FRAME - LINK_RUN_OVERHEAD)" in link_h
    assert (MAX_FRAME - RUN_OVERHEAD, (MAX_FRAME - RUN_REPLY_OVERHEAD) // 2) == (243, 120)


def test_the_receive_check_is_inline_and_a_read_takes_its_wire_and_chip_time(firmware_built):
    """The main loop asks ``link_rx_pending()`` twice for every byte received.  Once
    WAIT_STATUS asked too (firmware 1.4: a host byte ends the wait), GCC -Os made it a call
    (1.3 us a byte): RDRP at 1 Mbaud went 298 -> 308 us, LTRJ(6)+STT 847 -> 897 us.
    It is always inlined again: no out-of-line copy in the image, and a kept RDRP program's
    round trip at 1 Mbaud stays within 300 us (18 bytes on the wire: 180 us; the chip's
    command, busy and four reads about 42 us; the firmware's own work the rest)."""
    import lm629_host

    nm = subprocess.run(["avr-nm", str(FW / "build" / "lm629_bridge_1000000.elf")],
                        capture_output=True, text=True, check=True).stdout
    assert "link_rx_pending" not in nm
    with lm629_host.open("sim+avr://?baud=1000000") as chip:
        chip.reset()
        for _ in range(3):  # the bridge keeps a program it has seen twice (PROGRAM_CODES)
            chip.read_real_position()
        t0 = chip.clock.now()
        chip.read_real_position()
        rdrp_us = (chip.clock.now() - t0) * 1e6
    print(f"\nRDRP at 1 Mbaud through the firmware: {rdrp_us:.1f} us (simulated)")
    assert rdrp_us <= 300
