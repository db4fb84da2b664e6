/* Link protocol (PROTOCOL.md), shared by the firmware and the host-side tests. */
#include "link.h"
#include "bus.h"
#include "uart.h"

/* CRC-16/GENIBUS by table: 256 entries written out as literal bytes by tools/gen_tables.py
 * (LINK_CRC_TABLE_INIT in the generated header; made by preprocessor macros instead, one
 * compile of this file took 18 s and 3 GB), in flash on the AVR, as two byte tables (high and low
 * halves) aligned to 256 bytes, so that a step is two `lpm` at base + index and two xors: about
 * 14 AVR cycles a byte (the word table cost 26 with its index doubling; the bit-by-bit or
 * shift-xor forms 100+ with avr-gcc's 16-bit shifts). */
#ifdef __AVR__
#include <avr/pgmspace.h>
#define CRC_TABLE_ATTR PROGMEM __attribute__((aligned(256)))
#define CRC_BYTE(t, i) pgm_read_byte(&(t)[i])
#else
#define CRC_TABLE_ATTR
#define CRC_BYTE(t, i) ((t)[i])
#endif
/* high halves, then low halves */
static const uint8_t crc_tab[512] CRC_TABLE_ATTR = LINK_CRC_TABLE_INIT;

static inline __attribute__((always_inline)) uint16_t crc_step(uint16_t crc, uint8_t b)
{
    uint8_t i = (uint8_t)(crc >> 8) ^ b;
#ifdef __AVR__
    /* the table is 256-aligned: base | index is base + index, and costs no 16-bit add */
    const uint8_t *t = (const uint8_t *)((uintptr_t)crc_tab | i);
#else
    const uint8_t *t = crc_tab + i;
#endif
    uint8_t h = (uint8_t)crc ^ CRC_BYTE(t, 0);
    return (uint16_t)((h << 8) | CRC_BYTE(t, 256));
}

uint16_t link_crc16(const uint8_t *data, uint16_t len)
{
    uint16_t crc = LINK_CRC_INIT;
    while (len--)
        crc = crc_step(crc, *data++);
    return crc ^ LINK_CRC_XOROUT;
}

/* COBS encoder state, pointer-based: ~8 AVR cycles a byte (index arithmetic cost 22) */
typedef struct {
    uint8_t *code_at, *o;
    uint8_t code;
} cobs_t;

static inline __attribute__((always_inline)) void cobs_put(cobs_t *c, uint8_t b)
{
    if (b == 0) {
        *c->code_at = c->code;
        c->code_at = c->o++;
        c->code = 1;
    } else {
        *c->o++ = b;
        if (++c->code == 0xFF) {
            *c->code_at = c->code;
            c->code_at = c->o++;
            c->code = 1;
        }
    }
}

uint16_t link_cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out)
{
    cobs_t c = {out, out + 1, 1};
    while (len--)
        cobs_put(&c, *in++);
    *c.code_at = c.code;
    return (uint16_t)(c.o - out);
}

int16_t link_cobs_decode(uint8_t *buf, uint16_t len)
{
    uint16_t i = 0, o = 0;
    while (i < len) {
        uint8_t code = buf[i++];
        if (code == 0 || (uint16_t)(i + code - 1) > len)
            return -1;
        for (uint8_t k = 1; k < code; k++)
            buf[o++] = buf[i++];
        if (code != 0xFF && i < len)
            buf[o++] = 0;
    }
    return (int16_t)o;
}

static void rx_restart(link_t *l)
{
    l->rx_len = 0;
    l->rx_bad = 0;
    l->code_left = 0;
    l->started = 0;
    l->crc = LINK_CRC_INIT;
    l->chk_args = l->chk_ops = l->chk_reads = l->chk_status = l->chk_bad = l->chk_select = 0;
}

/* ---------------------------------------------------------------- PROFILE: the pieces */
/* The link whose schedule the program loops look at (a WAIT_STATUS, a WAIT, a recording's
 * wait between rows), so that a piece goes out at its time while a program waits. */
static link_t *prof_link;

static uint8_t piece_command(uint8_t cmd)
{
    uint8_t last;
    if (!bus_wait_not_busy(LINK_DEFAULT_BUSY_TIMEOUT_US, &last))
        return 0;
    bus_write_command(cmd);
    return 1;
}

static uint8_t piece_word(uint16_t w)
{
    uint8_t last;
    if (!bus_wait_not_busy(LINK_DEFAULT_BUSY_TIMEOUT_US, &last))
        return 0;
    bus_write_data((uint8_t)(w >> 8));
    bus_write_data((uint8_t)w);
    return 1;
}

/* Issue every piece that is due: LTRJ (velocity only) and STT on the schedule's chip; `chip`
 * is the chip selected now, selected again after.  A busy timeout drops the rest. */
static __attribute__((noinline)) void profile_poll(uint8_t chip)
{
    link_t *l = prof_link;
    if (!l || !l->prof_n)
        return;
    uint16_t t = bus_ticks();
    l->prof_now += (uint16_t)(t - l->prof_last);
    l->prof_last = t;
    while (l->prof_n && (int32_t)(l->prof_now - l->prof_due) >= 0) {
        uint32_t late = l->prof_now - l->prof_due, v = l->prof_v[l->prof_head];
        if (late > l->prof_late)
            l->prof_late = late;
        l->prof_head = (uint8_t)((l->prof_head + 1u) % LINK_PROFILE_MAX_SCHEDULE);
        l->prof_n--;
        l->prof_issued++;
        if (l->prof_cs != chip)
            bus_select(l->prof_cs);
        uint8_t ok = piece_command(CMD_LTRJ) && piece_word(LINK_PROFILE_LTRJ_CONTROL)
            && piece_word((uint16_t)(v >> 16)) && piece_word((uint16_t)v) && piece_command(CMD_STT);
        if (l->prof_cs != chip)
            bus_select(chip);
        /* the next one's due time (unused when none), and never sooner than
         * LINK_PROFILE_MIN_SPACING_US after this one's STT: a piece that went out late (the
         * bridge was busy with a program) must not bring the next STT within 10 ms of its
         * own, which would abort the chip's trajectory calculation (AN-706 4.6.2); late
         * pieces never go out back to back */
        t = bus_ticks();
        l->prof_now += (uint16_t)(t - l->prof_last);
        l->prof_last = t;
        uint32_t next = l->prof_due + l->prof_dt[l->prof_head];
        uint32_t soonest = l->prof_now + LINK_PROFILE_MIN_SPACING_US / LINK_RECORD_TICK_US;
        l->prof_due = (int32_t)(next - soonest) < 0 ? soonest : next;
        if (!ok) {
            l->prof_n = 0;
            l->prof_result = RESULT_BUSY_TIMEOUT;
        }
    }
}

