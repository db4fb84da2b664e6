/* Host-side unit tests of link.c against the golden frame vectors shared with the Python
 * codec (golden_frames.txt) and a scripted fake chip (fake_bus.c).  Prints one line per check
 * group; exits 1 on the first failure. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "../link.h"
#include "fake_bus.h"

#define MAXV 32
typedef struct { char name[64]; uint8_t dec[300], enc[320]; int ndec, nenc; } vec_t;
static vec_t V[MAXV];
static int nv, checks;
static link_t L;

#define CHECK(c, ...) do { checks++; if (!(c)) { printf("FAIL %s:%d: ", __FILE__, __LINE__); \
    printf(__VA_ARGS__); printf("\n"); exit(1); } } while (0)

static int unhex(const char *s, uint8_t *out)
{
    int n = 0;
    while (s[0] && s[1] && s[0] != '\t' && s[0] != '\n') {
        unsigned v;
        sscanf(s, "%2x", &v);
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static void load(const char *path)
{
    FILE *f = fopen(path, "r");
    CHECK(f, "cannot open %s", path);
    char line[2048];
    while (fgets(line, sizeof line, f)) {
        if (line[0] == '#' || line[0] == '\n')
            continue;
        char *t1 = strchr(line, '\t'), *t2 = t1 ? strchr(t1 + 1, '\t') : NULL;
        CHECK(t1 && t2 && nv < MAXV, "bad golden line: %s", line);
        vec_t *v = &V[nv++];
        snprintf(v->name, sizeof v->name, "%.*s", (int)(t1 - line), line);
        v->ndec = unhex(t1 + 1, v->dec);
        v->nenc = unhex(t2 + 1, v->enc);
    }
    fclose(f);
}

static vec_t *get(const char *name)
{
    for (int i = 0; i < nv; i++)
        if (!strcmp(V[i].name, name))
            return &V[i];
    CHECK(0, "golden vector %s missing", name);
    return NULL;
}

/* feed bytes; returns the reply (copied to out) length, 0 for none; at most one reply */
static int feed(const uint8_t *p, int n, uint8_t *out)
{
    int got = 0;
    for (int i = 0; i < n; i++) {
        const uint8_t *r;
        uint16_t k = link_feed(&L, p[i], &r);
        if (k) {
            CHECK(!got, "two replies to one frame");
            CHECK(fake_tx_verify(r, k), "the bytes sent through link_tx_byte are not the reply returned");
            memcpy(out, r, k);
            got = k;
        }
    }
    return got;
}

static int frame(uint8_t type, uint8_t seq, const uint8_t *payload, int n, uint8_t *wire)
{
    uint8_t d[300];
    d[0] = type;
    d[1] = seq;
    memcpy(d + 2, payload, (size_t)n);
    uint16_t crc = link_crc16(d, (uint16_t)(n + 2));
    d[n + 2] = (uint8_t)(crc >> 8);
    d[n + 3] = (uint8_t)crc;
    int k = link_cobs_encode(d, (uint16_t)(n + 4), wire);
    wire[k++] = 0;
    return k;
}

/* decode a reply frame to its payload; checks COBS, CRC, type and seq */
static int reply_payload(uint8_t *wire, int n, uint8_t type, uint8_t seq, uint8_t **payload)
{
    CHECK(n >= 1 && wire[n - 1] == 0, "reply without delimiter");
    int d = link_cobs_decode(wire, (uint16_t)(n - 1));
    CHECK(d >= 4, "reply does not decode");
    CHECK(link_crc16(wire, (uint16_t)(d - 2)) == ((wire[d - 2] << 8) | wire[d - 1]), "reply CRC");
    CHECK(wire[0] == type && wire[1] == seq, "reply type %02X seq %02X, expected %02X %02X",
          wire[0], wire[1], type, seq);
    *payload = wire + 2;
    return d - 4;
}

static void test_codec(void)
{
    CHECK(link_crc16((const uint8_t *)"123456789", 9) == 0xD64E, "CRC check value");
    for (int i = 0; i < nv; i++) {
        vec_t *v = &V[i];
        uint8_t buf[320];
        int k = link_cobs_encode(v->dec, (uint16_t)v->ndec, buf);
        buf[k++] = 0;
        CHECK(k == v->nenc && !memcmp(buf, v->enc, (size_t)k), "%s: COBS encoding differs", v->name);
        memcpy(buf, v->enc, (size_t)v->nenc);
        CHECK(link_cobs_decode(buf, (uint16_t)(v->nenc - 1)) == v->ndec
              && !memcmp(buf, v->dec, (size_t)v->ndec), "%s: COBS decoding differs", v->name);
        uint16_t crc = link_crc16(v->dec, (uint16_t)(v->ndec - 2));
        CHECK(crc == ((v->dec[v->ndec - 2] << 8) | v->dec[v->ndec - 1]), "%s: CRC", v->name);
    }
    uint8_t bad[] = {0x05, 0x01, 0x02};
    CHECK(link_cobs_decode(bad, 3) < 0, "COBS code past the end accepted");
    printf("codec: %d golden vectors, COBS both ways and CRC agree\n", nv);
}

