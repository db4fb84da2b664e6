"""libsigrokdecode protocol decoder (API 3) for the LM628/LM629 host bus.

The decoder follows the chip as the chip follows the bus: a byte counts when the chip would
take it.  Writes are latched at /WR rising and reads sampled at /RD rising, with D0-D7 as they
were during the last sample the strobe was low (a line that changes with the rising edge is
not the latched value).  A transfer made while the last status read showed busy is ignored by
the chip, so it is ignored here too (and warned about); so is a data byte the chip refuses.

The busy discipline (datasheet, AN-706 3.6): before every command byte and before the first
byte of every data word, written or read, the host reads the status byte until busy is
clear.  The second byte of a word needs no check (the chip goes busy after the word).
"""

import sigrokdecode as srd

from .tables import (
    COMMANDS,
    FILTER_BITS,
    INTERRUPTS,
    SIGNALS_BITS,
    STATUS_BITS,
    TRAJECTORY_BITS,
    TRAJECTORY_ORDER,
)

D0, CS, RD, WR, PS, RST, HI = 0, 8, 9, 10, 11, 12, 13
BUSY = 0x01

# annotation classes
(A_STATUS, A_COMMAND_BYTE, A_DATA_WRITE, A_DATA_READ, A_RESET, A_COMMAND, A_WORD, A_READY,
 A_BUSY, A_WARNING, A_HI) = range(11)


def _data_channels():
    return tuple({"id": f"d{i}", "name": f"D{i}", "desc": f"Data bus bit {i}"}
                 for i in range(8))


def flag_names(value, bits):
    """The names of the bits of ``value`` set, in table order ('none' when none is)."""
    names = [name for bit, name in bits if value & bit]
    return " ".join(names) if names else "none"


def s16(w):
    return w - 0x10000 if w & 0x8000 else w


def s32(v):
    return v - 0x100000000 if v & 0x80000000 else v


def fixed(v):
    """A 16.16 word pair as a number (velocities, accelerations: counts/sample, /sample^2)."""
    return "%.6g" % (v / 65536.0)


