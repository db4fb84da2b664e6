/* LM629 serial bridge firmware: ATmega328P at 16 MHz (Arduino Uno / Nano).
 *
 * Bytes from the USB serial link wait in the UART's receive buffer (uart_avr.c); the main
 * loop feeds them to the link layer (link.c), which answers each good request with one reply
 * frame, sent byte by byte through link_tx_byte (transmitter polled) while it is still being
 * encoded.  The CPU sleeps (idle mode) while no byte is waiting: the receive
 * interrupt wakes it, and so do Timer1's (twice per wrap, for the clock link_clock folds into
 * 32 bits, and at the failsafe's expiry).  Timer1 keeps counting as it did (clk/64, never
 * written): RECORD's samples read it as before, the interrupts only wake. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include "bus.h"
#include "link.h"
#include "uart.h"

void bus_init(void);

static link_t link;

/* SET_BAUD (link.c answered it, at the old rate): switch once the reply has left (the
 * transmitter's buffer empty, then a byte time for its shift register), and go back when no
 * good frame comes at the new rate within LINK_BAUD_WINDOW_MS (a USB serial chip that cannot
 * do it): the host goes back too, and finds the bridge where it left it. */
static uint16_t ubrr_before;      /* the rate to go back to */
static uint8_t on_probation;      /* switched, no good frame at the new rate yet */
static link_count_t frames_before;
static uint32_t probation_ticks;  /* Timer1 ticks (4 us) since the switch */
static uint16_t last_tick;

static void switch_baud(uint16_t div)
{
    ubrr_before = uart_switch((uint16_t)(div - 1u));
    on_probation = 1;
    frames_before = link.frames;
    probation_ticks = 0;
    last_tick = TCNT1;
}

static void probation(void)
{
    if (link.frames != frames_before) {
        on_probation = 0; /* a good frame at the new rate: it works */
        return;
    }
    uint16_t now = TCNT1;
    probation_ticks += (uint16_t)(now - last_tick);
    last_tick = now;
    if (probation_ticks >= LINK_BAUD_WINDOW_MS * 250UL) {
        uart_set_ubrr(ubrr_before);
        on_probation = 0;
    }
}

EMPTY_INTERRUPT(TIMER1_OVF_vect)
EMPTY_INTERRUPT(TIMER1_COMPA_vect)
EMPTY_INTERRUPT(TIMER1_COMPB_vect)

int main(void)
{
    bus_init();
    link_init(&link);
    uart_init();
    OCR1A = 0x8000; /* with the overflow: a wake every half wrap, 131 ms */
    TIMSK1 = (1 << TOIE1) | (1 << OCIE1A) | (1 << OCIE1B);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (;;) {
        if (on_probation)
            probation();
        if (!link_rx_pending()) { /* between bursts: the bytes of a frame go first */
            link_poll();
            OCR1B = link_failsafe_wake(); /* wakes at the expiry (or earlier: harmless) */
        }
        cli();
        if (!link_rx_pending()) {
            if (link.prof_n) { /* a shaped move's pieces are timed by polling Timer1 */
                sei();
                link_idle(&link);
                continue;
            }
            if (on_probation) { /* the window is timed by polling Timer1: no sleep */
                sei();
                continue;
            }
#ifdef BRIDGE_NO_SLEEP
            sei(); /* one instruction runs before a pending interrupt is taken: */
            __asm__ __volatile__("nop"); /* the nop lets the receive interrupt in */
            continue;
#endif
            sleep_enable();
            sei();
            sleep_cpu(); /* the receive interrupt wakes us */
            sleep_disable();
            continue;
        }
        sei();
        uint8_t b = uart_rx_take();
        const uint8_t *out;
        link_feed(&link, b, &out); /* a reply goes out from inside, byte by byte */
        if (!b)
            link_poll(); /* at every delimiter too: a line that never goes quiet */
        if (link.baud_div) {
            uint16_t div = link.baud_div;
            link.baud_div = 0;
            switch_baud(div);
        }
    }
}