static void expect_reply(const char *req, const char *rep)
{
    uint8_t out[320];
    vec_t *q = get(req), *r = get(rep);
    int n = feed(q->enc, q->nenc, out);
    CHECK(n == r->nenc && !memcmp(out, r->enc, (size_t)n), "%s: reply differs from %s", req, rep);
}

static void test_golden_requests(void)
{
    uint8_t out[320], wire[320];
    link_init(&L);
    fake_reset();
    expect_reply("hello", "hello_reply");
    expect_reply("ping", "pong");
    expect_reply("failsafe_arm", "failsafe_reply_armed");
    vec_t *fw = get("failsafe_feed");
    static const uint8_t feed_wire[] = LINK_FAILSAFE_FEED_INIT;
    CHECK(fw->nenc == LINK_FAILSAFE_FEED_LEN && !memcmp(fw->enc, feed_wire, LINK_FAILSAFE_FEED_LEN),
          "failsafe_feed: the table's FAILSAFE_FEED differs from the golden frame");
    fake_reset();
    fake.status = 0xC0;
    expect_reply("run_an693_filter", "run_reply_an693_filter");
    static const uint8_t an693[] = {'C', 0x1E, 'W', 0x00, 'W', 0x08, 'W', 0x00, 'W', 0x0A, 'C', 0x04};
    CHECK(fake.log_len == sizeof an693 && !memcmp(fake.log, an693, sizeof an693),
          "AN-693 filter program reached the bus differently");
    fake_reset();
    fake.hi = 1;
    fake.n_data = 1;
    fake.data[0] = 0;
    expect_reply("run_zero_bytes", "run_reply_zero_bytes");
    CHECK(fake.waited_us == 0x100, "WAIT 0x0100 waited %u us", fake.waited_us);
    /* the busy-timeout golden reply: STATUS (C4), COMMAND, READ 1234, COMMAND stuck busy (81) */
    fake_reset();
    fake.n_script = 4;
    memcpy(fake.script, "\xC4\xC4\xC4\x81", 4);
    fake.n_data = 1;
    fake.data[0] = 0x1234;
    uint8_t prog[] = {0x00, 0x00, 0x64, 0x01, 0x02, 0x0A, 0x04, 0x02, 0x01};
    int n = feed(wire, frame(0x02, 0x7F, prog, sizeof prog, wire), out);
    vec_t *bt = get("run_reply_busy_timeout");
    CHECK(n == bt->nenc && !memcmp(out, bt->enc, (size_t)n), "busy timeout reply differs");
    CHECK(fake.total_polls >= 100, "busy timeout of 100 us gave up after %u polls", fake.total_polls);
    /* the largest RUN: 81 words written */
    fake_reset();
    vec_t *mx = get("run_max_frame");
    uint8_t *p;
    n = feed(mx->enc, mx->nenc, out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0xFE, &p) == 5 && p[0] == 0, "max frame run");
    CHECK(fake.log_len == 81 * 4, "max frame wrote %d log entries", fake.log_len / 2);
    /* a synchronized start on chips 1 and 2: cs 1, STT, SELECT 2, STT */
    fake_reset();
    fake.status = 0xC4;
    fake.hi = 1; /* chip 2's HI: its trajectory-complete flag, enabled after reset */
    expect_reply("run_sync_start", "run_reply_sync_start");
    static const uint8_t stts[] = {'C', 0x01, 'C', 0x01};
    CHECK(fake.log_len == sizeof stts && !memcmp(fake.log, stts, sizeof stts)
          && fake.n_selects == 3 && fake.selects[0] == 1 && fake.selects[1] == 2
          && fake.selects[2] == 0, "sync start reached the bus differently");
    /* the compact RUN: the same module, and RDRP read in program order */
    fake_reset();
    fake.status = 0xC0;
    expect_reply("run_short_an693_filter", "run_short_reply_an693_filter");
    CHECK(fake.log_len == sizeof an693 && !memcmp(fake.log, an693, sizeof an693),
          "AN-693 filter program (RUN_SHORT) reached the bus differently");
    fake_reset();
    fake.status = 0xC0;
    fake.hi = 1;
    fake.n_data = 2;
    fake.data[0] = 0xFFFF;
    fake.data[1] = 0xFC18;
    expect_reply("run_short_rdrp", "run_short_reply_rdrp");
    /* a compact RUN that times out part-way is answered as a RUN: the golden busy timeout */
    fake_reset();
    fake.n_script = 4;
    memcpy(fake.script, "\xC4\xC4\xC4\x81", 4);
    fake.n_data = 1;
    fake.data[0] = 0x1234;
    uint8_t sprog[] = {0x01, 0x02, 0x0A, 0x04, 0x02, 0x01};
    n = feed(wire, frame(0x04, 0x7F, sprog, sizeof sprog, wire), out);
    CHECK(n == bt->nenc && !memcmp(out, bt->enc, (size_t)n), "compact busy timeout reply differs");
    CHECK(fake.total_polls >= 5000, "default busy timeout gave up after %u polls", fake.total_polls);
    /* a bad op code in a compact RUN: nothing runs, BAD_PROGRAM at its index */
    fake_reset();
    uint8_t bprog[] = {0x01, 0x02, 0x0A, 0x7E, 0x04};
    n = feed(wire, frame(0x04, 0x11, bprog, sizeof bprog, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x11, &p) == 5 && p[0] == RESULT_BAD_PROGRAM
          && p[1] == 2 && fake.log_len == 0, "compact RUN with a bad op");
    uint8_t tprog[] = {0x01, 0x03, 0x12};
    n = feed(wire, frame(0x04, 0x12, tprog, sizeof tprog, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x12, &p) == 5 && p[0] == RESULT_BAD_PROGRAM
          && p[1] == 1 && fake.log_len == 0, "compact RUN with a truncated argument");
    /* a compact RUN starts on chip 0; SELECT in it works as in a RUN, checked as the bytes
     * arrive: a chip the bridge lacks is BAD_CHIP_SELECT at that operation, nothing runs */
    fake_reset();
    uint8_t selp[] = {0x02, 0x01, 0x09, 0x02, 0x02, 0x01};
    n = feed(wire, frame(0x04, 0x16, selp, sizeof selp, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x84, 0x16, &p) == 1 && fake.n_selects == 2
          && fake.selects[0] == 2 && fake.selects[1] == 0, "compact RUN with SELECT 2");
    fake_reset();
    uint8_t selbad[] = {0x02, 0x01, 0x09, LINK_CHIP_SELECTS, 0x02, 0x01};
    n = feed(wire, frame(0x04, 0x17, selbad, sizeof selbad, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x17, &p) == 5 && p[0] == RESULT_BAD_CHIP_SELECT
          && p[1] == 1 && fake.log_len == 0, "compact RUN selecting a chip the bridge lacks");
    /* RUN_STORE keeps RDRP under code 3 (and runs it); RUN_CODE 3 runs it again; a HELLO
     * forgets it: RUN_CODE 3 is then UNKNOWN_CODE, and nothing runs */
    fake_reset();
    fake.status = 0xC0;
    fake.hi = 1;
    fake.n_data = 4;
    fake.data[0] = fake.data[2] = 0xFFFF;
    fake.data[1] = fake.data[3] = 0xFC18;
    vec_t *st3 = get("run_store_rdrp");
    n = feed(st3->enc, st3->nenc, out);
    CHECK(n > 0 && reply_payload(out, n, 0x84, 0x11, &p) == 5 && !memcmp(p, "\xFF\xFF\xFC\x18\xC1", 5),
          "RUN_STORE of RDRP");
    uint16_t log_store = fake.log_len;
    expect_reply("run_code_rdrp", "run_code_reply_rdrp");
    CHECK(fake.log_len == 2 * log_store, "RUN_CODE did not run the program kept");
    vec_t *hh = get("hello");
    feed(hh->enc, hh->nenc, out);
    uint16_t log_before = fake.log_len;
    expect_reply("run_code_rdrp", "run_reply_unknown_code");
    CHECK(fake.log_len == log_before, "an unknown code ran something");
    /* a code out of range, a program too long to keep: refused, nothing stored or run */
    uint8_t bad_code[] = {LINK_CODE_SLOTS, 0x01};
    n = feed(wire, frame(0x05, 0x13, bad_code, sizeof bad_code, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x13, &p) == 5 && p[0] == RESULT_UNKNOWN_CODE,
          "RUN_STORE to a code out of range");
    uint8_t big[1 + LINK_CODE_BYTES + 1];
    big[0] = 1;
    memset(big + 1, 0x01, LINK_CODE_BYTES + 1);
    n = feed(wire, frame(0x05, 0x14, big, sizeof big, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x14, &p) == 5 && p[0] == RESULT_PROGRAM_TOO_LONG
          && fake.log_len == log_before, "RUN_STORE of a program too long to keep");
    uint8_t code1[] = {1};
    n = feed(wire, frame(0x06, 0x15, code1, sizeof code1, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x15, &p) == 5 && p[0] == RESULT_UNKNOWN_CODE,
          "RUN_CODE after a refused RUN_STORE");
    /* SET_BAUD: 1 Mbaud made exactly (divisor 2, for main.c to switch to); 230400 refused */
    L.baud_div = 0;
    expect_reply("set_baud_1m", "baud_reply_1m");
    CHECK(L.baud_div == 2, "SET_BAUD 1000000 left divisor %u", L.baud_div);
    L.baud_div = 0;
    uint8_t b230[] = {0x00, 0x03, 0x84, 0x00};
    n = feed(wire, frame(0x07, 0x21, b230, sizeof b230, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x87, 0x21, &p) == 5 && p[0] == RESULT_BAD_BAUD
          && L.baud_div == 0, "SET_BAUD 230400 (222222 made: 3.5 %% off) not refused");
    /* unknown request type -> ERROR_REPLY BAD_REQUEST */
    n = feed(wire, frame(0x70, 0x33, NULL, 0, wire), out);
    vec_t *er = get("error_reply");
    CHECK(n == er->nenc && !memcmp(out, er->enc, (size_t)n), "error reply differs");
    printf("requests: HELLO, PING, RUN (AN-693 filter, zero bytes, busy timeout, largest), "
           "RUN_SHORT (AN-693, RDRP, busy timeout, bad op, truncated), RUN_STORE / RUN_CODE "
           "(kept, run again, forgotten by HELLO, bad code, too long), unknown type answered "
           "as the golden replies\n");
}

