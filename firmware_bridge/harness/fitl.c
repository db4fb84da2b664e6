/* Firmware in the loop: the compiled bridge firmware in libsimavr, its LM629 bus wired to a
 * chip model in Python (lm629_host/sim/avr.py, through ctypes).
 *
 * The port hooks decode /CS /PS /RD /WR /RST edges here in C and call Python once per bus
 * cycle (a status read, a command, a data byte written or read, a /RST pulse).  A read strobe
 * is answered with the byte the model returns, driven onto the data pins only after the chip's
 * read access time (before that the pins carry the complement, so firmware that samples too
 * early reads garbage).  Timing minimums of the chip are checked against the AVR's cycle count
 * and collected as violations.  The UART is fed in-process: host bytes wait in a queue and are
 * raised only while the simulated UART says XON.
 *
 * Several chips (a multi-axis board): the /CS lines of CS_*_MASKS_INIT (chip 0 on the control
 * port, chips 1-3 on the data-high port) say which chip a strobe reaches; the callback's kind
 * carries it (kind | chip << 4), and its answer carries every chip's HI (bit 8 + chip), which is
 * driven onto the HI pins of HI_*_MASKS_INIT.  Two chips selected during a strobe is a
 * violation; a strobe with no /CS low reaches no chip.
 *
 * Life: fitl_new makes an AVR and boots the firmware; fitl_restart powers the same AVR on again
 * for a new session, as new (RAM, flash, EEPROM, IRQs, cycle count, harness state); fitl_free
 * ends it.  Python keeps closed sessions' AVRs for the next open (simavr 1.6 leaks part of each
 * AVR it makes and frees).
 *
 * Pin log (for a VCD of the bus, lm629_host/sim/vcd.py): when switched on, every change of a bus
 * line's level is kept as (AVR cycle, levels) until Python takes it; off, it costs one test per
 * port hook.  Levels: bits 0-7 D0-D7 (the AVR's where it drives them, the chip's while it
 * answers a read, else 1: the pull-ups), 8 /RD, 9 /WR, 10 /PS, 11 /RST, 12-15 /CS of chips 0-3,
 * 16-19 HI of chips 0-3. */
#include <stdarg.h>
#include <stdint.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/avr_extint.h>
#include <simavr/avr_eeprom.h>
#include "../lm629_tables.h"

/* bus cycle kinds passed to the Python callback */
enum { FITL_STATUS = 0, FITL_COMMAND = 1, FITL_WRITE = 2, FITL_READ = 3, FITL_RESET = 4 };
/* callback: (kind | chip << 4, value, cycle) -> byte read | HI of chip k << (8 + k), or < 0 to
 * stop (Python raised) */
typedef int (*fitl_bus_cb)(int kind, int value, uint64_t cycle);

#define CPU_HZ 16000000ul
/* the chip's timing minimums in AVR cycles of 62.5 ns, rounded up (6 MHz table) */
#define T_STROBE 2   /* /WR pulse >= 100 ns; /RD held at least the access time */
#define T_SETUP_DATA 1 /* write data setup >= 50 ns */
#define T_HOLD 2     /* write data hold >= 120 ns */
#define T_RECOVERY 2 /* between strobes >= 120 ns */
#define T_PS_SETUP 1 /* /PS and /CS before the strobe >= 30 ns */
#define QSIZE 8192u