void link_idle(link_t *l)
{
    (void)l;
    profile_poll(0);
}

void link_init(link_t *l)
{
    prof_link = l;
    l->prof_n = l->prof_head = 0;
    l->prof_issued = 0;
    l->prof_late = 0;
    l->prof_result = RESULT_OK;
    rx_restart(l);
    l->cache_len = 0;
    l->baud_div = 0;
    l->frames = l->bad_frames = l->runs = l->cache_hits = 0;
    for (uint8_t k = 0; k < LINK_CODE_SLOTS; k++)
        l->code_len[k] = 0;
}

/* ---------------------------------------------------------------- the failsafe */
/* A timer on this side of the link: every good frame feeds it; when the host has been silent
 * for fs_ms, every chip select that answers is stopped (LTRJ with the action's stop bit, STT,
 * each with the busy discipline) and the trip is latched: programs with STT are refused until
 * a host acknowledges it.  Plain statics: there is one link. */
#define TICKS_PER_MS (1000u / LINK_RECORD_TICK_US)
static uint32_t clock_now, fs_last, fs_silent, fs_at, fs_ticks; /* fs_ticks: fs_ms in ticks */
static uint16_t clock_last, fs_ms; /* fs_ms 0: disarmed */
static uint8_t fs_action, fs_tripped, fs_chips, feed_at;
static const uint8_t feed_frame[LINK_FAILSAFE_FEED_LEN] = LINK_FAILSAFE_FEED_INIT;

/* fold a reading of the 16-bit timer into the 32-bit clock */
static uint32_t clock_fold(uint16_t t)
{
    clock_now += (uint16_t)(t - clock_last);
    clock_last = t;
    return clock_now;
}

uint32_t link_clock(void) { return clock_fold(bus_ticks()); }

uint16_t link_failsafe_wake(void) { return (uint16_t)(fs_last + fs_ticks); }

/* expired at clock `now` */
static uint8_t failsafe_due(uint32_t now)
{
    return fs_ms && !fs_tripped && now - fs_last >= fs_ticks;
}

/* every time: the clock keeps counting, armed or not */
static uint8_t failsafe_expired(void) { return failsafe_due(link_clock()); }

/* stop every chip select that answers (a status of FF is a bus no chip drives), latch the
 * trip, select `chip` again (a program under way goes on with it); a shaped move's pending
 * pieces are dropped first: none may restart a motor the trip stopped */
static __attribute__((noinline)) void failsafe_trip(uint8_t chip)
{
    if (prof_link && prof_link->prof_n) {
        prof_link->prof_n = 0;
        prof_link->prof_result = RESULT_PROFILE_CANCELLED;
    }
    uint16_t word = fs_action == FAILSAFE_ACTION_SMOOTH ? FAILSAFE_STOP_SMOOTH
        : fs_action == FAILSAFE_ACTION_OFF ? FAILSAFE_STOP_OFF : FAILSAFE_STOP_ABRUPT;
    uint8_t chips = 0, st;
    for (uint8_t k = 0; k < LINK_CHIP_SELECTS; k++) {
        bus_select(k);
        if (bus_read_status() == 0xFF)
            continue;
        if (!bus_wait_not_busy(LINK_DEFAULT_BUSY_TIMEOUT_US, &st))
            continue;
        bus_write_command(CMD_LTRJ);
        if (!bus_wait_not_busy(LINK_DEFAULT_BUSY_TIMEOUT_US, &st))
            continue;
        bus_write_data((uint8_t)(word >> 8));
        bus_write_data((uint8_t)word);
        if (!bus_wait_not_busy(LINK_DEFAULT_BUSY_TIMEOUT_US, &st))
            continue;
        bus_write_command(CMD_STT);
        chips |= (uint8_t)(1u << k);
    }
    bus_select(chip);
    fs_tripped = 1;
    fs_chips = chips;
    fs_silent = clock_now - fs_last;
    fs_at = clock_now;
}

void link_poll(void)
{
    if (failsafe_expired())
        failsafe_trip(0);
}

/* During a recording: take FAILSAFE_FEED as it comes (each whole one feeds the failsafe);
 * returns 0 at the first byte that is not the feed's next one (it stays in the buffer and ends
 * the recording; a feed's start matched before it is dropped). */
static uint8_t take_feed(void)
{
    while (link_rx_pending()) {
        if (link_rx_peek() != feed_frame[feed_at]) {
            feed_at = 0;
            return 0;
        }
        link_rx_skip();
        if (++feed_at == LINK_FAILSAFE_FEED_LEN) {
            feed_at = 0;
            fs_last = link_clock();
        }
    }
    return 1;
}

/* FAILSAFE_REPLY's payload after the result: timeout, action, the latched trip */
static uint16_t failsafe_reply(uint8_t *r, uint8_t result)
{
    uint32_t silent = fs_tripped ? fs_silent / TICKS_PER_MS : 0;
    uint32_t at = fs_tripped ? fs_at / TICKS_PER_MS : 0;
    r[0] = FRAME_FAILSAFE_REPLY;
    r[2] = result;
    r[3] = (uint8_t)(fs_ms >> 8);
    r[4] = (uint8_t)fs_ms;
    r[5] = fs_action;
    r[6] = fs_tripped;
    r[7] = fs_tripped ? fs_chips : 0;
    for (uint8_t k = 0; k < 4; k++) {
        r[8 + k] = (uint8_t)(silent >> (24 - 8 * k));
        r[12 + k] = (uint8_t)(at >> (24 - 8 * k));
    }
    return 16;
}

static uint16_t failsafe_request(uint8_t *r, const uint8_t *payload, uint16_t plen)
{
    uint8_t result = RESULT_OK;
    if (plen) {
        uint8_t cmd = payload[0];
        uint16_t ms = plen == 4 ? (uint16_t)((payload[1] << 8) | payload[2]) : 0;
        if (cmd == FAILSAFE_CMD_ARM && plen == 4 && ms >= LINK_FAILSAFE_MIN_MS
            && ms <= LINK_FAILSAFE_MAX_MS && payload[3] <= FAILSAFE_ACTION_OFF) {
            fs_ms = ms;
            fs_ticks = (uint32_t)ms * TICKS_PER_MS;
            fs_action = payload[3];
        } else if (cmd == FAILSAFE_CMD_DISARM && plen == 1) {
            fs_ms = 0;
        } else if (cmd == FAILSAFE_CMD_ACKNOWLEDGE && plen == 1) {
            fs_tripped = 0;
        } else {
            result = RESULT_BAD_FAILSAFE;
        }
    }
    return failsafe_reply(r, result);
}