static void test_exactly_once(void)
{
    uint8_t out1[320], out2[320];
    link_init(&L);
    fake_reset();
    fake.status = 0xC0;
    vec_t *q = get("run_an693_filter");
    int n1 = feed(q->enc, q->nenc, out1);
    uint16_t log1 = fake.log_len;
    int n2 = feed(q->enc, q->nenc, out2);
    CHECK(n1 && n1 == n2 && !memcmp(out1, out2, (size_t)n1), "repeat answered differently");
    CHECK(fake.log_len == log1 && L.runs == 1 && L.cache_hits == 1, "repeat ran the program again");
    /* same seq, other bytes: a new request */
    uint8_t wire[320], out[320], prog[] = {0x00, 0x13, 0x88, 0x02, 0x01};
    CHECK(feed(wire, frame(0x02, 0x2A, prog, sizeof prog, wire), out) && L.runs == 2,
          "same seq, other CRC not run");
    /* HELLO forgets the cache */
    vec_t *h = get("hello");
    feed(h->enc, h->nenc, out);
    feed(q->enc, q->nenc, out);
    CHECK(L.runs == 3, "HELLO did not forget the cached reply");
    printf("exactly once: a repeated RUN is answered from the cache, other CRC or HELLO runs anew\n");
}

/* OP_WAIT_STATUS: status reads every WAIT_STATUS_POLL_US until the mask matches or the
 * timeout (ms) has passed; one status reported, the result OK either way */