typedef struct {
    /* what lives as long as the simulated AVR: kept when it is powered on again (fitl_restart) */
    avr_t *avr;
    uint8_t *image_flash, *image_eeprom;  /* the firmware image's flash and EEPROM, as the ELF says */
    uint32_t image_flashsize, image_flashbase, image_datasize, image_eesize;
    avr_irq_t *uart_in;
    avr_irq_t *data_lo_pin[8], *data_hi_pin[8], *hi_pin;
    avr_irq_t *hi_pins[CHIP_SELECTS];    /* HI of each chip (NULL: no line) */
    /* from here to the end: one session's state, zeroed at every power-on (power_on) */
    fitl_bus_cb cb;
    int chip;                            /* the chip whose /CS is low, -1 none, -2 several */
    uint8_t ctrl;                       /* last control port value */
    uint8_t lo_port, hi_port;           /* last data port values */
    uint8_t lo_ddr, hi_ddr;
    uint64_t rd_fall, wr_fall, strobe_rise, rst_fall, sel_change, data_change, wr_rise;
    int access_cycles;                  /* read access time + input synchroniser, AVR cycles */
    uint8_t pending;                    /* byte to drive when the access time is over */
    uint8_t in_q[QSIZE];
    uint32_t in_head, in_tail;
    int xon;
    uint8_t out[QSIZE];
    uint32_t out_len;
    uint32_t out_frames;                /* 0x00 delimiters sent since the last read */
    int stop, failed;
    uint32_t violations;
    char first_violation[256];
    uint64_t bus_cycles;
    uint64_t xon_events, xoff_events, bytes_in;
    int pins_on;                        /* pin log switched on */
    uint64_t *log_cycle;                /* the pin log: cycle and levels of each change */
    uint32_t *log_levels;
    uint32_t log_len, log_cap, log_last;
    int chip_drives;                    /* the chip drives D0-D7 (a read strobe is low) */
    uint8_t driven;                     /* the byte the chip drives */
    uint8_t hi_levels;                  /* HI of each chip, bit k */
} fitl_t;

static char last_error[256];
const char *fitl_error(void) { return last_error; }

/* simavr's messages: errors are kept for fitl_error(), the loader's chatter is dropped */
static void quiet_logger(avr_t *avr, const int level, const char *format, va_list ap)
{
    (void)avr;
    if (level <= LOG_ERROR)
        vsnprintf(last_error, sizeof last_error, format, ap);
}

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long) { (void)avr; (void)how_long; }

static void violation(fitl_t *h, const char *what)
{
    if (!h->violations++)
        snprintf(h->first_violation, sizeof h->first_violation, "%s at AVR cycle %llu", what,
                 (unsigned long long)h->avr->cycle);
}

static void log_pins(fitl_t *h);
void fitl_free(fitl_t *h);

static void drive_data(fitl_t *h, uint8_t b)
{
    h->driven = b;
    for (int i = 0; i < 8; i++) {
        avr_irq_t *irq = i < 6 ? h->data_lo_pin[i] : h->data_hi_pin[i - 6];
        avr_raise_irq(irq, (b >> i) & 1);
    }
    log_pins(h);
}

static avr_cycle_count_t access_done(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr; (void)when;
    fitl_t *h = param;
    drive_data(h, h->pending);
    return 0;
}

static const uint8_t cs_ctrl[CHIP_SELECTS] = CS_CTRL_MASKS_INIT;
static const uint8_t cs_dhi[CHIP_SELECTS] = CS_DHI_MASKS_INIT;
static const uint8_t hi_ctrl[CHIP_SELECTS] = HI_CTRL_MASKS_INIT;
static const uint8_t hi_dhi[CHIP_SELECTS] = HI_DHI_MASKS_INIT;

/* the level of the data-high port's /CS lines: a line the firmware does not drive is pulled
 * up (the README's 10k pull-ups), so a firmware that leaves them inputs (1.0) selects no chip */
static uint8_t dhi_level(fitl_t *h, uint8_t port)
{
    return (uint8_t)((port & h->hi_ddr) | ~h->hi_ddr);
}

/* the chip whose /CS is low on (control port, data-high port): -1 none, -2 more than one */
static int chip_of(uint8_t ctrl, uint8_t dhi)
{
    int found = -1;
    for (int k = 0; k < (int)CHIP_SELECTS; k++)
        if ((cs_ctrl[k] && !(ctrl & cs_ctrl[k])) || (cs_dhi[k] && !(dhi & cs_dhi[k])))
            found = found == -1 ? k : -2;
    return found;
}