/* ---------------------------------------------------------------- programs */
static const uint8_t op_args[] = OP_ARG_BYTES_INIT;

/* The result of checking a program before it runs. */
typedef struct {
    uint8_t result, index; /* RESULT_OK, or why it is refused (and at which operation) */
    uint8_t reads, n_status;
} check_t;

/* Check a whole program before touching the bus: a bad program runs nothing.  Every count
 * fits a byte (a program is at most LINK_MAX_PROGRAM = 243 bytes), and the AVR's 8-bit loops
 * are much shorter.  An op code past OP_MAX, or one without arguments table entry (0xFF), is
 * refused by the same compare as a truncated argument: `end - p` is at most 243. */
static inline __attribute__((always_inline)) check_t check_program(const uint8_t *prog, uint8_t left)
{
    check_t c = {RESULT_OK, LINK_NONE_BYTE, 0, 0};
    uint8_t nops = 0;
    for (const uint8_t *p = prog; left; nops++) {
        uint8_t op = *p;
        uint8_t a = op <= OP_MAX ? op_args[op] : 0xFF;
        if (a >= left) {
            c.result = RESULT_BAD_PROGRAM;
            c.index = nops;
            return c;
        }
        if (op == OP_READ) {
            c.reads++;
        } else if (op == OP_STATUS || op == OP_SYNC || op == OP_WAIT_STATUS) {
            c.n_status++;
        } else if (op == OP_SELECT && p[1] >= LINK_CHIP_SELECTS) {
            c.result = RESULT_BAD_CHIP_SELECT;
            c.index = nops;
            return c;
        }
        a++;
        p += a;
        left -= a;
    }
    if (c.reads > LINK_MAX_READS || LINK_RUN_REPLY_OVERHEAD + c.n_status + 2u * c.reads > LINK_MAX_FRAME)
        c.result = RESULT_PROGRAM_TOO_LONG;
    return c;
}

/* A checked program with STT while a failsafe trip is latched: refused (nothing runs) until a
 * host acknowledges the trip. */
static check_t refuse_motion(check_t c, const uint8_t *prog, uint8_t left)
{
    if (!fs_tripped || c.result != RESULT_OK)
        return c;
    uint8_t i = 0;
    for (const uint8_t *p = prog, *end = prog + left; p != end; i++) {
        if (*p == OP_COMMAND && p[1] == CMD_STT) {
            c.result = RESULT_FAILSAFE_TRIPPED;
            c.index = i;
            return c;
        }
        p += 1u + op_args[*p];
    }
    return c;
}

/* How a program ended: result, failing operation (LINK_NONE_BYTE when OK), last status byte
 * seen (LINK_NONE_BYTE before any), statuses and words reported. */
typedef struct {
    uint8_t result, index, last, ns, nw, hi;
} ran_t;

/* Run a checked program.  `order`: the bytes it reads go to `st` in program order (the
 * compact RUN_SHORT_REPLY), each summed into *crc as soon as it is read, while the chip is
 * busy anyway; otherwise status bytes go to `st` and word bytes to `wd` (RUN_REPLY). */
static inline __attribute__((always_inline)) ran_t exec_program(const uint8_t *prog,
    const uint8_t *end, uint8_t cs, uint16_t timeout_us, uint8_t *st, uint8_t *wd,
    const uint8_t order, uint16_t *crc)
{
    uint8_t chip = cs; /* the chip selected now: chip 0 between programs */
    if (chip)
        bus_select(chip);
    ran_t r = {RESULT_OK, LINK_NONE_BYTE, LINK_NONE_BYTE, 0, 0, 0};
    uint8_t last = LINK_NONE_BYTE, nops = 0;
    /* order: *crc holds the reply's seq; the CRC of type and seq is made after the first
     * transfer, while the chip is busy with it, or before the first byte read */
    uint16_t c = order ? *crc : 0;
    uint8_t head = order;
#define HEAD_CRC() do { if (order && head) { \
        c = crc_step(crc_step(LINK_CRC_INIT, FRAME_RUN_SHORT_REPLY), (uint8_t)c); head = 0; } } while (0)
    for (const uint8_t *p = prog; p != end; nops++) {
        uint8_t op = *p++;
        if (op == OP_COMMAND || op == OP_WRITE || op == OP_READ || op == OP_SYNC) {
            if (!bus_wait_not_busy(timeout_us, &last)) {
                r.result = RESULT_BUSY_TIMEOUT;
                r.index = nops;
                break;
            }
            if (op == OP_COMMAND) {
                bus_write_command(*p++);
                HEAD_CRC();
            } else if (op == OP_WRITE) {
                bus_write_data(p[0]);
                bus_write_data(p[1]);
                p += 2;
                HEAD_CRC();
            } else if (op == OP_READ) {
                uint8_t h = bus_read_data();
                uint8_t l = bus_read_data();
                HEAD_CRC();
                if (order) {
                    st[0] = h;
                    st[1] = l;
                    st += 2;
                    c = crc_step(crc_step(c, h), l);
                } else {
                    wd[0] = h;
                    wd[1] = l;
                    wd += 2;
                }
                r.nw += 2;
            } else {
                *st++ = last;
                HEAD_CRC();
                if (order)
                    c = crc_step(c, last);
                r.ns++;
            }
        } else if (op == OP_STATUS) {
            last = bus_read_status();
            *st++ = last;
            HEAD_CRC();
            if (order)
                c = crc_step(c, last);
            r.ns++;
        } else if (op == OP_RESET) {
            bus_reset_pulse();
        } else if (op == OP_SELECT) {
            chip = *p++;
            bus_select(chip);
        } else if (op == OP_WAIT_STATUS) {
            /* a status read every WAIT_STATUS_POLL_US until a bit of the mask is set or `ms`
             * milliseconds have passed (each period is a little longer than its nominal time,
             * so the wait never ends early); the host judges which from the status.  A byte
             * from the host ends it too: a host waits for the reply before it sends the next
             * request, so a byte now is one that gave up (a new client's HELLO), and a wait
             * of up to 65 s for a bit that never comes (mask 0) must not leave it unanswered */
            uint8_t mask = p[0];
            uint16_t ms = (uint16_t)((p[1] << 8) | p[2]);
            p += 3;
            uint32_t polls = (uint32_t)ms * (1000u / WAIT_STATUS_POLL_US);
            for (;;) {
                last = bus_read_status();
                if ((last & mask) || !polls-- || link_rx_pending())
                    break;
                if (failsafe_expired()) { /* a wait is the host alive only up to the timeout */
                    failsafe_trip(chip);
                    break;
                }
                bus_wait_us(WAIT_STATUS_POLL_US);
                profile_poll(chip); /* a piece due meanwhile goes out at its time */
            }
            *st++ = last;
            HEAD_CRC();
            if (order)
                c = crc_step(c, last);
            r.ns++;
        } else { /* OP_WAIT, in steps of at most 1 ms: a piece due meanwhile goes out */
            uint16_t us = (uint16_t)((p[0] << 8) | p[1]);
            p += 2;
            while (us > 1000u && prof_link && prof_link->prof_n) { /* one go without a schedule */
                bus_wait_us(1000u);
                us -= 1000u;
                profile_poll(chip);
            }
            bus_wait_us(us);
        }
    }
    HEAD_CRC();
