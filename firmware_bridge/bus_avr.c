/* The LM629 bus on the ATmega328P's ports (pin map: lm629_tables.h, from bridge_pins.py).
 *
 * Timing at 16 MHz (one cycle 62.5 ns) against the chip's minimums (6 MHz table):
 *   /CS and /PS change one port write before the strobe falls: >= 62.5 ns setup (30 ns);
 *   /WR low for 3 cycles: 187 ns (100 ns); data set before /WR falls, so setup >= 250 ns (50 ns);
 *   data held >= 3 cycles after /WR rises: 187 ns (120 ns);
 *   /RD sampled 7 cycles after it falls: 437 ns, against a 180 ns access time plus the
 *   ~1.5-cycle input synchroniser of PINx;
 *   strobes are >= 4 cycles apart: 250 ns recovery (120 ns);
 *   /RST low for 10 us: 8 clocks of a chip clocked as slowly as 1 MHz, with margin.
 * The data bus idles as an input without pull-ups and is driven only for a write.
 *
 * Several chips: each has its own /CS (CS_*_MASKS_INIT: chip 0 on the control port, chips 1-3
 * on the data-high port beside D6-D7).  bus_select() works out the control port's values for
 * the strobes of the chip it selects, and holds a data-high-port /CS low until the next
 * bus_select (the chip ignores /CS without a strobe): never two chips selected together, and a
 * strobe costs what it cost on a one-chip bridge. */
#include <avr/io.h>
#include <util/delay.h>
#include "bus.h"
#include "lm629_tables.h"

#define NOP() __asm__ __volatile__("nop")

static uint16_t timer_start;
static const uint8_t cs_ctrl[CHIP_SELECTS] = CS_CTRL_MASKS_INIT;
static const uint8_t cs_dhi[CHIP_SELECTS] = CS_DHI_MASKS_INIT;
static const uint8_t hi_ctrl[CHIP_SELECTS] = HI_CTRL_MASKS_INIT;
static const uint8_t hi_dhi[CHIP_SELECTS] = HI_DHI_MASKS_INIT;
#define CTRL_IDLE (PIN_CS | PIN_PS | PIN_RD | PIN_WR | PIN_RST) /* and HI: input, no pull-up */
/* the control port during a strobe of the selected chip, /PS low (status, command) or high
 * (data), and its /CS on the data-high port (0: on the control port); chip 0 until selected */
static uint8_t sel_ctrl = PIN_CS, sel_ctrl_ps = CTRL_IDLE & ~(PIN_CS | PIN_PS),
               sel_ctrl_data = CTRL_IDLE & ~PIN_CS, sel_dhi;
static uint8_t sel_hi_ctrl = PIN_HI, sel_hi_dhi; /* the selected chip's HI line */

/* A /CS on the data-high port (chips 1-3) is held low from here until the next bus_select
 * (link_run ends every program with bus_select(0), which releases them all); the chip ignores
 * /CS without a strobe, so each strobe costs what it did on a one-chip bridge.  Chip 0's /CS,
 * on the control port, falls and rises with each strobe as before. */
void bus_select(uint8_t chip)
{
    sel_hi_ctrl = hi_ctrl[chip];
    sel_hi_dhi = hi_dhi[chip];
    sel_ctrl = cs_ctrl[chip];
    sel_ctrl_ps = (uint8_t)(CTRL_IDLE & ~(sel_ctrl | PIN_PS));
    sel_ctrl_data = (uint8_t)(CTRL_IDLE & ~sel_ctrl);
    sel_dhi = cs_dhi[chip];
    DATA_HI_PORT = (uint8_t)((DATA_HI_PORT | CS_DHI_ALL) & ~sel_dhi);
}

void bus_init(void)
{
    CTRL_PORT = PIN_CS | PIN_PS | PIN_RD | PIN_WR | PIN_RST; /* all high, HI without pull-up */
    CTRL_DDR = PIN_CS | PIN_PS | PIN_RD | PIN_WR | PIN_RST;
    DATA_LO_DDR &= (uint8_t)~DATA_LO_MASK;
    DATA_LO_PORT &= (uint8_t)~DATA_LO_MASK;
    DATA_HI_DDR &= (uint8_t)~DATA_HI_MASK;
    DATA_HI_PORT &= (uint8_t)~DATA_HI_MASK;
    DATA_HI_PORT = (uint8_t)((DATA_HI_PORT | CS_DHI_ALL) & ~HI_DHI_ALL); /* /CS1.. high */
    DATA_HI_DDR = (uint8_t)((DATA_HI_DDR | CS_DHI_ALL) & ~HI_DHI_ALL);
    TCCR1A = 0;
    TCCR1B = (1 << CS11) | (1 << CS10); /* clk/64: 4 us per tick, 262 ms per wrap */
}

static inline void drive(uint8_t b)
{
    DATA_LO_PORT = (uint8_t)((DATA_LO_PORT & ~DATA_LO_MASK) | ((uint8_t)(b << DATA_LO_SHIFT) & DATA_LO_MASK));
    DATA_HI_PORT = (uint8_t)((DATA_HI_PORT & ~DATA_HI_MASK) | ((uint8_t)(b >> DATA_HI_SHIFT) & DATA_HI_MASK));
    DATA_LO_DDR |= DATA_LO_MASK;
    DATA_HI_DDR |= DATA_HI_MASK;
}