static int call(fitl_t *h, int kind, int value)
{
    h->bus_cycles++;
    int chip = h->chip < 0 ? 0 : h->chip;
    int r = h->cb(kind | chip << 4, value, h->avr->cycle);
    if (r < 0) {
        h->stop = h->failed = 1;
        return 0;
    }
    for (int k = 0; k < (int)CHIP_SELECTS; k++)
        if (h->hi_pins[k])
            avr_raise_irq(h->hi_pins[k], (r >> (8 + k)) & 1);
    h->hi_levels = (uint8_t)((r >> 8) & 0x0F);
    return r & 0xFF;
}

static uint8_t data_byte(fitl_t *h)
{
    return (uint8_t)(((h->lo_port & DATA_LO_MASK) >> DATA_LO_SHIFT)
                     | ((h->hi_port & DATA_HI_MASK) << DATA_HI_SHIFT));
}

/* D0-D7 as the AVR drives them: which lines are outputs */
static uint8_t data_ddr(fitl_t *h)
{
    return (uint8_t)(((h->lo_ddr & DATA_LO_MASK) >> DATA_LO_SHIFT)
                     | ((h->hi_ddr & DATA_HI_MASK) << DATA_HI_SHIFT));
}

static void log_pins(fitl_t *h)
{
    if (!h->pins_on)
        return;
    uint8_t out = data_ddr(h);
    uint8_t undriven = h->chip_drives ? h->driven : 0xFF;
    uint32_t v = (uint8_t)((data_byte(h) & out) | (undriven & ~out));
    v |= (h->ctrl & PIN_RD ? 1u : 0u) << 8 | (h->ctrl & PIN_WR ? 1u : 0u) << 9
         | (h->ctrl & PIN_PS ? 1u : 0u) << 10 | (h->ctrl & PIN_RST ? 1u : 0u) << 11;
    uint8_t dhi = dhi_level(h, h->hi_port);
    for (int k = 0; k < (int)CHIP_SELECTS; k++) {
        int high = cs_ctrl[k] ? !!(h->ctrl & cs_ctrl[k]) : cs_dhi[k] ? !!(dhi & cs_dhi[k]) : 1;
        v |= (uint32_t)high << (12 + k);
    }
    v |= (uint32_t)h->hi_levels << 16;
    if (h->log_len && v == h->log_last)
        return;
    if (h->log_len == h->log_cap) {
        uint32_t cap = h->log_cap ? 2 * h->log_cap : 4096;
        uint64_t *c = realloc(h->log_cycle, cap * sizeof *c);
        uint32_t *l = c ? realloc(h->log_levels, cap * sizeof *l) : NULL;
        if (c)
            h->log_cycle = c;
        if (!l)
            return; /* out of memory: the log misses changes, the simulation goes on */
        h->log_levels = l;
        h->log_cap = cap;
    }
    h->log_cycle[h->log_len] = h->avr->cycle;
    h->log_levels[h->log_len++] = v;
    h->log_last = v;
}

