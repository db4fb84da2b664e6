/* A scripted chip behind bus.h, for the host-side tests and the fuzz run of link.c. */
#ifndef FAKE_BUS_H
#define FAKE_BUS_H
#include <stdint.h>
typedef struct {
    uint8_t status;       /* status byte returned when not busy */
    uint8_t hi;           /* HI line */
    uint8_t selected;     /* chip select of the last bus_select */
    uint8_t selects[8];   /* the chips bus_select was called with, in order */
    uint16_t n_selects;
    uint8_t script[16];   /* if n_script: status reads return these in turn, the last repeats */
    uint16_t n_script, script_at;
    uint16_t busy_polls;  /* the next this-many status reads show busy (bit 0 set) */
    uint16_t data[64];    /* words the chip hands out, high byte first */
    uint16_t n_data, data_at, byte_phase;
    uint8_t log[1024];    /* 'C' cmd, 'W' byte, 'R', 'S', 'X' reset, 'T' wait(hi,lo) ... */
    uint16_t log_len;
    uint32_t elapsed_us;  /* simulated time since bus_timer_start; a status read costs 1 us */
    uint32_t total_polls, resets, waited_us;
    uint32_t ticks;                 /* bus_ticks: one more at each read */
    uint32_t rx_polls, rx_pending_after; /* link_rx_pending: 1 after this many polls */
    uint8_t rows[1024];             /* the RECORD_ROW frames sent before the last reply */
    uint16_t rows_len;
    uint32_t rows_seen;
} fake_bus_t;
extern fake_bus_t fake;
void fake_reset(void);
/* after each reply: 1 if exactly its bytes went through link_tx_byte, in order (then forgets them) */
int fake_tx_verify(const uint8_t *out, uint16_t n);
#endif
