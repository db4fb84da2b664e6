#include <string.h>
#include "../bus.h"
#include "../link.h"
#include "../uart.h"
#include "fake_bus.h"

fake_bus_t fake;

void fake_reset(void) { memset(&fake, 0, sizeof fake); }

static void note(uint8_t a, uint8_t b)
{
    if (fake.log_len + 2u <= sizeof fake.log) {
        fake.log[fake.log_len++] = a;
        fake.log[fake.log_len++] = b;
    }
}

uint8_t bus_read_status(void)
{
    fake.total_polls++;
    fake.elapsed_us++;
    if (fake.n_script) {
        uint16_t i = fake.script_at < fake.n_script ? fake.script_at++ : fake.n_script - 1;
        return fake.script[i];
    }
    if (fake.busy_polls) {
        fake.busy_polls--;
        return (uint8_t)(fake.status | 1u);
    }
    return fake.status;
}
void bus_write_command(uint8_t cmd) { note('C', cmd); }
void bus_write_data(uint8_t byte) { note('W', byte); }
uint8_t bus_read_data(void)
{
    uint16_t w = fake.data_at < fake.n_data ? fake.data[fake.data_at] : 0;
    uint8_t b = fake.byte_phase ? (uint8_t)w : (uint8_t)(w >> 8);
    if (fake.byte_phase)
        fake.data_at++;
    fake.byte_phase ^= 1;
    note('R', b);
    return b;
}
void bus_reset_pulse(void) { fake.resets++; note('X', 0); }
void bus_select(uint8_t chip)
{
    fake.selected = chip;
    if (fake.n_selects < sizeof fake.selects)
        fake.selects[fake.n_selects++] = chip;
}
uint8_t bus_hi(void) { return fake.hi; }
void bus_wait_us(uint16_t us) { fake.waited_us += us; note('T', (uint8_t)(us >> 8)); }
void bus_timer_start(void) { fake.elapsed_us = 0; }
/* the clock advances one tick (4 us) each time it is read */
uint16_t bus_ticks(void) { return (uint16_t)(fake.ticks++); }
/* a byte from the host "arrives" after rx_pending_after polls (0: one is waiting already) */
uint8_t link_rx_pending(void)
{
    fake.rx_polls++;
    return fake.rx_polls > fake.rx_pending_after;
}
/* the byte waiting: a lone delimiter (any byte but FAILSAFE_FEED's first ends a recording) */
uint8_t link_rx_peek(void) { return 0; }
void link_rx_skip(void) {}
uint8_t bus_timer_elapsed(uint16_t us) { return fake.elapsed_us > us; }

uint8_t bus_wait_not_busy(uint16_t timeout_us, uint8_t *status)
{
    bus_timer_start();
    for (;;) {
        uint8_t s = bus_read_status();
        *status = s;
        if (!(s & 0x01u))
            return 1;
        if (bus_timer_elapsed(timeout_us))
            return 0;
    }
}

/* the transmitter: link.c sends every reply byte through link_tx_byte; fake_tx_verify checks
 * that exactly the frame link_feed returned went out, in order.  Room for a recording the fuzz
 * run stops only after rx_pending_after polls: a row may take one poll, so 300 rows of up to
 * ~100 bytes come before its RECORD_END */
static uint8_t tx_sent[32768];
static uint16_t tx_n;

void link_tx_byte(uint8_t b)
{
    if (tx_n < sizeof tx_sent)
        tx_sent[tx_n] = b;
    tx_n++;
}

/* Before a reply only whole RECORD_ROW frames may have gone out (a recording's rows; its
 * RECORD_END is the reply returned). */
static int only_rows(const uint8_t *p, uint16_t n)
{
    uint8_t buf[1024];
    uint16_t start = 0;
    for (uint16_t i = 0; i < n; i++) {
        if (p[i])
            continue;
        uint16_t len = (uint16_t)(i - start);
        memcpy(buf, p + start, len);
        int16_t d = link_cobs_decode(buf, len);
        if (d < 4 || buf[0] != FRAME_RECORD_ROW
            || link_crc16(buf, (uint16_t)(d - 2)) != ((buf[d - 2] << 8) | buf[d - 1]))
            return 0;
        fake.rows_seen++;
        start = (uint16_t)(i + 1);
    }
    return start == n;
}

int fake_tx_verify(const uint8_t *out, uint16_t n)
{
    int ok = tx_n >= n && tx_n <= sizeof tx_sent && !memcmp(out, tx_sent + tx_n - n, n)
        && only_rows(tx_sent, (uint16_t)(tx_n - n));
    if (ok && tx_n > n)
        memcpy(fake.rows, tx_sent, (size_t)(tx_n - n) < sizeof fake.rows ? (size_t)(tx_n - n)
                                                                       : sizeof fake.rows);
    fake.rows_len = (uint16_t)(tx_n - n);
    tx_n = 0;
    return ok;
}