static void ctrl_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    uint64_t now = h->avr->cycle;
    uint8_t v = (uint8_t)value, old = h->ctrl, fell = old & ~v, rose = ~old & v;
    h->ctrl = v;
    if (!((fell | rose) & 0xFF))
        return;
    h->chip = chip_of(v, dhi_level(h, h->hi_port));
    if ((fell | rose) & (PIN_CS | PIN_PS)) {
        if (!(old & PIN_RD) || !(old & PIN_WR))
            violation(h, "/CS or /PS changed during a strobe");
        h->sel_change = now;
    }
    if (fell & PIN_RST)
        h->rst_fall = now;
    if (rose & PIN_RST)
        call(h, FITL_RESET, (int)(now - h->rst_fall));
    int selected = h->chip >= 0;
    if ((fell & (PIN_RD | PIN_WR)) && h->chip == -2)
        violation(h, "two chips selected during a strobe");
    if ((fell & (PIN_RD | PIN_WR)) && selected) {
        if (!(v & PIN_RD) && !(v & PIN_WR))
            violation(h, "/RD and /WR low together");
        if (now - h->strobe_rise < T_RECOVERY)
            violation(h, "strobe recovery shorter than 120 ns");
        if (now - h->sel_change < T_PS_SETUP)
            violation(h, "/CS or /PS setup before the strobe shorter than 30 ns");
    }
    if ((fell & PIN_RD) && selected) {
        h->rd_fall = now;
        if ((h->lo_ddr & DATA_LO_MASK) || (h->hi_ddr & DATA_HI_MASK))
            violation(h, "read strobe while the AVR drives the data bus");
        int b = call(h, (v & PIN_PS) ? FITL_READ : FITL_STATUS, 0);
        h->pending = (uint8_t)b;
        h->chip_drives = 1;
        drive_data(h, (uint8_t)~b);
        avr_cycle_timer_register(h->avr, h->access_cycles, access_done, h);
    }
    if ((fell & PIN_WR) && selected)
        h->wr_fall = now;
    if ((rose & PIN_RD) && selected) {
        if (now - h->rd_fall < (uint64_t)h->access_cycles)
            violation(h, "/RD released before the read access time");
        h->strobe_rise = now;
    }
    if ((rose & PIN_WR) && selected) {
        if (now - h->wr_fall < T_STROBE)
            violation(h, "/WR pulse shorter than 100 ns");
        if (now - h->data_change < T_SETUP_DATA)
            violation(h, "write data setup shorter than 50 ns");
        if ((h->lo_ddr & DATA_LO_MASK) != DATA_LO_MASK || (h->hi_ddr & DATA_HI_MASK) != DATA_HI_MASK)
            violation(h, "write strobe with the data bus not driven");
        h->strobe_rise = h->wr_rise = now;
        call(h, (v & PIN_PS) ? FITL_WRITE : FITL_COMMAND, data_byte(h));
    }
    if (rose & PIN_RD)
        h->chip_drives = 0;
    log_pins(h);
}

static void data_changed(fitl_t *h)
{
    uint64_t now = h->avr->cycle;
    h->data_change = now;
    if (!(h->ctrl & PIN_WR) && !(h->ctrl & PIN_CS))
        violation(h, "data bus changed while /WR is low");
    else if (now - h->wr_rise < T_HOLD)
        violation(h, "write data hold shorter than 120 ns");
}

static void lo_port_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    uint8_t v = (uint8_t)value;
    if ((v ^ h->lo_port) & DATA_LO_MASK & h->lo_ddr) {
        h->lo_port = v;
        data_changed(h);
    }
    h->lo_port = v;
    log_pins(h);
}

static void hi_port_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    uint8_t v = (uint8_t)value;
    if ((dhi_level(h, v) ^ dhi_level(h, h->hi_port)) & CS_DHI_ALL) { /* a /CS of chips 1-3 */
        if (!(h->ctrl & PIN_RD) || !(h->ctrl & PIN_WR))
            violation(h, "/CS changed during a strobe");
        h->sel_change = h->avr->cycle;
        h->chip = chip_of(h->ctrl, dhi_level(h, v));
    }
    if ((v ^ h->hi_port) & DATA_HI_MASK & h->hi_ddr) {
        h->hi_port = v;
        data_changed(h);
    }
    h->hi_port = v;
    log_pins(h);
}

static void lo_ddr_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    if (((uint8_t)value ^ h->lo_ddr) & DATA_LO_MASK) {
        h->lo_ddr = (uint8_t)value;
        data_changed(h);
    }
    h->lo_ddr = (uint8_t)value;
    log_pins(h);
}

static void hi_ddr_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    if (((uint8_t)value ^ h->hi_ddr) & CS_DHI_ALL) { /* /CS lines of chips 1-3 made outputs */
        uint8_t old = dhi_level(h, h->hi_port);
        uint8_t ddr = h->hi_ddr;
        h->hi_ddr = (uint8_t)value;
        if ((dhi_level(h, h->hi_port) ^ old) & CS_DHI_ALL)
            h->sel_change = h->avr->cycle;
        h->chip = chip_of(h->ctrl, dhi_level(h, h->hi_port));
        h->hi_ddr = ddr; /* the data-bus bookkeeping below compares against the old value */
    }
    if (((uint8_t)value ^ h->hi_ddr) & DATA_HI_MASK) {
        h->hi_ddr = (uint8_t)value;
        data_changed(h);
    }
    h->hi_ddr = (uint8_t)value;
    log_pins(h);
}