static void test_wait_status(void)
{
    uint8_t wire[320], out[320], *p;
    uint8_t prog[] = {0x00, 0x13, 0x88, OP_WAIT_STATUS, 0x04, 0x00, 0x0A}; /* bit 2, 10 ms */
    link_init(&L);
    fake_reset();
    fake.rx_pending_after = 0xFFFFFFFFu; /* the host sends nothing during these waits */
    fake.n_script = 4;
    memcpy(fake.script, "\x80\x80\x80\x84", 4);
    int n = feed(wire, frame(0x02, 0x10, prog, sizeof prog, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x10, &p) == 6, "wait status reply size");
    CHECK(p[0] == 0 && p[2] == 0x84 && p[4] == 1 && p[5] == 0x84, "wait status: reply %02X %02X %02X %02X",
          p[0], p[2], p[4], p[5]);
    CHECK(fake.total_polls == 4 && fake.waited_us == 3 * WAIT_STATUS_POLL_US,
          "wait status: %u reads, %u us waited (expected 4, %u)", fake.total_polls, fake.waited_us,
          3 * WAIT_STATUS_POLL_US);
    /* the timeout: 2 ms of a status that never matches = 1 + 2 * 8 reads, 16 periods */
    fake_reset();
    fake.rx_pending_after = 0xFFFFFFFFu;
    fake.status = 0x80;
    prog[6] = 0x02;
    n = feed(wire, frame(0x02, 0x11, prog, sizeof prog, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x11, &p) == 6 && p[0] == 0 && p[5] == 0x80,
          "wait status timeout reply");
    CHECK(fake.total_polls == 17 && fake.waited_us == 16 * WAIT_STATUS_POLL_US,
          "wait status timeout: %u reads, %u us waited", fake.total_polls, fake.waited_us);
    /* a wait for a mask no status can match (0), 65.5 s: a byte from the host (a new
     * client's HELLO) after 5 polls ends it, answered OK with the last status read, instead
     * of the bridge staying deaf for the whole wait */
    fake_reset();
    fake.rx_pending_after = 5;
    fake.status = 0x80;
    uint8_t deaf[] = {0x00, 0x13, 0x88, OP_WAIT_STATUS, 0x00, 0xFF, 0xFF};
    n = feed(wire, frame(0x02, 0x12, deaf, sizeof deaf, wire), out);
    CHECK(n > 0 && reply_payload(out, n, 0x82, 0x12, &p) == 6 && p[0] == 0 && p[5] == 0x80,
          "wait status ended by the host: reply");
    CHECK(fake.total_polls == 6 && fake.waited_us == 5 * WAIT_STATUS_POLL_US,
          "wait status ended by the host: %u reads, %u us waited (expected 6, %u)",
          fake.total_polls, fake.waited_us, 5 * WAIT_STATUS_POLL_US);
    printf("wait status: reads until the mask matches, for the timeout, or until the host sends; "
           "one status reported\n");
}