#undef HEAD_CRC
    r.last = last;
    r.hi = bus_hi(); /* the HI line of the chip selected last */
    if (chip)
        bus_select(0); /* every /CS released between programs */
    if (order)
        *crc = c;
    return r;
}

static uint16_t run_header(uint8_t *reply, uint8_t result, uint8_t index, uint8_t last, uint8_t hi)
{
    reply[0] = result;
    reply[1] = index;
    reply[2] = last;
    reply[3] = hi;
    reply[4] = 0;
    return 5;
}

/* RUN_REPLY's payload for a program that ran (all of it, or up to a busy timeout): header,
 * the statuses at reply + 5, the words after them (already there). */
static uint16_t run_reply(uint8_t *reply, ran_t r)
{
    reply[0] = r.result;
    reply[1] = r.index;
    reply[2] = r.last;
    reply[3] = r.hi;
    reply[4] = r.ns;
    return (uint16_t)(5u + r.ns + r.nw);
}

/* Run a checked program for RUN_REPLY: statuses right after the header, words after all the
 * statuses; on a failure the unused status slots close up, so the words follow the statuses
 * read. */
static uint16_t run_long(const uint8_t *prog, const uint8_t *end, uint8_t cs,
                         uint16_t timeout_us, check_t c, uint8_t *reply)
{
    uint8_t *st = reply + 5, *wd = reply + 5 + c.n_status;
    ran_t r = exec_program(prog, end, cs, timeout_us, st, wd, 0, 0);
    if (r.ns != c.n_status)
        for (uint8_t k = 0; k < r.nw; k++)
            st[r.ns + k] = wd[k];
    return run_reply(reply, r);
}

uint16_t link_run(const uint8_t *payload, uint16_t len, uint8_t *reply)
{
    uint8_t cs = payload[0];
    uint16_t timeout_us = (uint16_t)((payload[1] << 8) | payload[2]);
    const uint8_t *prog = payload + 3;
    uint16_t plen = len - 3;
    if (!timeout_us)
        timeout_us = LINK_DEFAULT_BUSY_TIMEOUT_US;
    if (cs >= LINK_CHIP_SELECTS)
        return run_header(reply, RESULT_BAD_CHIP_SELECT, LINK_NONE_BYTE, LINK_NONE_BYTE, 0);
    if (plen > LINK_MAX_PROGRAM)
        return run_header(reply, RESULT_PROGRAM_TOO_LONG, LINK_NONE_BYTE, LINK_NONE_BYTE, 0);
    check_t c = refuse_motion(check_program(prog, (uint8_t)plen), prog, (uint8_t)plen);
    if (c.result != RESULT_OK)
        return run_header(reply, c.result, c.index, LINK_NONE_BYTE, 0);
    return run_long(prog, prog + plen, cs, timeout_us, c, reply);
}

/* A compact RUN that timed out part-way is answered as a RUN_REPLY: the bytes read, in
 * program order at frame + 2, regrouped (statuses first, then words: walk the operations
 * that ran).  Apart from run_short, so that its large buffer stays off the fast path. */
static __attribute__((noinline)) uint16_t regroup(const uint8_t *prog, uint8_t *frame, ran_t r)
{
    frame[0] = FRAME_RUN_REPLY;
    uint8_t *st = frame + 7, *out = frame + 2, tmp[LINK_MAX_FRAME];
    uint8_t n = (uint8_t)(r.ns + r.nw), ns = 0, nw = 0;
    for (uint8_t k = 0; k < n; k++)
        tmp[k] = out[k];
    const uint8_t *p = prog, *src = tmp;
    for (uint8_t i = 0; i < r.index; i++) {
        uint8_t op = *p;
        p += 1u + op_args[op];
        if (op == OP_READ) {
            st[r.ns + nw] = src[0];
            st[r.ns + nw + 1] = src[1];
            nw += 2;
            src += 2;
        } else if (op == OP_STATUS || op == OP_SYNC || op == OP_WAIT_STATUS) {
            st[ns++] = *src++;
        }
    }
    return 2u + run_reply(frame + 2, r);
}

/* RUN_SHORT: the program alone (chip select 0, the default busy timeout).  `frame` is the
 * decoded reply frame being built: type and seq are in frame[0..1].  When the program runs to
 * its end the answer is RUN_SHORT_REPLY: the bytes read in program order, then one byte, the
 * last status seen with its busy bit (0 after a passed busy check) replaced by HI, then the
 * CRC, made as the bytes were read (so the reply starts as soon as the last strobe is over).
 * Otherwise it is a RUN_REPLY, as for RUN.  Returns the decoded size; *crc_done tells whether
 * the CRC is already stored after it. */
static inline __attribute__((always_inline)) uint16_t run_short(check_t c, const uint8_t *prog,
                                                                 uint16_t plen, uint8_t *frame,
                                                                 uint8_t *crc_done)
{
    *crc_done = 0;
    const uint8_t *end = prog + plen;
    if (c.result != RESULT_OK) {
        frame[0] = FRAME_RUN_REPLY;
        return 2u + run_header(frame + 2, c.result, c.index, LINK_NONE_BYTE, 0);
    }
    frame[0] = FRAME_RUN_SHORT_REPLY;
    uint16_t crc = frame[1];
    uint8_t *out = frame + 2;
    ran_t r = exec_program(prog, end, 0, LINK_DEFAULT_BUSY_TIMEOUT_US, out, 0, 1, &crc);
    uint8_t n = (uint8_t)(r.ns + r.nw);
    if (r.result == RESULT_OK) {
        uint8_t hdr = (uint8_t)((r.last & (uint8_t)~STATUS_BUSY) | r.hi);
        out[n] = hdr;
        crc = crc_step(crc, hdr) ^ LINK_CRC_XOROUT;
        out[n + 1] = (uint8_t)(crc >> 8);
        out[n + 2] = (uint8_t)crc;
        *crc_done = 1;
        return (uint16_t)(3u + n);
    }
    return regroup(prog, frame, r);
}