static void pump(fitl_t *h)
{
    while (h->xon && h->in_tail != h->in_head) {
        uint8_t b = h->in_q[h->in_tail];
        h->in_tail = (h->in_tail + 1) % QSIZE;
        h->bytes_in++;
        avr_raise_irq(h->uart_in, b); /* may call the XOFF hook */
    }
}

static void xon_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value;
    fitl_t *h = param;
    h->xon_events++;
    h->xon = 1;
    pump(h);
}

static void xoff_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    if (value) {
        ((fitl_t *)param)->xon = 0;
        ((fitl_t *)param)->xoff_events++;
    }
}

static void out_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fitl_t *h = param;
    if (h->out_len < QSIZE)
        h->out[h->out_len++] = (uint8_t)value;
    if ((uint8_t)value == 0)
        h->out_frames++;
}

/* elf_read_firmware mallocs the image's sections (12 KiB of flash and more per open) and
 * avr_load_firmware copies them: the flash and EEPROM images are kept (fitl_restart loads them
 * again), the rest is freed at once */
static void release_firmware(elf_firmware_t *fw)
{
    free(fw->flash);
    free(fw->eeprom);
    free(fw->fuse);
    free(fw->lockbits);
    if (fw->symbol) {
        for (uint32_t i = 0; i < fw->symbolcount; i++)
            free(fw->symbol[i]);
        free(fw->symbol);
    }
    fw->flash = fw->eeprom = fw->fuse = fw->lockbits = NULL;
    fw->symbol = NULL;
}

/* the bus callback while the AVR is reset, between two sessions: nobody listens */
static int no_bus(int kind, int value, uint64_t cycle)
{
    (void)kind; (void)value; (void)cycle;
    return 0;
}

/* What the harness sets in simavr after the firmware is loaded: a reset (avr_reset) puts some of
 * it back to simavr's defaults, so it is set again at every power-on. */
static void configure(avr_t *avr)
{
    avr->frequency = CPU_HZ;
    avr->log = 0;
    avr->sleep = no_sleep;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
}

/* One session from power-on: the harness's state as new (every field from `cb` on), the HI lines
 * low, then the firmware boots until its receiver is on (bytes raised before that are dropped by
 * simavr).  0, or -1 when the receiver never came on (fitl_error says so). */
static int power_on(fitl_t *h, fitl_bus_cb cb, const char *what)
{
    avr_t *avr = h->avr;
    free(h->log_cycle);
    free(h->log_levels);
    memset(&h->cb, 0, sizeof *h - offsetof(fitl_t, cb));
    h->cb = cb;
    h->access_cycles = 4; /* 180 ns = 2.9 cycles, rounded up, + 1 for the PINx synchroniser */
    h->ctrl = 0xFF;
    h->xon = 1;
    h->chip = -1;
    h->hi_port = 0; /* reset values: port and direction 0, the /CS lines pulled up */
    h->hi_ddr = 0;
    avr_raise_irq(h->hi_pin, 0);
    for (int k = 0; k < (int)CHIP_SELECTS; k++)
        if (h->hi_pins[k])
            avr_raise_irq(h->hi_pins[k], 0);
    int st = cpu_Running;
    while (avr->cycle < 1000000 && !(avr->data[0xC1] & (1 << 4)) && st != cpu_Crashed && st != cpu_Done)
        st = avr_run(avr); /* a crashed AVR's cycle count stands still: it must end the loop */
    if (st == cpu_Crashed || st == cpu_Done) {
        snprintf(last_error, sizeof last_error, "the firmware in %s %s at AVR cycle %llu, before it "
                 "enabled its UART receiver", what, st == cpu_Done ? "went to sleep for good" : "crashed",
                 (unsigned long long)avr->cycle);
        return -1;
    }
    if (!(avr->data[0xC1] & (1 << 4))) {
        snprintf(last_error, sizeof last_error, "the firmware in %s never enabled its UART receiver", what);
        return -1;
    }
    return 0;
}