static void test_errors(void)
{
    uint8_t wire[320], out[320], *p;
    int n;
    link_init(&L);
    fake_reset();
    /* corrupt one byte: no answer, counted bad; the next good frame is answered */
    vec_t *q = get("ping");
    memcpy(wire, q->enc, (size_t)q->nenc);
    wire[3] ^= 0x40;
    CHECK(feed(wire, q->nenc, out) == 0 && L.bad_frames == 1, "corrupt frame answered");
    static const uint8_t junk[] = {0x12, 0x00, 0xFF, 0xFF, 0x03, 0x00, 0x00, 0x00};
    CHECK(feed(junk, sizeof junk, out) == 0, "junk answered");
    CHECK(feed(q->enc, q->nenc, out) > 0, "no resync after junk");
    /* too long: 300 non-zero bytes then a delimiter; then resync */
    memset(wire, 0x11, 300);
    wire[300] = 0;
    CHECK(feed(wire, 301, out) == 0, "overlong frame answered");
    CHECK(feed(q->enc, q->nenc, out) > 0, "no resync after overlong frame");
    /* bad chip select, bad op, truncated arg, too many reads, truncated RUN */
    uint8_t cs1[] = {LINK_CHIP_SELECTS, 0x00, 0x00, 0x01};
    n = feed(wire, frame(0x02, 1, cs1, sizeof cs1, wire), out);
    CHECK(reply_payload(out, n, 0x82, 1, &p) == 5 && p[0] == RESULT_BAD_CHIP_SELECT, "bad cs");
    /* a SELECT beyond the chip selects: refused before the bus, naming the operation */
    uint8_t badsel[] = {0x00, 0x00, 0x00, OP_STATUS, OP_SELECT, LINK_CHIP_SELECTS};
    n = feed(wire, frame(0x02, 1, badsel, sizeof badsel, wire), out);
    CHECK(reply_payload(out, n, 0x82, 1, &p) == 5 && p[0] == RESULT_BAD_CHIP_SELECT && p[1] == 1,
          "bad SELECT");
    uint8_t badop[] = {0x00, 0x00, 0x00, 0x01, 0x02, 0x01, OP_MAX + 2};
    n = feed(wire, frame(0x02, 2, badop, sizeof badop, wire), out);
    CHECK(reply_payload(out, n, 0x82, 2, &p) == 5 && p[0] == RESULT_BAD_PROGRAM && p[1] == 2,
          "bad op index %d", p[1]);
    uint8_t trunc[] = {0x00, 0x00, 0x00, 0x01, 0x03, 0x12};
    n = feed(wire, frame(0x02, 3, trunc, sizeof trunc, wire), out);
    CHECK(reply_payload(out, n, 0x82, 3, &p) == 5 && p[0] == RESULT_BAD_PROGRAM && p[1] == 1,
          "truncated arg");
    CHECK(fake.log_len == 0, "a bad program touched the bus");
    uint8_t reads[3 + 121] = {0};
    memset(reads + 3, 0x04, 121);
    n = feed(wire, frame(0x02, 4, reads, sizeof reads, wire), out);
    CHECK(reply_payload(out, n, 0x82, 4, &p) == 5 && p[0] == RESULT_PROGRAM_TOO_LONG, "121 reads");
    uint8_t shortrun[] = {0x00, 0x00};
    n = feed(wire, frame(0x02, 5, shortrun, sizeof shortrun, wire), out);
    CHECK(reply_payload(out, n, 0xFF, 5, &p) == 1 && p[0] == RESULT_BAD_REQUEST, "short RUN");
    uint8_t big[40] = {0};
    n = feed(wire, frame(0x03, 6, big, sizeof big, wire), out);
    CHECK(reply_payload(out, n, 0xFF, 6, &p) == 1 && p[0] == RESULT_BAD_REQUEST, "long PING");
    CHECK(feed(wire, frame(0x82, 7, NULL, 0, wire), out) == 0, "a reply type was answered");
    printf("errors: corrupt, junk and overlong frames dropped with resync; bad cs, op, argument, "
           "reads, RUN and PING sizes answered with their codes\n");
}