/* The check put() made of a compact request's program while its bytes came in: as
 * check_program's. */
static check_t arrived_check(const link_t *l, uint16_t plen)
{
    check_t c = {RESULT_OK, LINK_NONE_BYTE, l->chk_reads, l->chk_status};
    if (plen > LINK_MAX_PROGRAM) {
        c.result = RESULT_PROGRAM_TOO_LONG;
    } else if (l->chk_bad || l->chk_args) {
        /* chk_bad: 1 + the index of the first bad op code or SELECT of a chip the bridge
         * lacks (then chk_select's bit 7) */
        c.result = l->chk_select & 0x80 ? RESULT_BAD_CHIP_SELECT : RESULT_BAD_PROGRAM;
        c.index = l->chk_bad ? (uint8_t)(l->chk_bad - 1) : (uint8_t)(l->chk_ops - 1);
    } else if (c.reads > LINK_MAX_READS
               || LINK_RUN_REPLY_OVERHEAD + c.n_status + 2u * c.reads > LINK_MAX_FRAME) {
        c.result = RESULT_PROGRAM_TOO_LONG;
    }
    return c;
}

/* ---------------------------------------------------------------- frames */
/* One reply byte: kept in the encoded frame (the cache of a RUN) and handed to the transmitter
 * at once, so the reply's first bytes are on the wire while the rest is still being made. */
static inline __attribute__((always_inline)) uint8_t *emit(uint8_t *o, uint8_t b)
{
    *o = b;
    link_tx_byte(b);
    return o + 1;
}

/* Up to `max` more bytes of a reply's CRC, from `at`; at `end` the CRC is stored there (the
 * reply has room for it).  Returns the new `at`.  Not inlined: its loop keeps the CRC in
 * registers (about 26 cycles a byte). */
static __attribute__((noinline)) uint8_t *crc_some(uint8_t *at, uint8_t *end, uint16_t *crc_p,
                                                   uint8_t max)
{
    uint16_t crc = *crc_p;
    while (max-- && at != end)
        crc = crc_step(crc, *at++);
    *crc_p = crc;
    if (at == end) {
        crc ^= LINK_CRC_XOROUT;
        end[0] = (uint8_t)(crc >> 8);
        end[1] = (uint8_t)crc;
    }
    return at;
}

/* Send a reply: CRC, COBS and delimiter, each byte sent as soon as it is known, and the encoded
 * frame left in `out`; returns its size.  `reply` has room for the CRC after its `len` bytes
 * (already there when `crc_done`).
 * A COBS code byte needs its block's end, so the scan stops at the first zero: the first
 * block's code byte (type, seq, then a result of 0) goes out before any CRC work; the CRC is
 * then made three bytes after each byte sent, while that byte is on the wire (176 cycles at
 * 1 Mbaud), and a block that runs into the CRC waits for the rest of it. */
static uint16_t finish(uint8_t *reply, uint16_t len, uint8_t *out, uint8_t crc_done)
{
    uint8_t *p = reply, *data_end = reply + len, *end = data_end + 2, *o = out;
    uint8_t *crc_at = crc_done ? data_end : reply; /* == data_end: the CRC is made and stored */
    uint16_t crc = LINK_CRC_INIT;
    for (;;) {
        uint8_t *start = p, *lim = end - p > 254 ? p + 254 : end;
        uint8_t *stop = lim < data_end ? lim : data_end;
        while (p < stop && *p)
            p++;
        if (p == data_end) /* the block runs into the CRC */
            while (crc_at != data_end)
                crc_at = crc_some(crc_at, data_end, &crc, 255);
        while (p < lim && *p)
            p++;
        uint8_t code = (uint8_t)(p - start + 1);
        for (o = emit(o, code);; o = emit(o, *start++)) {
            if (crc_at != data_end)
                crc_at = crc_some(crc_at, data_end, &crc, 3);
            if (start == p)
                break;
        }
        if (code == 0xFF) /* a full block: no zero implied, the next block starts here */
            continue;
        if (p == end)
            break;
        p++; /* the zero this block stands for */
    }
    o = emit(o, 0);
    return (uint16_t)(o - out);
}

/* Send a decoded frame whose CRC is already stored after its `len` bytes: COBS and the
 * delimiter, each byte sent as soon as it is known (the scan for a block's end stops at a 0
 * put after the CRC), and the encoded frame left in `out`; returns its size.  For frames
 * shorter than 254 bytes (a RUN_SHORT_REPLY), whose blocks are never full. */
static uint16_t send_ready(uint8_t *frame, uint8_t len, uint8_t *out)
{
    uint8_t *p = frame, *end = frame + len + 2, *o = out;
    *end = 0;
    for (;;) {
        uint8_t *q = p;
        while (*q)
            q++;
        uint8_t code = (uint8_t)(q - p + 1);
        *o++ = code;
        link_tx_byte(code);
        while (p != q) {
            uint8_t b = *p++;
            *o++ = b;
            link_tx_byte(b);
        }
        if (q == end)
            break;
        p = q + 1;
    }
    *o++ = 0;
    link_tx_byte(0);
    return (uint16_t)(o - out);
}

/* ---------------------------------------------------------------- RECORD */
/* Why the bridge refuses a sample program: check_program's reasons, the RECORD limits, and any
 * operation but a status read, a data-reporting command (RDDV..RDSUM), a READ or a SELECT: a
 * recording never changes the chip, so one started twice (the host's retry) does no harm. */
static check_t record_check(const uint8_t *prog, uint16_t plen)
{
    check_t c = {RESULT_PROGRAM_TOO_LONG, LINK_NONE_BYTE, 0, 0};
    if (plen > LINK_RECORD_MAX_PROGRAM)
        return c;
    c = check_program(prog, (uint8_t)plen);
    if (c.result != RESULT_OK)
        return c;
    uint8_t i = 0;
    for (const uint8_t *p = prog, *end = prog + plen; p != end; i++) {
        uint8_t op = *p;
        if (!(op == OP_STATUS || op == OP_READ || op == OP_SELECT
              || (op == OP_COMMAND && p[1] >= LINK_RECORD_CMD_FIRST && p[1] <= LINK_RECORD_CMD_LAST))) {
            c.result = RESULT_BAD_PROGRAM;
            c.index = i;
            return c;
        }
        p += 1u + op_args[op];
    }
    if (c.n_status + 2u * c.reads > LINK_RECORD_MAX_BYTES)
        c.result = RESULT_PROGRAM_TOO_LONG;
    return c;
}