fitl_t *fitl_new(const char *elf_path, fitl_bus_cb cb)
{
    avr_global_logger_set(quiet_logger);
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf_path, &fw) != 0) {
        snprintf(last_error, sizeof last_error, "cannot read firmware ELF %s", elf_path);
        return NULL;
    }
    avr_t *avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        release_firmware(&fw);
        snprintf(last_error, sizeof last_error, "simavr has no atmega328p core");
        return NULL;
    }
    avr_init(avr);
    avr->frequency = CPU_HZ;
    avr->log = 0;
    avr_load_firmware(avr, &fw);
    fitl_t *h = calloc(1, sizeof *h);
    h->avr = avr;
    /* copied into the AVR; the flash and EEPROM images are kept for fitl_restart */
    h->image_flash = fw.flash;
    h->image_flashsize = fw.flashsize;
    h->image_flashbase = fw.flashbase;
    h->image_datasize = fw.datasize;
    h->image_eeprom = fw.eeprom;
    h->image_eesize = fw.eeprom ? fw.eesize : 0;
    fw.flash = fw.eeprom = NULL;
    release_firmware(&fw);
    configure(avr);

    avr_irq_t *c = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(CTRL_PORT_LETTER), IOPORT_IRQ_REG_PORT);
    avr_irq_register_notify(c, ctrl_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_LO_PORT_LETTER), IOPORT_IRQ_REG_PORT), lo_port_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_HI_PORT_LETTER), IOPORT_IRQ_REG_PORT), hi_port_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_LO_PORT_LETTER), IOPORT_IRQ_DIRECTION_ALL), lo_ddr_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_HI_PORT_LETTER), IOPORT_IRQ_DIRECTION_ALL), hi_ddr_hook, h);
    for (int i = 0; i < 8; i++) {
        h->data_lo_pin[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_LO_PORT_LETTER), i + DATA_LO_SHIFT < 8 ? i + DATA_LO_SHIFT : 0);
        h->data_hi_pin[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(DATA_HI_PORT_LETTER), i < 2 ? i : 0);
    }
    int hi_bit = 0;
    while (hi_bit < 8 && (1u << hi_bit) != PIN_HI)
        hi_bit++;
    h->hi_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(CTRL_PORT_LETTER), hi_bit);
    for (int k = 0; k < (int)CHIP_SELECTS; k++) {
        uint8_t m = hi_ctrl[k] ? hi_ctrl[k] : hi_dhi[k];
        int bit = 0;
        while (m && !(m & (1u << bit)))
            bit++;
        h->hi_pins[k] = !m ? NULL : avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(
            hi_ctrl[k] ? CTRL_PORT_LETTER : DATA_HI_PORT_LETTER), bit);
    }
    h->uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), out_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), xon_hook, h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), xoff_hook, h);
    if (power_on(h, cb, elf_path)) {
        fitl_free(h);
        return NULL;
    }
    return h;
}

/* Power the same simulated AVR on again, for a new session with `cb`, as avr_init and
 * avr_load_firmware left it in fitl_new: RAM and registers zero, the flash and the EEPROM as the
 * image says, every IRQ's level as when it was made (0, not yet raised), the cycle count 0, then
 * simavr's own reset of the core and the peripherals and the harness's settings and boot.  Why
 * not a new AVR: simavr 1.6 never frees part of what avr_init makes (IRQ names, pools, about
 * 5 KB in some 100 blocks an AVR), so an open/close leaked that each time.  0, or -1 when the
 * firmware did not boot (the AVR is then unusable: fitl_free it). */