/* RUN's cs selects the first chip, OP_SELECT the next: both reach the bus in program order */
static void test_select(void)
{
    uint8_t wire[320], out[320], *p;
    link_init(&L);
    fake_reset();
    uint8_t prog[] = {0x01, 0x00, 0x00, OP_STATUS, OP_SELECT, 0x03, OP_STATUS, OP_SELECT, 0x00};
    int n = feed(wire, frame(0x02, 9, prog, sizeof prog, wire), out);
    CHECK(reply_payload(out, n, 0x82, 9, &p) == 7 && p[0] == RESULT_OK && p[4] == 2, "select run");
    /* cs 1, SELECT 3, SELECT 0 (chip 0 at the end: nothing to release) */
    CHECK(fake.n_selects == 3 && fake.selects[0] == 1 && fake.selects[1] == 3
          && fake.selects[2] == 0, "selects %d: %d %d %d", fake.n_selects, fake.selects[0],
          fake.selects[1], fake.selects[2]);
    /* a program that ends on chip 2 releases it: chip 0 selected again */
    fake_reset();
    uint8_t prog2[] = {0x00, 0x00, 0x00, OP_SELECT, 0x02, OP_STATUS};
    n = feed(wire, frame(0x02, 10, prog2, sizeof prog2, wire), out);
    CHECK(reply_payload(out, n, 0x82, 10, &p) == 6 && p[0] == RESULT_OK && fake.n_selects == 2
          && fake.selects[0] == 2 && fake.selects[1] == 0, "release after chip 2");
    printf("select: the RUN's cs, then each SELECT, reach the bus in order\n");
}

/* RECORD: the golden request (status, RDDP, RDRP every 1000 us, 3 rows) sends three rows, each
 * its number, its time on the bridge's clock and the bytes read in program order, then the
 * golden RECORD_END; the due times are exact multiples of the period (250 ticks of 4 us) */
static void test_record(void)
{
    uint8_t out[320], *p;
    link_init(&L);
    fake_reset();
    fake.status = 0xC4;
    fake.rx_pending_after = 100000;
    fake.n_data = 12;
    for (int i = 0; i < 12; i++)
        fake.data[i] = (uint16_t)(0x1000 + i);
    vec_t *req = get("record_basic"), *end = get("record_end");
    int n = feed(req->enc, req->nenc, out);
    CHECK(n == end->nenc && !memcmp(out, end->enc, (size_t)n), "record: RECORD_END differs");
    CHECK(fake.rows_seen == 3, "record: %u rows, expected 3", fake.rows_seen);
    uint32_t t_prev = 0;
    int at = 0;
    for (int k = 0; k < 3; k++) {
        int len = 0;
        while (fake.rows[at + len])
            len++;
        len++;
        int d = reply_payload(fake.rows + at, len, FRAME_RECORD_ROW, 0x30, &p);
        at += len;
        CHECK(d == 6 + 9, "record: row %d of %d bytes", k, d);
        uint32_t t = ((uint32_t)p[2] << 24) | ((uint32_t)p[3] << 16) | ((uint32_t)p[4] << 8) | p[5];
        CHECK(((p[0] << 8) | p[1]) == k, "record: row number %d", k);
        CHECK(k == 0 || (t - t_prev >= 1000 && t - t_prev <= 1008), "record: row %d at %u us, "
              "the one before at %u us", k, t, t_prev);
        t_prev = t;
        uint16_t w0 = (uint16_t)(0x1000 + 4 * k);
        CHECK(p[6] == 0xC4 && ((p[7] << 8) | p[8]) == w0 && ((p[9] << 8) | p[10]) == w0 + 1
              && ((p[13] << 8) | p[14]) == w0 + 3, "record: row %d's bytes", k);
    }
    /* the commands: RDDP, RDRP each row, nothing else (a recording never changes the chip) */
    int cmds = 0;
    for (int i = 0; i + 1 < fake.log_len; i += 2)
        if (fake.log[i] == 'C') {
            CHECK(fake.log[i + 1] == 0x08 || fake.log[i + 1] == 0x0A, "record: command %02X",
                  fake.log[i + 1]);
            cmds++;
        }
    CHECK(cmds == 6, "record: %d commands", cmds);
    /* a byte from the host stops it: END with the rows sent so far (row 0 at once, row 1 after
     * 250 ticks, the byte while waiting for row 2: a tick and a poll each loop) */
    fake_reset();
    fake.rx_pending_after = 300;
    n = feed(req->enc, req->nenc, out);
    CHECK(reply_payload(out, n, FRAME_RECORD_END, 0x30, &p) == 4 && p[0] == RESULT_OK
          && (uint32_t)((p[2] << 8) | p[3]) == fake.rows_seen && fake.rows_seen == 2,
          "record: stopped "
          "after %u rows", fake.rows_seen);
    /* a program that writes is refused before anything runs: the golden refusal */
    fake_reset();
    uint8_t bad[] = {0x00, 0x00, 0x03, 0xE8, 0x00, 0x03, OP_STATUS, OP_COMMAND, 0x01}, wire[64];
    vec_t *refused = get("record_end_bad_program");
    n = feed(wire, frame(FRAME_RECORD, 0x31, bad, sizeof bad, wire), out);
    CHECK(n == refused->nenc && !memcmp(out, refused->enc, (size_t)n) && fake.log_len == 0,
          "record: STT in a sample program not refused");
    printf("record: rows every 1000 us on the bridge's clock, in program order; stopped by a "
           "byte; a writing program refused\n");
}