/* RECORD_END: result, failing operation, rows sent; sent as it is made, left in `out` */
static uint16_t record_end(uint8_t *r, uint8_t seq, uint8_t result, uint8_t index, uint16_t rows,
                           uint8_t *out)
{
    r[0] = FRAME_RECORD_END;
    r[1] = seq;
    r[2] = result;
    r[3] = index;
    r[4] = (uint8_t)(rows >> 8);
    r[5] = (uint8_t)rows;
    return finish(r, 6, out, 0);
}

/* RECORD: period_us (4), rows (2; 0: until stopped), the sample program.  The program runs
 * every period on Timer1 (4 us ticks, the due times an exact multiple of the period from the
 * first row, so the rows never drift), and each run goes out at once as a RECORD_ROW stamped
 * with the tick count when it started (in us from the first row: the bridge's clock).  Any byte
 * from the host ends the recording (it waits in the receive buffer and is read as usual after
 * it); then, or after the last row, or at a busy timeout, a RECORD_END.  The reply cache is
 * emptied: its buffer carries the rows, and a recording is never answered from a cache. */
static uint16_t record(link_t *l, uint8_t seq, const uint8_t *payload, uint16_t plen,
                       const uint8_t **out)
{
    uint8_t *r = l->reply;
    l->cache_len = 0;
    *out = l->cache;
    uint32_t period_us = ((uint32_t)payload[0] << 24) | ((uint32_t)payload[1] << 16)
        | ((uint32_t)payload[2] << 8) | payload[3];
    uint16_t rows = (uint16_t)((payload[4] << 8) | payload[5]);
    const uint8_t *prog = payload + 6;
    uint16_t n = plen - 6;
    check_t c = record_check(prog, n);
    if (c.result != RESULT_OK)
        return record_end(r, seq, c.result, c.index, 0, l->cache);
    if (period_us < LINK_RECORD_MIN_PERIOD_US)
        return record_end(r, seq, RESULT_BAD_RATE, LINK_NONE_BYTE, 0, l->cache);
    feed_at = 0; /* a feed's start left by an earlier recording is not this one's */
    uint32_t period = period_us / LINK_RECORD_TICK_US, now = 0, due = 0, base = 0;
    uint16_t last = bus_ticks(), sent = 0;
    uint8_t result = RESULT_OK, index = LINK_NONE_BYTE;
    for (;;) {
        for (;;) { /* until the row is due; the 16-bit timer is read well within its wrap */
            uint16_t t = bus_ticks();
            now += (uint16_t)(t - last);
            last = t;
            int32_t early = (int32_t)(due - now);
            if (early <= 0)
                break;
            if (early > 64) { /* more than 256 us to go: room for the rest, off the row's edge */
                if (failsafe_due(clock_fold(t))) /* a recording: alive while the host feeds */
                    failsafe_trip(0);
                if (!take_feed())
                    goto stop;
            }
            if (l->prof_n) /* only then: the loop stays within a 4 us tick */
                profile_poll(0);
        }
        if (link_rx_pending() && !take_feed())
            break;
        if (!sent) /* the first row: the clock and the due times count from here */
            due = base = now;
        uint32_t stamp = (now - base) * LINK_RECORD_TICK_US;
        r[0] = FRAME_RECORD_ROW;
        r[1] = seq;
        r[2] = (uint8_t)(sent >> 8);
        r[3] = (uint8_t)sent;
        r[4] = (uint8_t)(stamp >> 24);
        r[5] = (uint8_t)(stamp >> 16);
        r[6] = (uint8_t)(stamp >> 8);
        r[7] = (uint8_t)stamp;
        uint16_t unused = seq;
        ran_t x = exec_program(prog, prog + n, 0, LINK_DEFAULT_BUSY_TIMEOUT_US, r + 8, 0, 1, &unused);
        if (x.result != RESULT_OK) {
            result = x.result;
            index = x.index;
            break;
        }
        finish(r, (uint16_t)(8u + x.ns + x.nw), l->cache, 0);
        if (failsafe_due(link_clock())) /* once a row too: periods shorter than 256 us */
            failsafe_trip(0);
        sent++;
        due += period;
        if (rows && sent == rows)
            break;
    }
stop:
    return record_end(r, seq, result, index, sent, l->cache);
}

/* A program the schedule is dropped for (PROTOCOL.md, PROFILE): one with an LTRJ command (a
 * stop, a new move) or a /RST pulse, so that no later piece restarts what it stopped. */
static uint8_t ends_profile(const uint8_t *prog, uint16_t n)
{
    for (const uint8_t *p = prog, *end = prog + n; p < end;) {
        uint8_t op = *p;
        if (op == OP_RESET || (op == OP_COMMAND && p + 1 < end && p[1] == CMD_LTRJ))
            return 1;
        uint8_t a = op <= OP_MAX ? op_args[op] : 0xFF;
        if (a == 0xFF)
            return 0;
        p += a + 1u;
    }
    return 0;
}

static uint32_t be32(const uint8_t *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}

/* PROFILE: flags, cs, pieces (t_us, velocity); every piece checked before any is kept (a
 * refusal keeps nothing), NEW starts the schedule's clock now.  PROFILE_REPLY: result, pieces
 * issued, pending, the largest lateness in us.  Cached as a RUN's reply: a repeat is answered
 * from the cache and schedules nothing twice. */