int fitl_restart(fitl_t *h, fitl_bus_cb cb)
{
    avr_t *avr = h->avr;
    h->cb = no_bus; /* the hooks may run during the reset: never into a closed session's model */
    memset(avr->data, 0, avr->ramend + 1);
    memset(avr->flash, 0xff, avr->flashend + 1);
    if (h->image_flash)
        memcpy(avr->flash + h->image_flashbase, h->image_flash, h->image_flashsize);
    avr->codeend = h->image_flashsize + h->image_flashbase - h->image_datasize;
    avr_eeprom_desc_t ee = { .ee = NULL, .offset = 0, .size = avr->e2end + 1 };
    avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &ee);
    if (ee.ee)
        memset(ee.ee, 0xff, avr->e2end + 1);
    if (h->image_eeprom && h->image_eesize) {
        avr_eeprom_desc_t d = { .ee = h->image_eeprom, .offset = 0, .size = h->image_eesize };
        avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
    }
    for (int i = 0; i < avr->irq_pool.count; i++) {
        avr_irq_t *irq = avr->irq_pool.irq[i];
        if (irq) {
            irq->value = 0;
            irq->flags = (irq->flags & ~IRQ_FLAG_FLOATING) | IRQ_FLAG_INIT;
        }
    }
    avr->cycle = 0;
    avr_reset(avr);
    avr_regbit_set(avr, avr->reset_flags.porf); /* as avr_init: a power-on reset */
    configure(avr);
    return power_on(h, cb, "the firmware image");
}

void fitl_free(fitl_t *h)
{
    if (!h)
        return;
    h->cb = no_bus; /* a closed session's callback may be gone */
    avr_terminate(h->avr);
    free(h->avr);
    free(h->log_cycle);
    free(h->log_levels);
    free(h->image_flash);
    free(h->image_eeprom);
    free(h);
}

int fitl_write(fitl_t *h, const uint8_t *data, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++) {
        uint32_t next = (h->in_head + 1) % QSIZE;
        if (next == h->in_tail)
            return (int)i;
        h->in_q[h->in_head] = data[i];
        h->in_head = next;
    }
    pump(h);
    return (int)n;
}

/* Run until `until` cycles, or (frames != 0) until the firmware has sent a 0x00 delimiter.
 * Returns 0 at `until`, 1 on a delimiter, -1 when the Python callback failed, -2 on a crash. */
static avr_cycle_count_t wake(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr; (void)when; (void)param;
    return 0;
}

int fitl_run(fitl_t *h, uint64_t until, int frames)
{
    avr_t *avr = h->avr;
    h->stop = 0;
    /* a sleeping AVR jumps to its next cycle timer (a Timer1 wrap is 262 ms away): a timer at
     * `until` keeps the jump from overshooting */
    if (until > avr->cycle)
        avr_cycle_timer_register(avr, until - avr->cycle, wake, h);
    while (avr->cycle < until) {
        if (frames && h->out_frames) {
            avr_cycle_timer_cancel(avr, wake, h);
            return 1;
        }
        int st = avr_run(avr);
        if (h->stop || st == cpu_Done || st == cpu_Crashed) {
            avr_cycle_timer_cancel(avr, wake, h);
            return h->stop ? -1 : -2;
        }
        if (h->xon && h->in_tail != h->in_head)
            pump(h);
    }
    avr_cycle_timer_cancel(avr, wake, h);
    return (frames && h->out_frames) ? 1 : 0;
}

uint32_t fitl_read(fitl_t *h, uint8_t *buf, uint32_t max)
{
    uint32_t n = h->out_len < max ? h->out_len : max;
    memcpy(buf, h->out, n);
    memmove(h->out, h->out + n, h->out_len - n);
    h->out_len -= n;
    h->out_frames = 0;
    for (uint32_t i = 0; i < h->out_len; i++)
        if (!h->out[i])
            h->out_frames++;
    return n;
}