/* PROFILE: the golden request (a new schedule, pieces at 20 and 40 ms) is answered with the
 * golden reply (nothing issued, two pending); link_idle issues each piece once the bridge's
 * clock (one tick a look in the fake) reaches it: LTRJ 0008 and the velocity, then STT; a
 * program with LTRJ (a stop) drops what is pending, and the next reply says so. */
static void test_profile(void)
{
    uint8_t out[320], wire[64], *p;
    link_init(&L);
    fake_reset();
    fake.status = 0xC0;
    expect_reply("profile_two", "profile_reply_two");
    CHECK(fake.log_len == 0, "profile: a piece issued at once");
    while (L.prof_n == 2 && fake.ticks < 100000)
        link_idle(&L);
    CHECK(L.prof_n == 1 && fake.ticks >= 5000 && fake.ticks <= 5010,
          "profile: first piece at tick %u", (unsigned)fake.ticks);
    const uint8_t want[] = {'C', 0x1F, 'W', 0x00, 'W', 0x08, 'W', 0x00, 'W', 0x01, 'W', 0x40,
                            'W', 0x00, 'C', 0x01};
    int at = 0, ok = 1;
    for (int i = 0; i + 1 < fake.log_len && at < (int)sizeof want; i += 2)
        if (fake.log[i] == 'C' || fake.log[i] == 'W') {
            ok &= fake.log[i] == want[at] && fake.log[i + 1] == want[at + 1];
            at += 2;
        }
    CHECK(ok && at == (int)sizeof want, "profile: the piece's bus cycles");
    /* a stop (LTRJ 0100 abrupt, STT) before the second piece: the schedule is dropped */
    uint8_t stop[] = {0x00, 0x00, 0x00, OP_COMMAND, 0x1F, OP_WRITE, 0x02, 0x00, OP_COMMAND, 0x01};
    feed(wire, frame(FRAME_RUN, 0x41, stop, sizeof stop, wire), out);
    CHECK(L.prof_n == 0, "profile: a stop left %u pieces", L.prof_n);
    uint8_t ask[] = {0x00, 0x00};
    int n = feed(wire, frame(FRAME_PROFILE, 0x42, ask, sizeof ask, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x42, &p) == 9
          && p[0] == RESULT_PROFILE_CANCELLED && ((p[1] << 8) | p[2]) == 1 && p[4] == 0,
          "profile: the reply after a stop");
    /* pieces closer than 10 ms: refused, nothing kept */
    uint8_t close[] = {0x01, 0x00, 0, 0, 0x4E, 0x20, 0, 1, 0, 0, 0, 0, 0x55, 0xF0, 0, 1, 0, 0};
    n = feed(wire, frame(FRAME_PROFILE, 0x43, close, sizeof close, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x43, &p) == 9 && p[0] == RESULT_BAD_PROFILE
          && p[4] == 0, "profile: pieces 2 ms apart not refused");
    printf("profile: the golden schedule, a piece at its tick (LTRJ 0008 + velocity, STT), "
           "dropped by a stop; pieces 2 ms apart refused\n");
}

/* PROFILE's pieces 20 and 40 ms (ticks 5000 and 10000): the first goes out late, at tick
 * 9000 (the bridge was busy with a program); the second waits until 10 ms (2500 ticks) after
 * it instead of following at its own time 1000 ticks later, which would be two STTs 4 ms apart
 * (the chip aborts its trajectory calculation, AN-706 4.6.2) */
static void test_profile_spacing(void)
{
    link_init(&L);
    fake_reset();
    fake.status = 0xC0;
    expect_reply("profile_two", "profile_reply_two");
    fake.ticks = 9000;
    link_idle(&L);
    CHECK(L.prof_n == 1, "profile spacing: the late first piece not issued");
    uint32_t first = fake.ticks;
    while (L.prof_n == 1 && fake.ticks < 100000)
        link_idle(&L);
    CHECK(L.prof_n == 0 && fake.ticks >= first + 2500u - 2u,
          "profile spacing: second piece %u ticks after a late first one (10 ms = 2500)",
          (unsigned)(fake.ticks - first));
    printf("profile spacing: a late piece pushes the next to 10 ms after it\n");
}

/* A failsafe trip while a shaped move's pieces are pending: the schedule is dropped before the
 * chips are stopped, no piece goes out after (not even at its time), and new pieces are
 * refused until the trip is acknowledged. */
