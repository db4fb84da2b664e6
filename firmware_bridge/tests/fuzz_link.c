/* Fuzz run of the firmware's frame parser and request dispatcher on the host (built with
 * AddressSanitizer and UBSan): random bytes, mutated valid frames and random valid RUN
 * and RUN_SHORT programs, fed back to back.  Every reply must be a well-formed frame with a good CRC and the
 * seq of a request; after the run a clean HELLO must still be answered.
 *   fuzz_link ITERATIONS SEED */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "../link.h"
#include "fake_bus.h"

static uint64_t rng = 88172645463325252ull;
static uint32_t rnd(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)rng;
}

static link_t L;
static unsigned long replies, bad;


static void check_reply(const uint8_t *r, uint16_t n)
{
    uint8_t buf[400];
    if (n < 2 || n > LINK_MAX_WIRE_FRAME || r[n - 1] != 0) {
        printf("FAIL: reply of %u bytes badly delimited\n", n);
        exit(1);
    }
    memcpy(buf, r, n);
    for (uint16_t i = 0; i + 1 < n; i++)
        if (!buf[i]) {
            printf("FAIL: zero byte inside an encoded reply\n");
            exit(1);
        }
    int d = link_cobs_decode(buf, (uint16_t)(n - 1));
    if (d < 4 || link_crc16(buf, (uint16_t)(d - 2)) != ((buf[d - 2] << 8) | buf[d - 1])
        || !(buf[0] & 0x80)) {
        printf("FAIL: reply does not decode or fails its CRC\n");
        exit(1);
    }
    replies++;
}

static void feed(const uint8_t *p, int n)
{
    for (int i = 0; i < n; i++) {
        const uint8_t *r;
        uint16_t k = link_feed(&L, p[i], &r);
        if (k) {
            if (!fake_tx_verify(r, k)) {
                printf("FAIL: the bytes sent through link_tx_byte are not the reply returned\n");
                exit(1);
            }
            check_reply(r, k);
        }
    }
}

static int make_frame(uint8_t *wire)
{
    uint8_t d[300];
    int n = 2;
    d[0] = (uint8_t)(rnd() % 5 ? (rnd() % 8) + 1 : rnd());
    d[1] = (uint8_t)rnd();
    if (d[0] == 8) { /* RECORD: a period around the shortest, a few rows, a program of reads */
        uint32_t period = (uint32_t)(rnd() % 4 ? 150 + rnd() % 400 : rnd());
        for (int k = 3; k >= 0; k--)
            d[n++] = (uint8_t)(period >> (8 * k));
        d[n++] = 0;
        d[n++] = (uint8_t)(rnd() % 5);
        int ops = (int)(rnd() % 12);
        for (int i = 0; i < ops; i++) {
            uint8_t op = (uint8_t)(rnd() % 3 == 0 ? OP_STATUS : rnd() % 2 ? OP_READ : OP_COMMAND);
            if (rnd() % 20 == 0)
                op = (uint8_t)rnd();
            d[n++] = op;
            if (op == OP_COMMAND)
                d[n++] = (uint8_t)(rnd() % 8 ? 7 + rnd() % 7 : rnd());
        }
    } else if (d[0] == 6) { /* RUN_CODE: a code, now and then out of range */
        d[n++] = (uint8_t)(rnd() % 10);
    } else if (d[0] == 7) { /* SET_BAUD: any rate, 0 included */
        for (int k = 0; k < 4; k++)
            d[n++] = (uint8_t)(rnd() % 3 ? rnd() : 0);
    } else if (d[0] == 2 || d[0] == 4 || d[0] == 5) { /* RUN, RUN_SHORT, RUN_STORE */
        if (d[0] == 5)
            d[n++] = (uint8_t)(rnd() % 10);
        if (d[0] == 2) {
            d[n++] = (uint8_t)(rnd() % 8 ? 0 : rnd());
            d[n++] = 0;
            d[n++] = (uint8_t)(rnd() % 200);
        }
        int ops = (int)(rnd() % (d[0] == 5 ? 6 : 60)); /* RUN_STORE: mostly short enough to keep */
        for (int i = 0; i < ops && n < 240; i++) {
            uint8_t op = (uint8_t)(rnd() % 20 ? (rnd() % 7) + 1 : rnd());
            d[n++] = op;
            int args = op == 2 ? 1 : (op == 3 || op == 6) ? 2 : 0;
            for (int k = 0; k < args && n < 246; k++)
                d[n++] = (uint8_t)(op == 6 ? rnd() % 3 : rnd());
        }
    } else {
        int len = (int)(rnd() % 40);
        for (int i = 0; i < len; i++)
            d[n++] = (uint8_t)rnd();
    }
    uint16_t crc = link_crc16(d, (uint16_t)n);
    d[n++] = (uint8_t)(crc >> 8);
    d[n++] = (uint8_t)crc;
    int k = link_cobs_encode(d, (uint16_t)n, wire);
    wire[k++] = 0;
    return k;
}

int main(int argc, char **argv)
{
    long iters = argc > 1 ? atol(argv[1]) : 100000;
    rng ^= (uint64_t)(argc > 2 ? atol(argv[2]) : 1) * 0x9E3779B97F4A7C15ull;
    link_init(&L);
    fake_reset();
    uint8_t wire[600];
    for (long it = 0; it < iters; it++) {
        fake_reset();
        fake.status = (uint8_t)(rnd() & 0xFE);
        fake.busy_polls = (uint16_t)(rnd() % 4 ? 0 : rnd() % 300);
        fake.n_data = 64;
        fake.rx_pending_after = 300; /* a recording is stopped by the host after a while */
        int n, kind = (int)(rnd() % 4);
        if (kind == 0) { /* random bytes, zeros now and then */
            n = (int)(rnd() % 400);
            for (int i = 0; i < n; i++)
                wire[i] = (uint8_t)(rnd() % 16 ? rnd() : 0);
        } else {
            n = make_frame(wire);
            if (kind == 1) { /* mutate: flip, drop or insert bytes */
                int m = 1 + (int)(rnd() % 3);
                for (int k = 0; k < m && n > 1; k++) {
                    int at = (int)(rnd() % (unsigned)n), how = (int)(rnd() % 3);
                    if (how == 0)
                        wire[at] ^= (uint8_t)(1u << (rnd() % 8));
                    else if (how == 1) {
                        memmove(wire + at, wire + at + 1, (size_t)(n - at - 1));
                        n--;
                    } else if (n < 590) {
                        memmove(wire + at + 1, wire + at, (size_t)(n - at));
                        wire[at] = (uint8_t)rnd();
                        n++;
                    }
                }
            }
        }
        feed(wire, n);
        bad = L.bad_frames;
    }
    /* still in step: a delimiter, then a good HELLO must be answered */
    unsigned long before = replies;
    uint8_t hello[] = {0x00, 0x05, 0x01, 0x01, 0xC1, 0xE0, 0x00};
    feed(hello, sizeof hello);
    if (replies != before + 1) {
        printf("FAIL: no answer to HELLO after the fuzz run\n");
        return 1;
    }
    printf("fuzz_link: %ld inputs, %lu replies checked, %lu good frames, %lu bad frames dropped, "
           "%lu programs run, 0 failures\n", iters, replies, (unsigned long)L.frames, bad, (unsigned long)L.runs);
    return 0;
}
