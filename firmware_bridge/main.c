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

int main(void)
{
    bus_init();
    link_init(&link);
    uart_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (;;) {
        cli();
        if (rx_head == rx_tail) {
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
    }
}
