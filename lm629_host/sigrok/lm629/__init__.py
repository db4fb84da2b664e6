'''
The National / TI LM628 and LM629 precision motion controllers, on their 8-bit host bus.

Channels: D0-D7, /CS, /RD, /WR and /PS (required), /RST and HI (optional).  The chip
latches a byte on the rising edge of /WR and is read while /RD is low; /PS low selects
the command byte (write) and the status byte (read), /PS high a data byte (words go high
byte first).

The decoder shows each bus cycle, each command with its words decoded (the LTRJ and LFIL
control words and their parameters, MSKI/RSTI masks, the values the RD commands return),
the busy checks, and warnings for what a correct host never does: a transfer while the last
status read said busy, a command or word without a busy check before it, an LTRJ or LFIL
shorter or longer than its control word announces, a read with no command, a data read on
a write-only command.

One decoder instance follows one chip: on a board of several chips give it that chip's /CS
(and HI).  Shipped by lm629-host (`lm629 sigrok install`); its simulators write the same
bus as a VCD (`sim://?vcd=bus.vcd`), see docs/debugging.md there.
'''

from .pd import Decoder

__all__ = ["Decoder"]
