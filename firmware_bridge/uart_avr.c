/* USART0 of the ATmega328P: the bridge's serial link to the host (uart.h).
 *
 * Bytes are collected by the receive interrupt into a ring buffer, which the main loop drains
 * into the link layer; replies are sent with the transmitter polled. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include "bus.h"
#include "uart.h"

#ifndef BAUD
#define BAUD 115200UL
#endif
/* double speed (U2X) divisor, rounded: 115200 -> 16 (2.1% fast, as the Arduino core),
 * 1000000 -> 1 (exact) */
#define UBRR_VALUE ((F_CPU + 4UL * BAUD) / (8UL * BAUD) - 1UL)

#define RX_SIZE 128u /* power of two */
static volatile uint8_t rx_buf[RX_SIZE];
volatile uint8_t uart_rx_head, uart_rx_tail; /* uart.h reads them inline: link_rx_pending */

ISR(USART_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((uart_rx_head + 1u) & (RX_SIZE - 1u));
    if (next != uart_rx_tail) { /* full: drop; the frame fails its CRC and the host retries */
        rx_buf[uart_rx_head] = b;
        uart_rx_head = next;
    }
}


uint8_t link_rx_peek(void) { return rx_buf[uart_rx_tail]; }

void link_rx_skip(void) { uart_rx_tail = (uint8_t)((uart_rx_tail + 1u) & (RX_SIZE - 1u)); }

uint8_t uart_rx_take(void)
{
    uint8_t b = rx_buf[uart_rx_tail];
    uart_rx_tail = (uint8_t)((uart_rx_tail + 1u) & (RX_SIZE - 1u));
    return b;
}

void uart_init(void)
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

void uart_set_ubrr(uint16_t ubrr)
{
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr; /* simavr recomputes the rate on this write */
}

/* the transmitter's buffer empty, then a byte time for its shift register */
uint16_t uart_switch(uint16_t ubrr)
{
    while (!(UCSR0A & (1 << UDRE0)))
        ;
    uint16_t before = (uint16_t)((UBRR0H << 8) | UBRR0L);
    bus_wait_us((uint16_t)(5u * (before + 1u) + 4u)); /* a byte of 10 bits: 8 x (UBRR+1) / 16 MHz each */
    uart_set_ubrr(ubrr);
    return before;
}
