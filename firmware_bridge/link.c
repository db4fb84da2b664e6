/* Link protocol (PROTOCOL.md), shared by the firmware and the host-side tests. */
#include "link.h"
#include "bus.h"

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
}

void link_init(link_t *l)
{
    rx_restart(l);
    l->cache_len = 0;
    l->frames = l->bad_frames = l->runs = l->cache_hits = 0;
}

/* ---------------------------------------------------------------- programs */
static const uint8_t op_args[] = OP_ARG_BYTES_INIT;

static uint16_t run_header(uint8_t *reply, uint8_t result, uint8_t index, uint8_t last, uint8_t hi)
{
    reply[0] = result;
    reply[1] = index;
    reply[2] = last;
    reply[3] = hi;
    reply[4] = 0;
    return 5;
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

    /* check the whole program before touching the bus: a bad program runs nothing.  From here
     * on every count fits a byte (the program is at most LINK_MAX_PROGRAM = 243 bytes), and
     * the AVR's 8-bit loops are much shorter. */
    const uint8_t *end = prog + plen;
    uint8_t reads = 0, n_status = 0, nops = 0;
    for (const uint8_t *p = prog; p != end; nops++) {
        uint8_t op = *p;
        if (op > OP_MAX || op_args[op] == 0xFF || op_args[op] >= (uint8_t)(end - p))
            return run_header(reply, RESULT_BAD_PROGRAM, nops, LINK_NONE_BYTE, 0);
        if (op == OP_READ)
            reads++;
        else if (op == OP_STATUS || op == OP_SYNC || op == OP_WAIT_STATUS)
            n_status++;
        else if (op == OP_SELECT && p[1] >= LINK_CHIP_SELECTS)
            return run_header(reply, RESULT_BAD_CHIP_SELECT, nops, LINK_NONE_BYTE, 0);
        p += 1u + op_args[op];
    }
    if (reads > LINK_MAX_READS || LINK_RUN_REPLY_OVERHEAD + n_status + 2u * reads > LINK_MAX_FRAME)
        return run_header(reply, RESULT_PROGRAM_TOO_LONG, LINK_NONE_BYTE, LINK_NONE_BYTE, 0);

    /* statuses go right after the header, words after all the statuses */
    uint8_t *st = reply + 5;
    uint8_t *wd = reply + 5 + n_status;
    uint8_t ns = 0, last = LINK_NONE_BYTE, result = RESULT_OK, index = LINK_NONE_BYTE;
    uint8_t nw = 0;
    nops = 0;
    uint8_t chip = cs; /* the chip selected now: chip 0 between programs */
    if (chip)
        bus_select(chip);
    for (const uint8_t *p = prog; p != end; nops++) {
        uint8_t op = *p++;
        uint16_t arg = 0;
        uint8_t mask = 0;
        if (op_args[op] == 1) {
            arg = *p++;
        } else if (op_args[op] >= 2) {
            if (op_args[op] == 3) /* OP_WAIT_STATUS: the mask, then the timeout */
                mask = *p++;
            arg = (uint16_t)((p[0] << 8) | p[1]);
            p += 2;
        }
        if (op == OP_COMMAND || op == OP_WRITE || op == OP_READ || op == OP_SYNC) {
            if (!bus_wait_not_busy(timeout_us, &last)) {
                result = RESULT_BUSY_TIMEOUT;
                index = nops;
                break;
            }
            if (op == OP_COMMAND) {
                bus_write_command((uint8_t)arg);
            } else if (op == OP_WRITE) {
                bus_write_data((uint8_t)(arg >> 8));
                bus_write_data((uint8_t)arg);
            } else if (op == OP_READ) {
                wd[nw++] = bus_read_data();
                wd[nw++] = bus_read_data();
            } else {
                st[ns++] = last;
            }
        } else if (op == OP_STATUS) {
            last = bus_read_status();
            st[ns++] = last;
        } else if (op == OP_RESET) {
            bus_reset_pulse();
        } else if (op == OP_SELECT) {
            chip = (uint8_t)arg;
            bus_select(chip);
        } else if (op == OP_WAIT_STATUS) {
            /* a status read every WAIT_STATUS_POLL_US until a bit of the mask is set or `arg`
             * ms have passed (each period is a little longer than its nominal time, so the
             * wait never ends early); the host judges which from the status */
            uint32_t polls = (uint32_t)arg * (1000u / WAIT_STATUS_POLL_US);
            for (;;) {
                last = bus_read_status();
                if ((last & mask) || !polls--)
                    break;
                bus_wait_us(WAIT_STATUS_POLL_US);
            }
            st[ns++] = last;
        } else { /* OP_WAIT */
            bus_wait_us(arg);
        }
    }
    reply[0] = result;
    reply[1] = index;
    reply[2] = last;
    reply[3] = bus_hi();
    if (chip)
        bus_select(0); /* every /CS released between programs */
    reply[4] = ns;
    /* on a failure the unused status slots close up, so the words follow the statuses read */
    if (ns != n_status)
        for (uint8_t k = 0; k < nw; k++)
            st[ns + k] = wd[k];
    return (uint16_t)(5u + ns + nw);
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
 * frame left in `out`; returns its size.  `reply` has room for the CRC after its `len` bytes.
 * A COBS code byte needs its block's end, so the scan stops at the first zero: the first
 * block's code byte (type, seq, then a result of 0) goes out before any CRC work; the CRC is
 * then made three bytes after each byte sent, while that byte is on the wire (176 cycles at
 * 1 Mbaud), and a block that runs into the CRC waits for the rest of it. */
static uint16_t finish(uint8_t *reply, uint16_t len, uint8_t *out)
{
    uint8_t *p = reply, *data_end = reply + len, *end = data_end + 2, *o = out;
    uint8_t *crc_at = reply; /* == data_end: the CRC is made and stored */
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
        r[0] = FRAME_HELLO_REPLY;
        r[len++] = LINK_PROTOCOL_VERSION;
        r[len++] = FIRMWARE_MAJOR;
        r[len++] = FIRMWARE_MINOR;
        r[len++] = FIRMWARE_PATCH;
        r[len++] = 0;
        r[len++] = CAP_RESET_LINE | CAP_HI_LINE | CAP_BUSY_ON_BRIDGE | CAP_WAIT_STATUS | CAP_SELECT;
        r[len++] = (uint8_t)(LINK_MAX_PROGRAM >> 8);
        r[len++] = (uint8_t)LINK_MAX_PROGRAM;
        r[len++] = LINK_MAX_READS;
        r[len++] = LINK_CHIP_SELECTS;
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 24);
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 16);
        r[len++] = (uint8_t)(LINK_CPU_HZ >> 8);
        r[len++] = (uint8_t)LINK_CPU_HZ;
    } else if (type == FRAME_PING && plen <= LINK_MAX_PING) {
        r[0] = FRAME_PONG;
        for (uint16_t k = 0; k < plen; k++)
            r[len++] = payload[k];
    } else if (type == FRAME_RUN && plen >= 3) {
        if (l->cache_len && l->cache_seq == seq && l->cache_crc == crc) {
            l->cache_hits++;
            for (uint16_t k = 0; k < l->cache_len; k++)
                link_tx_byte(l->cache[k]);
            *out = l->cache;
            return l->cache_len;
        }
        l->runs++;
        r[0] = FRAME_RUN_REPLY;
        len += link_run(payload, plen, r + 2);
        l->cache_len = finish(r, len, l->cache);
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
    return finish(r, len, l->rx);
}

static inline __attribute__((always_inline)) void put(link_t *l, uint8_t b)
{
    uint16_t n = l->rx_len;
    if (n >= LINK_MAX_FRAME) {
        l->rx_bad = 1;
        return;
    }
    if (n >= 2) /* the last two bytes are the CRC itself: sum two bytes behind */
        l->crc = crc_step(l->crc, l->rx[n - 2]);
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
    rx_restart(l);
    if (empty)
        return 0; /* back-to-back delimiters: nothing to count */
    if (!ok) {
        l->bad_frames++;
        return 0; /* never answered: the host's retry covers it */
    }
    l->frames++;
    return handle(l, n, out);
}
