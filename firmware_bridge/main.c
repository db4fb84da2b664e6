/* LM629 serial bridge firmware: ATmega328P at 16 MHz (Arduino Uno / Nano).
 *
 * Bytes from the USB serial link are collected by the receive interrupt into a ring buffer;
 * the main loop feeds them to the link layer (link.c), which answers each good request with
 * one reply frame, sent byte by byte through link_tx_byte (transmitter polled) while it is
 * still being encoded.  The CPU sleeps (idle mode) while no byte is waiting: the receive
 * interrupt wakes it. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include "bus.h"
#include "link.h"

#ifndef BAUD
#define BAUD 115200UL
#endif
/* double speed (U2X) divisor, rounded: 115200 -> 16 (2.1% fast, as the Arduino core),
 * 1000000 -> 1 (exact) */
#define UBRR_VALUE ((F_CPU + 4UL * BAUD) / (8UL * BAUD) - 1UL)

void bus_init(void);

#define RX_SIZE 128u /* power of two */
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static link_t link;

ISR(USART_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1u) & (RX_SIZE - 1u));
    if (next != rx_tail) { /* full: drop; the frame fails its CRC and the host retries */
        rx_buf[rx_head] = b;
        rx_head = next;
    }
}

uint8_t link_rx_pending(void) { return rx_head != rx_tail; }

static void uart_init(void)
{
    UCSR0A = (1 << U2X0); /* U2X before UBRR: simavr recomputes the rate on UBRR0L writes */
    UBRR0H = (uint8_t)(UBRR_VALUE >> 8);
    UBRR0L = (uint8_t)UBRR_VALUE;
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00); /* 8N1 */
    UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);
}

/* the transmitter polled: at 1 Mbaud a byte takes 176 cycles, less than an interrupt's
 * overhead would leave to spare */
void link_tx_byte(uint8_t b)
{
    while (!(UCSR0A & (1 << UDRE0)))
        ;
    UDR0 = b;
}

/* SET_BAUD (link.c answered it, at the old rate): switch once the reply has left (the
 * transmitter's buffer empty, then a byte time for its shift register), and go back when no
 * good frame comes at the new rate within LINK_BAUD_WINDOW_MS (a USB serial chip that cannot
 * do it): the host goes back too, and finds the bridge where it left it. */
static uint16_t ubrr_before;      /* the rate to go back to */
static uint8_t on_probation;      /* switched, no good frame at the new rate yet */
static link_count_t frames_before;
static uint32_t probation_ticks;  /* Timer1 ticks (4 us) since the switch */
static uint16_t last_tick;

static void set_ubrr(uint16_t ubrr)
{
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr; /* simavr recomputes the rate on this write */
}

static void switch_baud(uint16_t div)
{
    while (!(UCSR0A & (1 << UDRE0)))
        ;
    uint16_t ubrr = (uint16_t)((UBRR0H << 8) | UBRR0L);
    bus_wait_us((uint16_t)(5u * (ubrr + 1u) + 4u)); /* a byte of 10 bits: 8 x (UBRR+1) / 16 MHz each */
    ubrr_before = ubrr;
    set_ubrr((uint16_t)(div - 1u));
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
        set_ubrr(ubrr_before);
        on_probation = 0;
    }
}

int main(void)
{
    bus_init();
    link_init(&link);
    uart_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (;;) {
        if (on_probation)
            probation();
        cli();
        if (rx_head == rx_tail) {
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
        uint8_t b = rx_buf[rx_tail];
        rx_tail = (uint8_t)((rx_tail + 1u) & (RX_SIZE - 1u));
        const uint8_t *out;
        link_feed(&link, b, &out); /* a reply goes out from inside, byte by byte */
        if (link.baud_div) {
            uint16_t div = link.baud_div;
            link.baud_div = 0;
            switch_baud(div);
        }
    }
}