class Decoder(srd.Decoder):
    api_version = 3
    id = "lm629"
    name = "LM629"
    longname = "National/TI LM628/LM629 motion controller"
    desc = "Host bus of the LM628/LM629 precision motion controllers."
    license = "mit"
    inputs = ["logic"]
    outputs: list = []
    tags = ["Embedded/industrial"]
    channels = _data_channels() + (
        {"id": "cs", "name": "/CS", "desc": "Chip select (active low)"},
        {"id": "rd", "name": "/RD", "desc": "Read strobe (active low)"},
        {"id": "wr", "name": "/WR", "desc": "Write strobe (active low, latches on rising)"},
        {"id": "ps", "name": "/PS", "desc": "Port select: low command/status, high data"},
    )
    optional_channels = (
        {"id": "rst", "name": "/RST", "desc": "Reset (active low)"},
        {"id": "hi", "name": "HI", "desc": "Host interrupt (active high)"},
    )
    options = ()
    annotations = (
        ("status", "Status read"),
        ("command-byte", "Command byte written"),
        ("data-write", "Data byte written"),
        ("data-read", "Data byte read"),
        ("reset", "/RST pulse"),
        ("command", "Command with its words"),
        ("word", "Data word decoded"),
        ("ready", "Busy check: ready"),
        ("busy", "Busy check: busy"),
        ("warning", "Protocol warning"),
        ("interrupt", "HI high"),
    )
    annotation_rows = (
        ("cycles", "Bus cycles", (A_STATUS, A_COMMAND_BYTE, A_DATA_WRITE, A_DATA_READ, A_RESET)),
        ("commands", "Commands", (A_COMMAND,)),
        ("words", "Words", (A_WORD,)),
        ("busy", "Busy checks", (A_READY, A_BUSY)),
        ("hi", "HI", (A_HI,)),
        ("warnings", "Protocol warnings", (A_WARNING,)),
    )

    def __init__(self):
        self.reset()

    def reset(self):
        self.out_ann = None
        self.clear_chip()
        self.rst_low_at = None
        self.hi_level = None
        self.hi_rose = None

    def clear_chip(self):
        """What a reset leaves: no command under way, no status seen."""
        self.cmd = None  # the command taking data words: dict, see start_command
        self.last_done = None  # the write command just completed (a word after it: long)
        self.checked = None  # the last status byte read since the last transfer
        # (byte, start sample, taken) of a word's high byte; not taken: the chip refused it
        # (a stray or ignored word), and its low byte goes with it without a second warning
        self.half = None

    def start(self):
        self.out_ann = self.register(srd.OUTPUT_ANN)

    def put_ann(self, ss, es, cls, texts):
        self.put(ss, max(es, ss + 1), self.out_ann, [cls, texts])

    def warn(self, ss, es, text):
        self.put_ann(ss, es, A_WARNING, [text, "warning"])

    # ---------------------------------------------------------------- the busy discipline
    def busy_check(self, what, ss, es):
        """Before a transfer: True when the chip takes it.  Warns when the last status read
        since the previous transfer said busy (the chip ignores the transfer) or when there
        was none (the chip may have been busy: nothing said it was not)."""
        st, self.checked = self.checked, None
        if st is None:
            self.warn(ss, es, f"{what} without a busy check before it")
            return True
        if st & BUSY:
            self.warn(ss, es, f"{what} while busy (status {st:02X}): the chip ignores it")
            return False
        return True

    # ---------------------------------------------------------------- commands
    def start_command(self, op, ss, es):
        self.finish_short(ss)
        self.half = None
        self.last_done = None
        info = COMMANDS.get(op)
        if info is None:
            self.warn(ss, es, f"unknown command {op:02X}: the chip sets its command-error bit")
            return
        name, direction, words = info
        self.cmd = {"op": op, "name": name, "dir": direction, "need": words, "words": [],
                    "ss": ss}
        if direction == "none":
            self.complete(es)

    def finish_short(self, ss):
        """A new command (or /RST) while the last one still expected words: it is cut short."""
        c = self.cmd
        if c is None:
            return
        got, need = len(c["words"]), c["need"]
        if got < need or (self.half is not None and self.half[2]):
            what = f"short {c['name']}: {got} of {need} words"
            if c["name"] in ("LTRJ", "LFIL") and got:
                what += f" (its control word {c['words'][0]:04X} announces {need - 1})"
            self.warn(c["ss"], ss, what)
            self.emit(c, ss, " (short)")
        self.cmd = None
        self.half = None

    def complete(self, es):
        c = self.cmd
        self.cmd = None
        self.last_done = c if c["dir"] == "write" else None
        self.emit(c, es, "")

    def emit(self, c, es, note):
        words = " ".join(f"{w:04X}" for w in c["words"])
        plain = c["name"] + (" " + words if words else "")
        decoded = self.describe(c)
        full = plain + (": " + decoded if decoded else "") + note
        self.put_ann(c["ss"], es, A_COMMAND, [full, plain + note, c["name"]])

    def describe(self, c):
        """The command's meaning in a line (its words decoded)."""
        w, name = c["words"], c["name"]
        if name == "LTRJ" and w:
            parts = [f"ctrl {flag_names(w[0], TRAJECTORY_BITS)}"]
            for _, label, value, relative in self.ltrj_values(w):
                parts.append(self.ltrj_text(label, value, relative))
            return ", ".join(parts)
        if name == "LFIL" and w:
            parts = [f"ds {w[0] >> 8} (every {(w[0] >> 8) + 1} samples)"]
            for (_, label), value in zip(self.lfil_flags(w[0]), w[1:]):
                parts.append(f"{label.lower()} {value}")
            return ", ".join(parts)
        if name in ("MSKI", "RSTI") and w:
            verb = "enable" if name == "MSKI" else "keep"
            return f"{verb} {flag_names(w[0] & INTERRUPTS, STATUS_BITS)}"
        if name in ("LPES", "LPEI") and w:
            return f"threshold {w[0]}"
        if name in ("SBPA", "SBPR") and len(w) == 2:
            return f"breakpoint {s32(w[0] << 16 | w[1])}"
        if name in ("RDRP", "RDDP", "RDIP") and len(w) == 2:
            return f"position {s32(w[0] << 16 | w[1])}"
        if name == "RDDV" and len(w) == 2:
            return f"velocity {fixed(s32(w[0] << 16 | w[1]))}"
        if name in ("RDRV", "RDSUM") and w:
            return ("velocity %d" if name == "RDRV" else "sum %d") % s16(w[0])
        if name == "RDSIGS" and w:
            return flag_names(w[0], SIGNALS_BITS)
        return ""

    @staticmethod
    def lfil_flags(control):
        return [(bit, label) for bit, label in FILTER_BITS if control & bit]

    @staticmethod
    def ltrj_values(words):
        """(word index of the first word, label, 32-bit value or None, relative) per flagged
        parameter, in the order the words follow the control word."""
        out, k = [], 1
        for bit, rel, label in TRAJECTORY_ORDER:
            if words[0] & bit:
                value = words[k] << 16 | words[k + 1] if k + 1 < len(words) else None
                out.append((k, label, value, bool(words[0] & rel)))
                k += 2
        return out

    @staticmethod
    def ltrj_text(label, value, relative):
        if value is None:
            return f"{label} missing"
        rel = " relative" if relative else ""
        if label == "position":
            return f"position{rel} {s32(value)}"
        v = s32(value) if relative else value
        return f"{label}{rel} {fixed(v)}"

    def word_text(self, c, index, word):
        """What data word ``index`` of command ``c`` means, for the words row."""
        name = c["name"]
        if name == "LTRJ":
            if index == 0:
                return f"ctrl {word:04X}: {flag_names(word, TRAJECTORY_BITS)}"
            for k, label, _, _ in self.ltrj_values(c["words"] + [0, 0]):
                if index in (k, k + 1):
                    half = "hi" if index == k else "lo"
                    return f"{label} {half} {word:04X}"
        if name == "LFIL":
            if index == 0:
                names = " ".join(label for _, label in self.lfil_flags(word)) or "none"
                return f"ctrl {word:04X}: ds {word >> 8}, {names}"
            flags = self.lfil_flags(c["words"][0])
            if index - 1 < len(flags):
                return f"{flags[index - 1][1].lower()} {word}"
        if name in ("MSKI", "RSTI"):
            return f"mask {word:04X}"
        if name == "RDSIGS":
            return f"signals {word:04X}"
        return f"{name} word {index + 1}: {word:04X}"

    def add_word(self, word, ss, es):
        c = self.cmd
        c["words"].append(word)
        index = len(c["words"]) - 1
        if index == 0 and c["name"] == "LTRJ":
            c["need"] = 1 + 2 * sum(1 for bit, _, _ in TRAJECTORY_ORDER if word & bit)
        elif index == 0 and c["name"] == "LFIL":
            c["need"] = 1 + len(self.lfil_flags(word))
        self.put_ann(ss, es, A_WORD, [self.word_text(c, index, word), f"{word:04X}"])
        if len(c["words"]) >= c["need"]:
            self.complete(es)

    # ---------------------------------------------------------------- bus cycles
    def status_read(self, b, ss, es):
        flags = flag_names(b & ~BUSY, STATUS_BITS)
        self.put_ann(ss, es, A_STATUS, [f"Status {b:02X}: {flags}", f"Status {b:02X}",
                                        f"S {b:02X}"])
        if b & BUSY:
            self.put_ann(ss, es, A_BUSY, [f"busy ({b:02X})", "busy", "B"])
        else:
            self.put_ann(ss, es, A_READY, [f"ready ({b:02X})", "ready", "R"])
        self.checked = b

    def command_write(self, b, ss, es):
        name = COMMANDS.get(b, ("unknown",))[0]
        self.put_ann(ss, es, A_COMMAND_BYTE, [f"Command {b:02X} ({name})", f"Cmd {b:02X}",
                                              "C"])
        if self.busy_check(f"command {b:02X} ({name})", ss, es):
            self.start_command(b, ss, es)

    def low_byte(self, b, es):
        """The second byte of a word: the chip takes the word now (unless it refused the first)."""
        hi, ws, taken = self.half
        self.half = None
        self.checked = None
        if taken:
            self.add_word(hi << 8 | b, ws, es)

    def data_write(self, b, ss, es):
        self.put_ann(ss, es, A_DATA_WRITE, [f"Data write {b:02X}", f"W {b:02X}", "W"])
        if self.half is not None:
            self.low_byte(b, es)
            return
        self.half = (b, ss, False)
        if not self.busy_check("data word", ss, es):
            return
        c = self.cmd
        if c is None:
            done = self.last_done
            if done is not None:
                what = f"long {done['name']}: a word after the {done['need']}"
                if done["name"] in ("LTRJ", "LFIL"):
                    what += f" its control word {done['words'][0]:04X} announces"
                self.warn(ss, es, what + " (the chip sets its command-error bit)")
            else:
                self.warn(ss, es, "data written with no command (the chip sets its "
                                  "command-error bit)")
            return
        if c["dir"] != "write":
            kind = "read" if c["dir"] == "read" else "no-data"
            self.warn(ss, es, f"data written to {c['name']}, a {kind} command (the chip sets "
                              "its command-error bit)")
            return
        self.half = (b, ss, True)

    def data_read(self, b, ss, es):
        self.put_ann(ss, es, A_DATA_READ, [f"Data read {b:02X}", f"R {b:02X}", "R"])
        if self.half is not None:
            self.low_byte(b, es)
            return
        self.half = (b, ss, False)
        if not self.busy_check("data read", ss, es):
            return
        c = self.cmd
        if c is None:
            self.warn(ss, es, "read with no command (the chip sets its command-error bit)")
            return
        if c["dir"] == "write":
            self.warn(ss, es, f"data read on {c['name']}, a write-only command (the chip sets "
                              "its command-error bit)")
            return
        self.half = (b, ss, True)

    def reset_pulse(self, ss, es):
        self.finish_short(ss)
        self.clear_chip()
        self.put_ann(ss, es, A_RESET, ["/RST pulse: the chip resets", "/RST", "R"])

    # ---------------------------------------------------------------- sampling
    def strobe(self, pins, line):
        """From a strobe's falling edge (with /CS low) to its rising edge: the byte is D0-D7
        as of the last sample the strobe was low."""
        ss = self.samplenum
        ps = pins[PS]
        byte = sum(pins[D0 + i] << i for i in range(8))
        conds = [{line: "r"}] + [{D0 + i: "e"} for i in range(8)]
        while True:
            pins = self.wait(conds)
            if self.matched[0]:
                break
            byte = sum(pins[D0 + i] << i for i in range(8))
        es = self.samplenum
        if line == RD:
            (self.data_read if ps else self.status_read)(byte, ss, es)
        else:
            (self.data_write if ps else self.command_write)(byte, ss, es)
        return pins

    def follow_lines(self, pins, has_rst, has_hi):
        """/RST and HI, from their levels now (their edges may fall inside a strobe)."""
        if has_rst:
            if pins[RST] == 0 and self.rst_low_at is None:
                self.rst_low_at = self.samplenum
            elif pins[RST] == 1 and self.rst_low_at is not None:
                self.reset_pulse(self.rst_low_at, self.samplenum)
                self.rst_low_at = None
        if has_hi and pins[HI] != self.hi_level:
            if pins[HI]:
                self.hi_rose = self.samplenum
            elif self.hi_rose is not None:
                self.put_ann(self.hi_rose, self.samplenum, A_HI, ["HI: interrupt", "HI"])
            self.hi_level = pins[HI]

    def decode(self):
        has_rst = self.has_channel(RST)
        has_hi = self.has_channel(HI)
        conds = [{CS: "l", RD: "f"}, {CS: "l", WR: "f"}]
        if has_rst:
            conds.append({RST: "e"})
        if has_hi:
            conds.append({HI: "e"})
        pins = self.wait({})  # the first sample: /RST may start low
        self.follow_lines(pins, has_rst, has_hi)
        while True:
            pins = self.wait(conds)
            if self.matched[0]:
                pins = self.strobe(pins, RD)
            elif self.matched[1]:
                pins = self.strobe(pins, WR)
            self.follow_lines(pins, has_rst, has_hi)
