#include <string.h>
#include "../bus.h"
#include "../link.h"
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
 * that exactly the frame link_feed returned went out, in order */
static uint8_t tx_sent[1024];
static uint16_t tx_n;

void link_tx_byte(uint8_t b)
{
    if (tx_n < sizeof tx_sent)
        tx_sent[tx_n] = b;
    tx_n++;
}

int fake_tx_verify(const uint8_t *out, uint16_t n)
{
    int ok = tx_n == n && !memcmp(out, tx_sent, n);
    tx_n = 0;
    return ok;
}