static uint16_t profile(link_t *l, const uint8_t *payload, uint16_t plen, uint8_t *r)
{
    profile_poll(0); /* the clock up to date, the pieces due issued */
    uint8_t flags = payload[0], cs = payload[1];
    uint8_t n = (uint8_t)((plen - 2u) / 8u), fresh = flags & LINK_PROFILE_NEW;
    uint8_t result = l->prof_result;
    if (n || fresh) {
        uint8_t held = fresh ? 0 : l->prof_n;
        uint8_t have_last = held != 0;
        /* the last piece kept (ticks from the start): appended pieces count from it */
        uint32_t tail = fresh ? 0 : l->prof_tail, last = tail * LINK_RECORD_TICK_US;
        result = RESULT_OK;
        if (cs >= LINK_CHIP_SELECTS || held + n > LINK_PROFILE_MAX_SCHEDULE)
            result = RESULT_BAD_PROFILE;
        for (uint8_t k = 0; k < n; k++) {
            uint32_t t = be32(payload + 2 + 8u * k), v = be32(payload + 6 + 8u * k);
            if (v > 0x3FFFFFFFUL || (have_last && t < last + LINK_PROFILE_MIN_SPACING_US)
                || t / LINK_RECORD_TICK_US - tail > 0xFFFFu || t / LINK_RECORD_TICK_US < tail)
                result = RESULT_BAD_PROFILE;
            tail = t / LINK_RECORD_TICK_US;
            last = t;
            have_last = 1;
        }
        if (result == RESULT_OK && n && fs_tripped) /* pieces carry STT: refused as a RUN's */
            result = RESULT_FAILSAFE_TRIPPED;
        if (result == RESULT_OK) {
            if (fresh) {
                l->prof_n = l->prof_head = 0;
                l->prof_issued = 0;
                l->prof_late = l->prof_now = l->prof_tail = 0;
                l->prof_last = bus_ticks();
                l->prof_cs = cs;
            }
            l->prof_result = RESULT_OK;
            for (uint8_t k = 0; k < n; k++) {
                uint8_t at = (uint8_t)((l->prof_head + l->prof_n) % LINK_PROFILE_MAX_SCHEDULE);
                uint32_t t = be32(payload + 2 + 8u * k) / LINK_RECORD_TICK_US;
                l->prof_dt[at] = (uint16_t)(t - l->prof_tail);
                if (!l->prof_n)
                    l->prof_due = t; /* the head: due at its own time */
                l->prof_tail = t;
                l->prof_v[at] = be32(payload + 6 + 8u * k);
                l->prof_n++;
            }
        }
    }
    uint32_t late_us = l->prof_late * LINK_RECORD_TICK_US;
    r[0] = FRAME_PROFILE_REPLY;
    r[2] = result;
    r[3] = (uint8_t)(l->prof_issued >> 8);
    r[4] = (uint8_t)l->prof_issued;
    r[5] = 0;
    r[6] = l->prof_n;
    r[7] = (uint8_t)(late_us >> 24);
    r[8] = (uint8_t)(late_us >> 16);
    r[9] = (uint8_t)(late_us >> 8);
    r[10] = (uint8_t)late_us;
    return 11;
}

static uint16_t handle(link_t *l, uint16_t n, const uint8_t **out)
{
    uint8_t *f = l->rx, *r = l->reply;
    uint8_t type = f[0], seq = f[1];
    uint16_t crc = (uint16_t)((f[n - 2] << 8) | f[n - 1]);
    uint16_t plen = n - 4, len = 2;
    const uint8_t *payload = f + 2;
    r[1] = seq;
    if (type == FRAME_HELLO) {
        l->cache_len = 0;
        for (uint8_t k = 0; k < LINK_CODE_SLOTS; k++)
            l->code_len[k] = 0; /* the host forgets its codes with HELLO too */
        r[0] = FRAME_HELLO_REPLY;
        r[len++] = LINK_PROTOCOL_VERSION;
        r[len++] = FIRMWARE_MAJOR;
        r[len++] = FIRMWARE_MINOR;
        r[len++] = FIRMWARE_PATCH;
        r[len++] = (uint8_t)((CAP_RECORD | CAP_FAILSAFE | CAP_PROFILE) >> 8);
        r[len++] = CAP_RESET_LINE | CAP_HI_LINE | CAP_BUSY_ON_BRIDGE | CAP_WAIT_STATUS | CAP_SELECT
            | CAP_COMPACT_RUN | CAP_PROGRAM_CODES | CAP_BAUD_SWITCH;
        r[len++] = (uint8_t)(LINK_MAX_PROGRAM >> 8);
        r[len++] = (uint8_t)LINK_MAX_PROGRAM;
        r[len++] = LINK_MAX_READS;
        r[len++] = LINK_CHIP_SELECTS;
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 24);
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 16);
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 8);
        r[len++] = (uint8_t)LINK_CPU_HZ;
    } else if (type == FRAME_SET_BAUD && plen == 4) {
        /* the U2X divisor for the rate asked (F_CPU / 8 / baud, rounded); refused when the rate
         * made is more than 2 % off.  The switch itself is the firmware's (main.c), once this
         * reply has left at the old rate. */
        uint32_t baud = ((uint32_t)payload[0] << 24) | ((uint32_t)payload[1] << 16)
            | ((uint16_t)payload[2] << 8) | payload[3];
        uint32_t div = baud ? (LINK_CPU_HZ / 8 + baud / 2) / baud : 0;
        uint32_t made = div ? LINK_CPU_HZ / 8 / div : 0;
        uint32_t off = made > baud ? made - baud : baud - made;
        uint8_t ok = div >= 1 && div <= 4096 && off * 50 <= baud;
        r[0] = FRAME_BAUD_REPLY;
        r[len++] = ok ? RESULT_OK : RESULT_BAD_BAUD;
        r[len++] = (uint8_t)(made >> 24);
        r[len++] = (uint8_t)(made >> 16);
        r[len++] = (uint8_t)(made >> 8);
        r[len++] = (uint8_t)made;
        l->baud_div = ok ? (uint16_t)div : 0;
    } else if (type == FRAME_PING && plen <= LINK_MAX_PING) {
        r[0] = FRAME_PONG;
        for (uint16_t k = 0; k < plen; k++)
            r[len++] = payload[k];
    } else if ((type == FRAME_RUN && plen >= 3) || type == FRAME_RUN_SHORT
               || (type == FRAME_RUN_STORE && plen >= 1) || (type == FRAME_RUN_CODE && plen == 1)) {
        if (l->cache_len && l->cache_seq == seq && l->cache_crc == crc) {
            l->cache_hits++;
            for (uint16_t k = 0; k < l->cache_len; k++)
                link_tx_byte(l->cache[k]);
            *out = l->cache;
            return l->cache_len;
        }
        if (l->prof_n) { /* a stop or a new move drops the pieces still pending */
            const uint8_t *prog = type == FRAME_RUN ? payload + 3 : type == FRAME_RUN_SHORT
                ? payload : payload + 1;
            uint16_t size = type == FRAME_RUN ? plen - 3u : type == FRAME_RUN_SHORT ? plen
                : plen - 1u;
            if (type == FRAME_RUN_CODE) {
                uint8_t slot = payload[0];
                size = slot < LINK_CODE_SLOTS && l->code_len[slot] ? l->code_len[slot] - 1u : 0;
                prog = slot < LINK_CODE_SLOTS ? l->codes[slot] : payload;
            }
            if (ends_profile(prog, size)) {
                l->prof_n = 0;
                l->prof_result = RESULT_PROFILE_CANCELLED;
            }
        }
        l->runs++;
        uint8_t crc_done = 0;
        if (type == FRAME_RUN) {
            r[0] = FRAME_RUN_REPLY;
            len += link_run(payload, plen, r + 2);
        } else if (type == FRAME_RUN_SHORT) {
            len = run_short(refuse_motion(arrived_check(l, plen), payload, (uint8_t)plen),
                            payload, plen, r, &crc_done);
        } else {
            /* RUN_STORE keeps a good program under its code, then runs it as RUN_SHORT;
             * RUN_CODE runs the program kept (checked when it was stored) */
            uint8_t slot = payload[0];
            check_t c = {RESULT_UNKNOWN_CODE, LINK_NONE_BYTE, 0, 0};
            const uint8_t *prog = payload + 1;
            uint8_t n = 0;
            if (slot < LINK_CODE_SLOTS) {
                if (type == FRAME_RUN_STORE) {
                    c = plen - 1 > LINK_CODE_BYTES ? (check_t){RESULT_PROGRAM_TOO_LONG,
                        LINK_NONE_BYTE, 0, 0} : arrived_check(l, plen - 1);
                    n = (uint8_t)(plen - 1);
                    l->code_len[slot] = 0;
                    if (c.result == RESULT_OK) {
                        for (uint8_t k = 0; k < n; k++)
                            l->codes[slot][k] = prog[k];
                        l->code_len[slot] = (uint8_t)(n + 1); /* 1 + size: 0 is "none" */
                        l->code_reads[slot] = c.reads;
                        l->code_status[slot] = c.n_status;
                    }
                } else if (l->code_len[slot]) {
                    n = (uint8_t)(l->code_len[slot] - 1);
                    prog = l->codes[slot];
                    c = (check_t){RESULT_OK, LINK_NONE_BYTE, l->code_reads[slot],
                                  l->code_status[slot]};
                }
            }
            len = run_short(refuse_motion(c, prog, n), prog, n, r, &crc_done);
        }
        l->cache_len = crc_done ? send_ready(r, (uint8_t)len, l->cache)
                                : finish(r, len, l->cache, crc_done);
        l->cache_seq = seq;
        l->cache_crc = crc;
        *out = l->cache;
        return l->cache_len;
    } else if (type == FRAME_RECORD && plen >= 6) {
        return record(l, seq, payload, plen, out);
    } else if (type == FRAME_FAILSAFE) {
        len = failsafe_request(r, payload, plen);
    } else if (type == FRAME_PROFILE && plen >= 2 && (plen - 2u) % 8u == 0) {
        if (l->cache_len && l->cache_seq == seq && l->cache_crc == crc) {
            l->cache_hits++;
            for (uint16_t k = 0; k < l->cache_len; k++)
                link_tx_byte(l->cache[k]);
            *out = l->cache;
            return l->cache_len;
        }
        l->cache_len = finish(r, profile(l, payload, plen, r), l->cache, 0);
        l->cache_seq = seq;
        l->cache_crc = crc;
        *out = l->cache;
        return l->cache_len;
    } else if (type & 0x80) {
        return 0; /* a reply type: not a request, no answer */
    } else {
        r[0] = FRAME_ERROR_REPLY;
        r[len++] = RESULT_BAD_REQUEST;
    }
    /* the request has been used up: its buffer takes the encoded reply */
    *out = l->rx;
    return finish(r, len, l->rx, 0);
}

