"""THE pin map of the FT232H adapter: which FT232H line drives which LM628/LM629 pin (and
the MPSSE commands that move them, FTDI AN_108).

This is the one definition.  The stream compiler (:mod:`lm629_host.transports.mpsse`)
compiles bus programs with these masks, the emulated FT232H (:mod:`lm629_host.sim.ftdi`) wires its pins to the
chip model with them, and docs/ftdi.md's wiring table and drawing are generated from them
(:mod:`lm629_host.wiring.connections`, ``tools/gen_wiring.py``; a test checks they are current).

Why this layout:

* the data bus D0-D7 sits on one whole byte, ACBUS0-7 (labelled C0-C7 on the Adafruit FT232H
  breakout), so one MPSSE "set high byte" (0x82) or "read high byte" (0x83) command moves a
  byte, and the direction of the whole bus is switched in the same command;
* the strobes sit on the other byte, ADBUS (D0-D7 on the breakout), set with "set low byte"
  (0x80).  ADBUS0 is the MPSSE clock output TCK: the stream's delays are idle clocks
  (0x8E/0x8F), which toggle TCK, so ADBUS0 is left unconnected (it is a handy scope trigger);
* HI is on ADBUS5, which the FT232H calls GPIOL1: the one line the MPSSE wait-on-I/O
  commands (0x88/0x89) can watch.  With ``busy_pin=gpiol1`` (:data:`BUSY_PINS`) that line
  watches D0 instead: D0 (ACBUS0) is wired to ADBUS5 too, and HI is left unconnected
  (its flags are bits 1-6 of the status byte, which the driver reads anyway;
  ``connections.connections("ft232h", busy_pin=True)`` is that wiring).  During a status read
  held with /CS, /PS and /RD low, D0 is the busy bit, so a stream can wait in the adapter
  until busy clears (see :mod:`lm629_host.transports.ftdi`);
* /RST is on ADBUS6 and not on a line with a special function, so that nothing but an explicit
  set-low-byte command can ever pulse it.

Put 10 kOhm pull-ups on /CS, /RD, /WR and /RST: until the transport has configured the FT232H
its lines are inputs, and the pull-ups keep the chip deselected and out of reset.  Closing
(pyftdi's ``close``: a bit-mode reset, ``set_bitmode(0, RESET)``) returns the FT232H to the mode
its EEPROM selects, UART by default: then ADBUS0, ADBUS2 and ADBUS4 are the UART's TXD, RTS#
and DTR# outputs, driven high while idle and deasserted, so /RD and /PS stay driven high, and
every other line (/CS, /WR, /RST, the data bus) is an input again, held by the pull-ups.
"""

from __future__ import annotations

# --- ADBUS (low byte, MPSSE commands 0x80 set / 0x81 read): control lines -------------------
TCK = 1 << 0  #: ADBUS0: MPSSE clock, toggled by the idle-clock delays; leave unconnected
CS = 1 << 1  #: ADBUS1 -> /CS  (active low)
RD = 1 << 2  #: ADBUS2 -> /RD  (active low)
WR = 1 << 3  #: ADBUS3 -> /WR  (active low; the chip latches on the rising edge)
PS = 1 << 4  #: ADBUS4 -> /PS  (low: command/status, high: data)
GPIOL1 = 1 << 5  #: ADBUS5: the line MPSSE's wait-on-I/O (0x88/0x89) watches
HI = GPIOL1  #: ADBUS5 (GPIOL1) <- HI (input, active high), in the default wiring
#: the URL option ``busy_pin``: the lines a stream can wait on, wired to D0, by name -> the
#: ADBUS bit (HI then has no line)
BUSY_PINS = {"gpiol1": GPIOL1}
RST = 1 << 6  #: ADBUS6 -> /RST (active low)
CS1 = 1 << 7  #: ADBUS7 -> /CS of a second chip (active low), the one free line left