static inline void release(void)
{
    DATA_LO_DDR &= (uint8_t)~DATA_LO_MASK;
    DATA_HI_DDR &= (uint8_t)~DATA_HI_MASK;
    DATA_LO_PORT &= (uint8_t)~DATA_LO_MASK;
    DATA_HI_PORT &= (uint8_t)~DATA_HI_MASK;
}

/* /CS of the selected chip (and /PS low when `ps`) before a strobe, as whole port values
 * worked out by bus_select (one `out` each); returns the control port's value.  All high
 * after the strobe. */
static inline __attribute__((always_inline)) uint8_t assert_select(uint8_t ps)
{
    uint8_t v = ps ? sel_ctrl_ps : sel_ctrl_data;
    CTRL_PORT = v;
    return v;
}

static inline __attribute__((always_inline)) void release_select(void)
{
    CTRL_PORT = CTRL_IDLE;
}

static inline __attribute__((always_inline)) void write_cycle(uint8_t ps, uint8_t b)
{
    drive(b);
    uint8_t v = assert_select(ps);
    CTRL_PORT = (uint8_t)(v & ~PIN_WR);
    NOP();
    NOP();
    CTRL_PORT = v;
    NOP();
    release_select();
    release();
}

/* a read strobe; the data pins as sampled (two ports) */
typedef struct {
    uint8_t lo, hi;
} pins_t;

static inline __attribute__((always_inline)) pins_t read_pins(uint8_t ps)
{
    pins_t p;
    uint8_t v = assert_select(ps);
    CTRL_PORT = (uint8_t)(v & ~PIN_RD);
    NOP(); NOP(); NOP(); NOP(); NOP(); NOP(); NOP(); /* sampled 8 cycles after /RD fell */
    p.lo = DATA_LO_PIN;
    p.hi = DATA_HI_PIN;
    CTRL_PORT = v;
    NOP();
    release_select();
    return p;
}

static inline __attribute__((always_inline)) uint8_t pins_byte(pins_t p)
{
    return (uint8_t)(((p.lo & DATA_LO_MASK) >> DATA_LO_SHIFT) | ((p.hi & DATA_HI_MASK) << DATA_HI_SHIFT));
}

static inline __attribute__((always_inline)) uint8_t read_cycle(uint8_t ps)
{
    return pins_byte(read_pins(ps));
}

uint8_t bus_read_status(void) { return read_cycle(PIN_PS); }
void bus_write_command(uint8_t cmd) { write_cycle(PIN_PS, cmd); }
void bus_write_data(uint8_t byte) { write_cycle(0, byte); }
uint8_t bus_read_data(void) { return read_cycle(0); }

void bus_reset_pulse(void)
{
    CTRL_PORT &= (uint8_t)~PIN_RST;
    _delay_us(10);
    CTRL_PORT |= PIN_RST;
}

/* HI of the selected chip, where it has a line (chips 2 and 3 have none: 0) */
uint8_t bus_hi(void) { return ((CTRL_PIN & sel_hi_ctrl) | (DATA_HI_PIN & sel_hi_dhi)) ? 1 : 0; }

void bus_timer_start(void) { timer_start = TCNT1; }

uint16_t bus_ticks(void) { return TCNT1; }

uint8_t bus_timer_elapsed(uint16_t us)
{
    /* ticks of 4 us; one more than us/4 so that a start late in a tick still waits `us` */
    return (uint16_t)(TCNT1 - timer_start) > (uint16_t)(us >> 2);
}

/* The busy bit is D0, on the low data port: each poll tests that pin alone, and the status
 * byte is put together once, at the end.  Not inlined, so that the loop keeps its state in
 * registers: a poll every 27 cycles, busy is seen clear within 2 us of clearing. */
#if (STATUS_BUSY << DATA_LO_SHIFT) & ~DATA_LO_MASK
#error "the busy bit is expected on the low data port"
#endif
/* The poll loop writes whole port values worked out before it (one `out` each), so a poll
 * takes 25 cycles whichever chip is selected (a /CS on the data-high port is held low by
 * bus_select). */
__attribute__((noinline)) uint8_t bus_wait_not_busy(uint16_t timeout_us, uint8_t *status)
{
    uint16_t start = TCNT1, ticks = timeout_us >> 2;
    uint8_t ok = 1;
    const uint8_t c_sel = sel_ctrl_ps;
    const uint8_t c_rd = (uint8_t)(c_sel & ~PIN_RD);
    pins_t p;
    for (;;) {
        CTRL_PORT = c_sel;
        CTRL_PORT = c_rd;
        NOP(); NOP(); NOP(); NOP(); NOP(); NOP(); NOP(); /* 8 cycles, as read_pins */
        p.lo = DATA_LO_PIN;
        p.hi = DATA_HI_PIN;
        CTRL_PORT = c_sel;
        NOP();
        CTRL_PORT = CTRL_IDLE;
        if (!(p.lo & (uint8_t)(STATUS_BUSY << DATA_LO_SHIFT)))
            break;
        if ((uint16_t)(TCNT1 - start) > ticks) { /* as bus_timer_elapsed */
            ok = 0;
            break;
        }
    }
    *status = pins_byte(p);
    return ok;
}

void bus_wait_us(uint16_t us)
{
    if (!us)
        return;
    bus_timer_start();
    while (!bus_timer_elapsed(us))
        ;
}