static inline __attribute__((always_inline)) void put(link_t *l, uint8_t b)
{
    uint16_t n = l->rx_len;
    if (n >= LINK_MAX_FRAME) {
        l->rx_bad = 1;
        return;
    }
    if (n >= 2) { /* the last two bytes are the CRC itself: sum two bytes behind */
        uint8_t c = l->rx[n - 2];
        l->crc = crc_step(l->crc, c);
        uint8_t t = l->rx[0];
        if ((t == FRAME_RUN_SHORT && n >= 4) || (t == FRAME_RUN_STORE && n >= 5)) {
            /* c is a program byte: check it now */
            if (l->chk_args) {
                l->chk_args--;
                if ((l->chk_select & 1) && c >= LINK_CHIP_SELECTS && !l->chk_bad) {
                    l->chk_bad = l->chk_ops; /* 1 + the SELECT's index: a chip it lacks */
                    l->chk_select |= 0x80;
                }
            } else {
                l->chk_select = (uint8_t)((l->chk_select & 0x80) | (c == OP_SELECT));
                uint8_t a = c <= OP_MAX ? op_args[c] : 0xFF;
                if (a == 0xFF) {
                    if (!l->chk_bad)
                        l->chk_bad = (uint8_t)(l->chk_ops + 1);
                } else {
                    l->chk_args = a;
                    if (c == OP_READ)
                        l->chk_reads++;
                    else if (c == OP_STATUS || c == OP_SYNC || c == OP_WAIT_STATUS)
                        l->chk_status++;
                }
                l->chk_ops++;
            }
        }
    }
    l->rx[n] = b;
    l->rx_len = (uint16_t)(n + 1);
}

void link_byte(link_t *l, uint8_t byte)
{
    if (l->rx_bad)
        return;
    if (l->code_left) {
        l->code_left--;
        put(l, byte);
        return;
    }
    /* a code byte: the block before it ends in an implied zero unless it was a full block */
    if (l->started && l->code != 0xFF)
        put(l, 0);
    l->started = 1;
    l->code = byte;
    l->code_left = (uint8_t)(byte - 1);
}

uint16_t link_frame_end(link_t *l, const uint8_t **out)
{
    uint16_t n = l->rx_len;
    uint16_t crc = l->crc ^ LINK_CRC_XOROUT;
    uint8_t ok = l->started && !l->rx_bad && !l->code_left && n >= 4
        && (uint8_t)(crc >> 8) == l->rx[n - 2] && (uint8_t)crc == l->rx[n - 1];
    uint8_t empty = !l->started;
    if (empty || !ok) {
        rx_restart(l);
        if (!empty)
            l->bad_frames++; /* never answered: the host's retry covers it */
        return 0; /* back-to-back delimiters: nothing to count */
    }
    l->frames++;
    fs_last = link_clock(); /* every good frame feeds the failsafe */
    uint16_t size = handle(l, n, out); /* uses the checks made while the frame came in */
    rx_restart(l);
    return size;
}