#: the URL option ``heartbeat``: a line the wiring may leave free, toggled while the host lives
#: (the charge pump of an external monostable on the amplifier's enable: the FT232H has no
#: timer of its own).  ADBUS7 is free on a one-chip bench; the transport then has one /CS.
HEARTBEAT_PINS = {"adbus7": CS1}
#: what the bus uses each other line for (why ``heartbeat=`` refuses it)
LINE_USES = {"adbus0": "the MPSSE clock TCK", "adbus1": "/CS", "adbus2": "/RD",
             "adbus3": "/WR", "adbus4": "/PS", "adbus5": "HI (GPIOL1)", "adbus6": "/RST",
             **{f"acbus{k}": f"data line D{k}" for k in range(8)}}

#: /CS of chip 0 and chip 1 (``Op.SELECT`` indexes this): two axes on one FT232H.  The chips
#: share D0-D7, /RD, /WR, /PS and /RST; the second has no HI line (no free pin: its status is
#: read instead).  ACBUS8/9 are not MPSSE lines, ADBUS0 is TCK: two is what the FT232H allows.
CHIP_SELECTS = (CS, CS1)
#: HI of each chip, where it has a line
HI_LINES = (HI, 0)
CS_ALL = CS | CS1

#: ADBUS lines driven by the adapter (HI is the one input)
CTRL_DIRECTION = TCK | CS | RD | WR | PS | RST | CS1
#: the idle state of the control lines: chips deselected, strobes and /RST high, TCK low
CTRL_IDLE = CS | RD | WR | PS | RST | CS1

# --- ACBUS (high byte, MPSSE commands 0x82 set / 0x83 read): the data bus ---------------------
DATA_OUT = 0xFF  #: ACBUS direction while the adapter drives D0-D7 (writes)
DATA_IN = 0x00  #: ACBUS direction while the chip may drive D0-D7 (reads, idle)

# --- the FT232H itself -------------------------------------------------------------------------
#: the FT232H's buffers, each way (datasheet: 1 KiB TX and 1 KiB RX): an MPSSE stream longer
#: than this cannot be written while the engine waits for the host to read its answers, so the
#: transport never sends a stream, or asks for a reply, longer than this
FIFO_BYTES = 1024

# MPSSE commands (FTDI AN_108): the transport writes them, the emulated FT232H executes them
SET_LOW = 0x80  #: set ADBUS levels and directions (2 bytes follow)
GET_LOW = 0x81  #: read ADBUS
SET_HIGH = 0x82  #: set ACBUS levels and directions (2 bytes follow)
GET_HIGH = 0x83  #: read ACBUS
LOOPBACK_ON = 0x84
LOOPBACK_OFF = 0x85
SET_DIVISOR = 0x86  #: TCK divisor (2 bytes follow)
SEND_IMMEDIATE = 0x87  #: flush the answer to the host now
DISABLE_DIV5 = 0x8A
ENABLE_DIV5 = 0x8B
ENABLE_CLK_3PHASE = 0x8C
DISABLE_CLK_3PHASE = 0x8D
CLK_BITS = 0x8E  #: n+1 idle clocks (1 byte follows)
CLK_BYTES = 0x8F  #: 8 x (n+1) idle clocks (2 bytes follow)
WAIT_HIGH = 0x88  #: wait until GPIOL1 is high (no timeout: the engine stops until it is)
WAIT_LOW = 0x89  #: wait until GPIOL1 is low
ENABLE_CLK_ADAPTIVE = 0x96
DISABLE_CLK_ADAPTIVE = 0x97


__all__ = ["TCK", "CS", "CS1", "CHIP_SELECTS", "HI_LINES", "CS_ALL", "RD", "WR", "PS", "HI",
           "GPIOL1", "BUSY_PINS", "HEARTBEAT_PINS", "LINE_USES", "RST", "CTRL_DIRECTION", "CTRL_IDLE", "DATA_OUT",
           "DATA_IN", "FIFO_BYTES"]