uint64_t fitl_cycle(fitl_t *h) { return h->avr->cycle; }
uint32_t fitl_pending_input(fitl_t *h) { return (h->in_head - h->in_tail + QSIZE) % QSIZE; }
uint64_t fitl_bus_cycles(fitl_t *h) { return h->bus_cycles; }
void fitl_set_access_cycles(fitl_t *h, int cycles) { h->access_cycles = cycles; }
uint32_t fitl_violations(fitl_t *h, char *buf, uint32_t size)
{
    if (size) {
        strncpy(buf, h->first_violation, size - 1);
        buf[size - 1] = 0;
    }
    return h->violations;
}
void fitl_set_hi(fitl_t *h, int level) { avr_raise_irq(h->hi_pin, level ? 1 : 0); }
void fitl_uart_counts(fitl_t *h, uint64_t *out)
{
    out[0] = h->bytes_in;
    out[1] = h->xon_events;
    out[2] = h->xoff_events;
}
/* a byte of the AVR's data space (registers, I/O, RAM), for tests and profiling */
uint8_t fitl_peek(fitl_t *h, uint16_t addr) { return h->avr->data[addr]; }
/* the AVR's program counter (byte address), for profiling */
uint32_t fitl_pc(fitl_t *h) { return h->avr->pc; }

/* The pin log (see the top of this file): switch it on (logging the levels now) or off. */
void fitl_pin_log(fitl_t *h, int on)
{
    h->pins_on = on;
    h->log_len = 0;
    log_pins(h);
}

/* Take up to `max` entries of the pin log, oldest first; returns how many. */
uint32_t fitl_pin_log_take(fitl_t *h, uint64_t *cycles, uint32_t *levels, uint32_t max)
{
    uint32_t n = h->log_len < max ? h->log_len : max;
    memcpy(cycles, h->log_cycle, n * sizeof *cycles);
    memcpy(levels, h->log_levels, n * sizeof *levels);
    memmove(h->log_cycle, h->log_cycle + n, (h->log_len - n) * sizeof *cycles);
    memmove(h->log_levels, h->log_levels + n, (h->log_len - n) * sizeof *levels);
    h->log_len -= n;
    return n;
}

/* For the tests that an AVR powered on again (fitl_restart) is as a new one: its data space
 * (which 0: registers, I/O, RAM), flash (1) or EEPROM (2), and its size; NULL for another. */
static uint8_t *memory_of(fitl_t *h, int which, uint32_t *size)
{
    avr_t *avr = h->avr;
    if (which == 2) {
        avr_eeprom_desc_t ee = { .ee = NULL, .offset = 0, .size = avr->e2end + 1u };
        avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &ee);
        *size = avr->e2end + 1u;
        return ee.ee;
    }
    *size = which == 0 ? avr->ramend + 1u : avr->flashend + 1u;
    return which == 0 ? avr->data : which == 1 ? avr->flash : NULL;
}

/* ... a copy of up to `max` bytes of one of them; returns its size (0: no such memory) */
uint32_t fitl_memory(fitl_t *h, int which, uint8_t *buf, uint32_t max)
{
    uint32_t size;
    uint8_t *mem = memory_of(h, which, &size);
    if (!mem)
        return 0;
    memcpy(buf, mem, size < max ? size : max);
    return size;
}

/* ... a byte of one of them changed, as a firmware that wrote its flash or EEPROM would; 0, or
 * -1 outside it */
int fitl_poke(fitl_t *h, int which, uint32_t address, uint8_t value)
{
    uint32_t size;
    uint8_t *mem = memory_of(h, which, &size);
    if (!mem || address >= size)
        return -1;
    mem[address] = value;
    return 0;
}

/* ... and each of simavr's IRQs: its level and flags (two words; a freed slot 0xFFFFFFFF twice),
 * as many as fit in `max` words; returns the number of IRQ slots. */
uint32_t fitl_irq_state(fitl_t *h, uint32_t *out, uint32_t max)
{
    avr_irq_pool_t *pool = &h->avr->irq_pool;
    for (int i = 0; i < pool->count && 2u * i + 1 < max; i++) {
        avr_irq_t *irq = pool->irq[i];
        out[2 * i] = irq ? irq->value : 0xFFFFFFFFu;
        out[2 * i + 1] = irq ? irq->flags : 0xFFFFFFFFu;
    }
    return (uint32_t)pool->count;
}