static void test_failsafe_drops_profile(void)
{
    uint8_t out[320], wire[64], *p;
    link_init(&L);
    fake_reset();
    fake.status = 0xC0;
    uint8_t arm[] = {FAILSAFE_CMD_ARM, 0x00, 0x32, FAILSAFE_ACTION_ABRUPT}; /* 50 ms */
    int n = feed(wire, frame(FRAME_FAILSAFE, 0x50, arm, sizeof arm, wire), out);
    CHECK(reply_payload(out, n, FRAME_FAILSAFE_REPLY, 0x50, &p) == LINK_FAILSAFE_REPLY_SIZE
          && p[0] == RESULT_OK, "failsafe+profile: armed");
    /* two pieces at 100 ms and 120 ms: both after the failsafe's 50 ms */
    uint8_t two[] = {LINK_PROFILE_NEW, 0x00, 0, 0x01, 0x86, 0xA0, 0, 1, 0, 0,
                     0, 0x01, 0xD4, 0xC0, 0, 2, 0, 0};
    n = feed(wire, frame(FRAME_PROFILE, 0x51, two, sizeof two, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x51, &p) == 9 && p[0] == RESULT_OK
          && p[4] == 2, "failsafe+profile: two pieces scheduled");
    uint32_t start = fake.ticks, tripped_at = 0;
    fake.log_len = 0;
    while (fake.ticks - start < 60000u) { /* 240 ms of main loop: link_poll, then the pieces */
        link_poll();
        if (!tripped_at && !L.prof_n)
            tripped_at = fake.ticks - start;
        link_idle(&L);
    }
    CHECK(tripped_at >= 12400u && tripped_at < 12600u,
          "failsafe+profile: the trip (schedule dropped) at tick %u, expected 12500",
          (unsigned)tripped_at);
    int stops = 0, pieces = 0;
    for (int i = 0; i + 5 < fake.log_len; i += 2)
        if (fake.log[i] == 'C' && fake.log[i + 1] == 0x1F && fake.log[i + 2] == 'W') {
            stops += fake.log[i + 3] == (FAILSAFE_STOP_ABRUPT >> 8);
            pieces += fake.log[i + 3] == (LINK_PROFILE_LTRJ_CONTROL >> 8)
                && fake.log[i + 5] == (uint8_t)LINK_PROFILE_LTRJ_CONTROL;
        }
    CHECK(stops == LINK_CHIP_SELECTS && pieces == 0,
          "failsafe+profile: %d abrupt stops, %d pieces issued after the trip", stops, pieces);
    uint8_t ask[] = {0x00, 0x00};
    n = feed(wire, frame(FRAME_PROFILE, 0x52, ask, sizeof ask, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x52, &p) == 9
          && p[0] == RESULT_PROFILE_CANCELLED && ((p[1] << 8) | p[2]) == 0 && p[4] == 0,
          "failsafe+profile: the schedule's reply after the trip");
    n = feed(wire, frame(FRAME_PROFILE, 0x53, two, sizeof two, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x53, &p) == 9
          && p[0] == RESULT_FAILSAFE_TRIPPED && p[4] == 0,
          "failsafe+profile: pieces taken while the trip is latched");
    uint8_t ack[] = {FAILSAFE_CMD_ACKNOWLEDGE}, off[] = {FAILSAFE_CMD_DISARM};
    feed(wire, frame(FRAME_FAILSAFE, 0x54, ack, sizeof ack, wire), out);
    n = feed(wire, frame(FRAME_FAILSAFE, 0x55, off, sizeof off, wire), out);
    CHECK(reply_payload(out, n, FRAME_FAILSAFE_REPLY, 0x55, &p) == LINK_FAILSAFE_REPLY_SIZE
          && p[0] == RESULT_OK && p[4] == 0 && p[5] == 0, "failsafe+profile: acknowledged, off");
    n = feed(wire, frame(FRAME_PROFILE, 0x56, two, sizeof two, wire), out);
    CHECK(reply_payload(out, n, FRAME_PROFILE_REPLY, 0x56, &p) == 9 && p[0] == RESULT_OK
          && p[4] == 2, "failsafe+profile: pieces taken again after the acknowledgement");
    link_init(&L);
    printf("failsafe+profile: a trip drops the pending pieces (none issued after, even at their "
           "time), PROFILE_CANCELLED, pieces refused until acknowledged\n");
}

int main(int argc, char **argv)
{
    load(argc > 1 ? argv[1] : "golden_frames.txt");
    test_codec();
    test_select();
    test_record();
    test_profile();
    test_profile_spacing();
    test_failsafe_drops_profile();
    test_golden_requests();
    test_exactly_once();
    test_wait_status();
    test_errors();
    printf("test_link: %d checks passed\n", checks);
    return 0;
}
