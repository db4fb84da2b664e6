/* The bus primitives the link layer runs programs with.
 *
 * bus_avr.c implements them on the ATmega328P's ports (the pin map is generated into
 * lm629_tables.h); the host-side C tests implement them over a fake chip, so that link.c, the
 * frame parser and the request dispatcher are tested and fuzzed on the build machine too. */
#ifndef BUS_H
#define BUS_H
#include <stdint.h>

uint8_t bus_read_status(void);          /* /CS /PS /RD low: the status byte (no busy check) */
void bus_write_command(uint8_t cmd);    /* /CS /PS low, /WR strobe */
void bus_write_data(uint8_t byte);      /* /CS low /PS high, /WR strobe */
uint8_t bus_read_data(void);            /* /CS low /PS high, /RD strobe */
void bus_reset_pulse(void);             /* /RST low for >= 8 chip clocks */
void bus_select(uint8_t chip);          /* the chip (its /CS) the following strobes address */
uint8_t bus_hi(void);                   /* the selected chip's HI line, 0 or 1 */
void bus_wait_us(uint16_t us);          /* at least `us` microseconds */
uint16_t bus_ticks(void);              /* the free-running clock: 4 us ticks, wraps at 16 bits */
void bus_timer_start(void);             /* start the busy-timeout stopwatch */
uint8_t bus_timer_elapsed(uint16_t us); /* 1 once `us` microseconds have passed since start */
/* poll the status byte back to back until busy is clear (1) or `timeout_us` has passed (0);
 * *status: the last status read */
uint8_t bus_wait_not_busy(uint16_t timeout_us, uint8_t *status);

#endif
