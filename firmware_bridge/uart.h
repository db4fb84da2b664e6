/* The byte transport under the link layer: the ATmega328P's USART0 (uart_avr.c) in the
 * firmware, a fake in the host-side C tests (tests/fake_bus.c supplies link_tx_byte and
 * link_rx_pending).  link.c and main.c both use it; neither calls into the other for it. */
#ifndef UART_H
#define UART_H
#include <stdint.h>

/* Every byte of a reply frame goes through here, in order, as soon as it is known (the
 * firmware waits for the transmitter, then hands it the byte); link_feed then returns the
 * same frame. */
void link_tx_byte(uint8_t b);

/* 1 when a byte from the host waits in the receive buffer (it ends a recording and a
 * WAIT_STATUS).  Always inlined in the firmware: the main loop asks twice per received byte,
 * and as a call (GCC -Os makes it one, even static inline, once WAIT_STATUS asked too) it cost
 * 1.3 us a byte: RDRP at 1 Mbaud 298 -> 308 us, LTRJ(6)+STT 847 -> 897 us. */
#ifdef __AVR__
extern volatile uint8_t uart_rx_head, uart_rx_tail;
static inline __attribute__((always_inline)) uint8_t link_rx_pending(void)
{
    return uart_rx_head != uart_rx_tail;
}
#else
uint8_t link_rx_pending(void);
#endif
/* The oldest waiting byte, left in the buffer / taken out (a recording matches FAILSAFE_FEED
 * byte by byte: a byte that does not match stays to be read as usual); only when pending. */
uint8_t link_rx_peek(void);
void link_rx_skip(void);

/* Firmware only (uart_avr.c). */
void uart_init(void);          /* 8N1 at BAUD, double speed, receive interrupt on */
uint8_t uart_rx_take(void);    /* the oldest waiting byte; only when link_rx_pending() */
/* Wait until the last byte has left the line, then switch to divisor UBRR `ubrr`; returns the
 * divisor it replaced (SET_BAUD's way back). */
uint16_t uart_switch(uint16_t ubrr);
void uart_set_ubrr(uint16_t ubrr);

#endif
