/* The link protocol of PROTOCOL.md: COBS framing, CRC-16/GENIBUS, request dispatch with the
 * exactly-once reply cache, and the bus-program interpreter.  Plain C99 without AVR headers:
 * the same file is compiled for the ATmega328P and for the host's unit tests and fuzz run. */
#ifndef LINK_H
#define LINK_H
#include <stdint.h>
#include "lm629_tables.h"

/* FIRMWARE_MAJOR/MINOR/PATCH: lm629_tables.h, from lm629_host.bridge.protocol.FIRMWARE_VERSION
 * (the Python far end reports the same release) */
#ifdef LINK_ONE_CHIP /* build/lm629_bridge_1chip: a bridge that reports one chip select */
#define LINK_CHIP_SELECTS 1
#else
#define LINK_CHIP_SELECTS CHIP_SELECTS /* lm629_tables.h, from bridge_pins.CHIP_SELECTS */
#endif
#define LINK_MAX_PROGRAM (LINK_MAX_FRAME - LINK_RUN_OVERHEAD)
#define LINK_MAX_READS ((LINK_MAX_FRAME - LINK_RUN_REPLY_OVERHEAD) / 2)
#ifndef LINK_CPU_HZ
#define LINK_CPU_HZ 16000000UL
#endif

#ifdef __AVR__
typedef uint16_t link_count_t; /* RAM is short on the AVR: the counters wrap */
#else
typedef uint32_t link_count_t;
#endif

typedef struct {
    /* small fields first: the AVR reaches them with a one-word displacement (0..63) */
    uint16_t rx_len;                    /* decoded bytes so far */
    uint8_t rx_bad;                     /* too long or bad COBS: drop up to the next 0x00 */
    uint8_t code, code_left, started;   /* COBS decoder: current block code, bytes left in it */
    uint16_t crc;                       /* CRC register over rx[0 .. rx_len - 2) */
    uint16_t cache_len;                 /* 0: no cached reply */
    uint8_t cache_seq;
    uint16_t cache_crc;
    uint16_t baud_div;                  /* SET_BAUD answered: the new U2X divisor (0: none) */
    /* counters (for tests) */
    link_count_t frames, bad_frames, runs, cache_hits;
    /* a RUN_SHORT's program, checked as its bytes arrive (two behind, as the CRC): the
     * argument bytes still due of the current operation, operations, reads and statuses so
     * far, and 1 + the index of the first bad operation (0: none) */
    uint8_t chk_args, chk_ops, chk_reads, chk_status, chk_bad, chk_select;
    /* programs kept for RUN_CODE: size (0: none), reads and statuses (checked when stored) */
    uint8_t code_len[LINK_CODE_SLOTS], code_reads[LINK_CODE_SLOTS], code_status[LINK_CODE_SLOTS];
    uint8_t codes[LINK_CODE_SLOTS][LINK_CODE_BYTES];
    uint8_t rx[LINK_MAX_WIRE_FRAME];    /* the frame being received, COBS-decoded as its bytes
                                           arrive; non-RUN replies are encoded here too */
    uint8_t reply[LINK_MAX_FRAME];      /* decoded reply being built */
    uint8_t cache[LINK_MAX_WIRE_FRAME]; /* encoded reply to the last RUN (exactly once) */
    /* PROFILE: the pieces still to issue, a ring from prof_head (each piece's Timer1 ticks
     * after the one before it, the first's after the start: 6 bytes a piece, RAM is short),
     * the chip they go to, what the schedule did, its clock and the head's due time */
    uint8_t prof_cs, prof_head, prof_n, prof_result;
    uint16_t prof_issued, prof_last;    /* pieces issued; bus_ticks() at the last look */
    uint32_t prof_now, prof_late;       /* ticks since the start; largest lateness (ticks) */
    uint32_t prof_due, prof_tail;       /* the head's ticks from the start; the last piece's */
    uint16_t prof_dt[LINK_PROFILE_MAX_SCHEDULE];
    uint32_t prof_v[LINK_PROFILE_MAX_SCHEDULE];
} link_t;

uint16_t link_crc16(const uint8_t *data, uint16_t len);
/* COBS-encode `len` bytes into `out` (room for len + len/254 + 1), no delimiter; returns size */
uint16_t link_cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out);
/* decode in place (safe: output never overtakes input); returns decoded size, or -1 */
int16_t link_cobs_decode(uint8_t *buf, uint16_t len);

void link_init(link_t *l);
/* A delimiter ended the frame in l->rx: check and answer it (see link_feed). */
uint16_t link_frame_end(link_t *l, const uint8_t **out);
/* One non-zero byte of a frame: COBS-decoded and CRC-summed at once, so that the work of a
 * frame is spread over its wire time instead of waiting for its delimiter. */
void link_byte(link_t *l, uint8_t byte);

/* Feed one received byte.  Returns the number of bytes of a complete encoded reply frame
 * (delimiter included), already sent through link_tx_byte (uart.h), pointed to by *out, or 0.
 * Inline: a byte inside a frame
 * costs a call of the small link_byte, not the register saves of the frame handler. */
static inline uint16_t link_feed(link_t *l, uint8_t byte, const uint8_t **out)
{
    if (byte != 0) {
        link_byte(l, byte);
        return 0;
    }
    return link_frame_end(l, out);
}
/* The bridge's clock in 4 us ticks since start (Timer1, folded into 32 bits: call it at least
 * once per 65536 ticks, 262 ms; main.c's Timer1 interrupts wake the CPU twice per wrap). */
uint32_t link_clock(void);
/* The failsafe: stop every chip when it has expired (the host silent past its timeout). */
void link_poll(void);
/* The low 16 bits of the clock at which the failsafe expires (a compare interrupt wakes the
 * CPU there); anything when it is disarmed. */
uint16_t link_failsafe_wake(void);
/* Between frames: issue the pieces of a shaped move (PROFILE) that are due.  While a schedule
 * holds pieces (l->prof_n) the main loop calls this instead of sleeping. */
void link_idle(link_t *l);
/* Run a RUN payload (cs, timeout, program) and build RUN_REPLY's payload in `reply`;
 * returns its size. */
uint16_t link_run(const uint8_t *payload, uint16_t len, uint8_t *reply);

#endif
