// board.c - the firmware-in-the-loop harness (see board.h for what it models and why).
//
// Everything here runs on emulated time: cycle timers registered with simavr fire at exact
// cycles (Timer1 BOTTOM and compare, the next byte on the RX line, the end of a run), so a run is
// the same whatever the host's speed.

#include "board.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <avr_adc.h>
#include <avr_eeprom.h>
#include <avr_ioport.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_cycle_timers.h>
#include <sim_elf.h>
#include <sim_hex.h>
#include <sim_io.h>
#include <sim_irq.h>

// ATmega2560 data-space addresses (datasheet, register summary).
enum {
    REG_DDRB = 0x24,
    REG_PORTB = 0x25,
    REG_TCCR1A = 0x80,
    REG_TCCR1B = 0x81,
    REG_TCNT1L = 0x84,
    REG_TCNT1H = 0x85,
    REG_ICR1L = 0x86,
    REG_ICR1H = 0x87,
    REG_OCR1AL = 0x88,
    REG_OCR1AH = 0x89,
    REG_UCSR0B = 0xC1,
    OC1A_BIT = 5, // PB5, Arduino pin 11
    RXEN0_BIT = 4,
};

#define RX_CAP (1u << 16)
#define TX_CAP (1u << 16)
#define PULSE_CAP (1u << 12)
#define EDGE_CAP (1u << 16)
#define MAX_PINS 8
#define RX_HW_BUFFER 3
#define PROFILE_WORDS (1u << 17) // 256 KiB of flash in 16-bit words
#define PROFILE_MASK (PROFILE_WORDS - 1) // the USART holds 2 received bytes plus one in the shift register

typedef struct {
    gb_board_t* board;
    uint8_t index;
} pin_hook_t;

struct gb_board {
    avr_t* avr;
    avr_io_t io; // our reset hook, registered as an IO module
    avr_uart_t* uart0;
    elf_firmware_t fw;

    // RX line (host -> board): a ring of bytes waiting for their frame time.
    uint8_t rx[RX_CAP];
    size_t rx_head, rx_count;
    uint64_t rx_last; // cycle the last queued byte completes
    uint64_t rx_bytes;
    uint32_t rx_overruns, rx_ignored;

    // TX (board -> host)
    gb_tx_t tx[TX_CAP];
    size_t tx_head, tx_count;
    uint64_t tx_bytes;

    // Timer1 / OC1A model
    int t1_running;
    int t1_mode;
    uint32_t t1_prescale;
    uint64_t t1_base; // cycle of a BOTTOM (TCNT1 == 0)
    int pulse_active;
    gb_pulse_t pulse; // the pulse in flight
    gb_pulse_t last_pulse;
    gb_pulse_t pulses[PULSE_CAP];
    size_t pulse_head, pulse_count;
    uint32_t n_pulses, pulse_faults;

    // watched pins
    pin_hook_t pin_hooks[MAX_PINS];
    int n_pins;
    gb_edge_t edges[EDGE_CAP];
    size_t edge_head, edge_count;

    uint64_t instructions, sleep_cycles;
    uint32_t* profile; // cycles spent at each flash word address (NULL: not profiling)
    uint32_t resets, dropped, log_errors;
    uint16_t sp_min;
    char last_log[256];
};

// ---- logging: simavr's logger is global; the board is found through avr->custom.data ------

static void board_logger(avr_t* avr, const int level, const char* format, va_list ap) {
    if (level > LOG_WARNING) return;
    gb_board_t* b = avr ? (gb_board_t*)avr->custom.data : NULL;
    if (!b) return;
    b->log_errors++;
    vsnprintf(b->last_log, sizeof b->last_log, format, ap);
}

// ---- rings ------------------------------------------------------------------------------------

#define RING_PUSH(b, ring, head, count, cap, value)                                             \
    do {                                                                                       \
        if ((b)->count == (cap)) {                                                             \
            (b)->head = ((b)->head + 1) % (cap);                                               \
            (b)->count--;                                                                      \
            (b)->dropped++;                                                                    \
        }                                                                                      \
        (b)->ring[((b)->head + (b)->count) % (cap)] = (value);                                 \
        (b)->count++;                                                                          \
    } while (0)

#define RING_READ(b, ring, head, count, cap, out, n)                                            \
    do {                                                                                       \
        size_t k_ = 0;                                                                         \
        while (k_ < (n) && (b)->count > 0) {                                                   \
            (out)[k_++] = (b)->ring[(b)->head];                                                \
            (b)->head = ((b)->head + 1) % (cap);                                               \
            (b)->count--;                                                                      \
        }                                                                                      \
        return k_;                                                                             \
    } while (0)

// ---- Timer1 and the servo pulse ---------------------------------------------------------------

static uint16_t reg16(avr_t* avr, int lo) { return (uint16_t)(avr->data[lo] | (avr->data[lo + 1] << 8)); }

static int t1_wgm(avr_t* avr) {
    return ((avr->data[REG_TCCR1B] >> 3) & 3) << 2 | (avr->data[REG_TCCR1A] & 3);
}

// TOP of the fast PWM modes (5, 6, 7, 14, 15); 0 for any other mode.
static uint32_t t1_top(avr_t* avr, int mode) {
    switch (mode) {
    case 5: return 0xFF;
    case 6: return 0x1FF;
    case 7: return 0x3FF;
    case 14: return reg16(avr, REG_ICR1L);
    case 15: return reg16(avr, REG_OCR1AL);
    default: return 0;
    }
}

static void record_pulse(gb_board_t* b, gb_pulse_t p) {
    b->last_pulse = p;
    b->n_pulses++;
    RING_PUSH(b, pulses, pulse_head, pulse_count, PULSE_CAP, p);
}

static avr_cycle_count_t t1_compare(avr_t* avr, avr_cycle_count_t when, void* param) {
    (void)avr;
    (void)when;
    gb_board_t* b = (gb_board_t*)param;
    if (b->pulse_active) {
        b->pulse_active = 0;
        record_pulse(b, b->pulse);
    }
    return 0;
}

// BOTTOM: OCR1A's buffer is latched, OC1A is set (non-inverting fast PWM) and cleared at the
// compare match (OCR1A + 1) ticks later.
static avr_cycle_count_t t1_bottom(avr_t* avr, avr_cycle_count_t when, void* param) {
    gb_board_t* b = (gb_board_t*)param;
    int mode = t1_wgm(avr);
    uint32_t top = t1_top(avr, mode);
    if (!b->t1_running || top == 0) return 0;
    uint64_t period = (uint64_t)(top + 1) * b->t1_prescale;
    b->t1_base = when;
    int com = (avr->data[REG_TCCR1A] >> 6) & 3;
    int out = (avr->data[REG_DDRB] >> OC1A_BIT) & 1;
    int port = (avr->data[REG_PORTB] >> OC1A_BIT) & 1;
    if (b->pulse_active) { // a compare that never came (cannot happen below TOP): close it here
        b->pulse_active = 0;
        record_pulse(b, b->pulse);
    }
    if (out && com == 2) {
        uint16_t ocr = reg16(avr, REG_OCR1AL);
        uint64_t ticks = ocr >= top ? top + 1 : (uint64_t)ocr + 1;
        b->pulse.start = when;
        b->pulse.width = (uint32_t)(ticks * b->t1_prescale);
        b->pulse.ocr = ocr;
        b->pulse.top = (uint16_t)top;
        b->pulse_active = 1;
        avr_cycle_timer_register(avr, b->pulse.width, t1_compare, b);
    } else if (out && (com == 3 || (com == 0 && port) || (com == 1 && mode != 15 && port))) {
        // inverted output, or the pin held high by PORTB: not a servo pulse
        b->pulse_faults++;
    }
    return when + period;
}

static void t1_restart(gb_board_t* b) {
    avr_t* avr = b->avr;
    avr_cycle_timer_cancel(avr, t1_bottom, b);
    int cs = avr->data[REG_TCCR1B] & 7;
    static const uint32_t prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    b->t1_prescale = prescale[cs];
    b->t1_mode = t1_wgm(avr);
    b->t1_running = b->t1_prescale != 0;
    if (!b->t1_running) return;
    uint32_t top = t1_top(avr, b->t1_mode);
    uint16_t tcnt = reg16(avr, REG_TCNT1L);
    if (top == 0) return; // not a PWM mode: no pulses to model
    // the next BOTTOM comes after the counter passes TOP
    uint64_t to_bottom = ((uint64_t)top + 1 - (tcnt <= top ? tcnt : top)) * b->t1_prescale;
    if (tcnt == 0) { // starting at BOTTOM: this is one
        to_bottom = 0;
    }
    b->t1_base = avr->cycle + to_bottom;
    if (to_bottom == 0)
        avr_cycle_timer_register(avr, 1, t1_bottom, b); // at once (1 cycle: after this write)
    else
        avr_cycle_timer_register(avr, to_bottom, t1_bottom, b);
}

static void on_tccr1b(avr_t* avr, avr_io_addr_t addr, uint8_t v, void* param) {
    (void)addr;
    gb_board_t* b = (gb_board_t*)param;
    uint32_t cs = v & 7;
    if ((cs != 0) != (b->t1_running != 0) || (cs && t1_wgm(avr) != b->t1_mode)) t1_restart(b);
}

static void on_tcnt1l(avr_t* avr, avr_io_addr_t addr, uint8_t v, void* param) {
    (void)avr;
    (void)addr;
    (void)v;
    gb_board_t* b = (gb_board_t*)param;
    if (b->t1_running) t1_restart(b); // a write to TCNT1 moves BOTTOM
}

// ---- UART ---------------------------------------------------------------------------------------

// Bytes in simavr's receive FIFO (its accessors are file-static in avr_uart.c).
static unsigned fifo_used(const uart_fifo_t* f) {
    return ((unsigned)f->write + uart_fifo_fifo_size - f->read) & (uart_fifo_fifo_size - 1);
}

static avr_cycle_count_t rx_next_byte(avr_t* avr, avr_cycle_count_t when, void* param) {
    gb_board_t* b = (gb_board_t*)param;
    if (b->rx_count == 0) return 0;
    uint8_t byte = b->rx[b->rx_head];
    b->rx_head = (b->rx_head + 1) % RX_CAP;
    b->rx_count--;
    avr_uart_t* u = b->uart0;
    if (!((avr->data[REG_UCSR0B] >> RXEN0_BIT) & 1)) {
        b->rx_ignored++;
    } else if (fifo_used(&u->input) >= RX_HW_BUFFER) {
        b->rx_overruns++; // data overrun: the firmware did not read the receiver in time
    } else {
        avr_raise_irq(u->io.irq + UART_IRQ_INPUT, byte);
        b->rx_bytes++;
    }
    return b->rx_count ? when + u->cycles_per_byte : 0;
}

static void on_tx(struct avr_irq_t* irq, uint32_t value, void* param) {
    (void)irq;
    gb_board_t* b = (gb_board_t*)param;
    gb_tx_t t = {b->avr->cycle, (uint8_t)value};
    b->tx_bytes++;
    RING_PUSH(b, tx, tx_head, tx_count, TX_CAP, t);
}

// ---- pins ---------------------------------------------------------------------------------------

static void on_pin(struct avr_irq_t* irq, uint32_t value, void* param) {
    (void)irq;
    pin_hook_t* h = (pin_hook_t*)param;
    gb_board_t* b = h->board;
    gb_edge_t e = {b->avr->cycle, h->index, (uint8_t)(value & 1)};
    RING_PUSH(b, edges, edge_head, edge_count, EDGE_CAP, e);
}

// ---- reset --------------------------------------------------------------------------------------

static void on_reset(avr_io_t* io) {
    gb_board_t* b = (gb_board_t*)((char*)io - offsetof(gb_board_t, io));
    b->resets++;
    if (b->pulse_active) { // the pin is released mid-pulse: the servo sees a runt
        b->pulse_active = 0;
        b->pulse.width = (uint32_t)(b->avr->cycle - b->pulse.start);
        b->pulse_faults++;
        record_pulse(b, b->pulse);
    }
    b->t1_running = 0;
    b->t1_mode = -1;
    // simavr cancelled every cycle timer: the line keeps delivering what is queued
    if (b->rx_count) avr_cycle_timer_register(b->avr, b->uart0->cycles_per_byte, rx_next_byte, b);
}

// ---- public API ---------------------------------------------------------------------------------

int gb_abi_version(void) { return GB_ABI_VERSION; }

static int ends_with(const char* s, const char* tail) {
    size_t n = strlen(s), m = strlen(tail);
    return n >= m && strcmp(s + n - m, tail) == 0;
}

static void no_sleep(avr_t* avr, avr_cycle_count_t how_long) {
    (void)avr; // simavr's default sleeps in wall time to pace a sleeping CPU; emulated time is ours
    (void)how_long;
}

gb_board_t* gb_open(const char* image_path, uint32_t freq_hz, char* err, size_t err_len) {
    avr_global_logger_set(board_logger);
    gb_board_t* b = (gb_board_t*)calloc(1, sizeof *b);
    if (!b) {
        snprintf(err, err_len, "out of memory");
        return NULL;
    }
    uint8_t* hex = NULL;
    uint32_t hex_size = 0, hex_start = 0;
    if (ends_with(image_path, ".hex")) {
        hex = read_ihex_file(image_path, &hex_size, &hex_start);
        if (!hex) {
            snprintf(err, err_len, "cannot read Intel hex image %s", image_path);
            free(b);
            return NULL;
        }
    } else if (elf_read_firmware(image_path, &b->fw) != 0) {
        snprintf(err, err_len, "cannot read ELF image %s", image_path);
        free(b);
        return NULL;
    }
    avr_t* avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) {
        snprintf(err, err_len, "this simavr has no atmega2560 core");
        free(hex);
        free(b);
        return NULL;
    }
    b->avr = avr;
    avr_init(avr);
    avr->custom.data = b;
    avr->log = LOG_WARNING;
    avr->frequency = freq_hz;
    avr->sleep = no_sleep;
    if (hex) {
        avr_loadcode(avr, hex, hex_size, hex_start);
        free(hex);
    } else {
        b->fw.frequency = freq_hz;
        avr_load_firmware(avr, &b->fw);
    }
    avr->frequency = freq_hz;
    avr->vcc = avr->avcc = avr->aref = 5000; // mV

    for (avr_io_t* io = avr->io_port; io; io = io->next)
        if (io->kind && strcmp(io->kind, "uart") == 0 && ((avr_uart_t*)io)->name == '0')
            b->uart0 = (avr_uart_t*)io;
    if (!b->uart0) {
        snprintf(err, err_len, "the atmega2560 core has no UART0");
        gb_close(b);
        return NULL;
    }
    uint32_t flags = 0; // no console echo of UDR, no wall-clock sleep while polling UCSR0A
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(b->uart0->io.irq + UART_IRQ_OUTPUT, on_tx, b);

    avr_register_io_write(avr, REG_TCCR1B, on_tccr1b, b);
    avr_register_io_write(avr, REG_TCNT1L, on_tcnt1l, b);
    b->t1_mode = -1;

    b->io.kind = "gripper-board";
    b->io.reset = on_reset;
    avr_register_io(avr, &b->io);

    b->sp_min = avr->ramend;
    return b;
}

void gb_close(gb_board_t* b) {
    if (!b) return;
    if (b->avr) {
        b->avr->custom.data = NULL;
        avr_terminate(b->avr);
        free(b->avr);
    }
    free(b->profile);
    free(b);
}

void gb_reset(gb_board_t* b) { avr_reset(b->avr); }

static avr_cycle_count_t run_limit(avr_t* avr, avr_cycle_count_t when, void* param) {
    (void)avr;
    (void)when;
    (void)param;
    return 0; // only bounds a sleeping CPU's jump to the end of the run
}

int gb_run_until(gb_board_t* b, uint64_t cycle) {
    avr_t* avr = b->avr;
    if (avr->cycle < cycle) avr_cycle_timer_register(avr, cycle - avr->cycle, run_limit, b);
    while (avr->cycle < cycle) {
        int state = avr->state;
        if (state != cpu_Running && state != cpu_Sleeping) break;
        uint64_t before = avr->cycle;
        avr_flashaddr_t pc = avr->pc;
        avr->run(avr);
        if (state == cpu_Sleeping) {
            b->sleep_cycles += avr->cycle - before;
        } else {
            b->instructions++;
            if (b->profile) b->profile[(pc >> 1) & PROFILE_MASK] += (uint32_t)(avr->cycle - before);
        }
        uint16_t sp = (uint16_t)(avr->data[R_SPL] | (avr->data[R_SPH] << 8));
        if (sp < b->sp_min) b->sp_min = sp;
    }
    return avr->state;
}

uint64_t gb_cycle(const gb_board_t* b) { return b->avr->cycle; }

int gb_eeprom_write(gb_board_t* b, uint16_t address, const uint8_t* data, uint32_t n) {
    avr_eeprom_desc_t d = {(uint8_t*)data, address, n};
    return avr_ioctl(b->avr, AVR_IOCTL_EEPROM_SET, &d);
}

void gb_set_adc_counts(gb_board_t* b, int channel, uint32_t counts) {
    if (counts > 1023) counts = 1023;
    // simavr converts as floor(mV * 1023 / AVcc): the smallest voltage that reads `counts`
    uint32_t mv = (counts * b->avr->avcc + 1022) / 1023;
    avr_raise_irq(avr_io_getirq(b->avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + channel), mv);
}

size_t gb_rx_write(gb_board_t* b, const uint8_t* data, size_t n) {
    avr_t* avr = b->avr;
    size_t room = RX_CAP - b->rx_count;
    if (n > room) n = room;
    if (n == 0) return 0;
    uint64_t cpb = b->uart0->cycles_per_byte;
    int idle = b->rx_count == 0;
    for (size_t k = 0; k < n; ++k) b->rx[(b->rx_head + b->rx_count + k) % RX_CAP] = data[k];
    b->rx_count += n;
    // A byte is handed to the USART at the start of its frame on the line and becomes readable
    // one frame time later (simavr's receive pump), when its stop bit has arrived.
    if (idle) {
        avr_cycle_timer_register(avr, 1, rx_next_byte, b);
        b->rx_last = avr->cycle + 1;
    }
    b->rx_last += (uint64_t)n * cpb;
    return n;
}

size_t gb_rx_pending(const gb_board_t* b) { return b->rx_count; }
uint64_t gb_rx_last_cycle(const gb_board_t* b) { return b->rx_last; }

size_t gb_tx_read(gb_board_t* b, gb_tx_t* out, size_t cap) {
    RING_READ(b, tx, tx_head, tx_count, TX_CAP, out, cap);
}

size_t gb_pulses_read(gb_board_t* b, gb_pulse_t* out, size_t cap) {
    RING_READ(b, pulses, pulse_head, pulse_count, PULSE_CAP, out, cap);
}

gb_pulse_t gb_last_pulse(const gb_board_t* b) { return b->last_pulse; }

int gb_watch_pin(gb_board_t* b, char port, int bit) {
    if (b->n_pins >= MAX_PINS || bit < 0 || bit > 7) return -1;
    avr_irq_t* irq = avr_io_getirq(b->avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
    if (!irq) return -1;
    pin_hook_t* h = &b->pin_hooks[b->n_pins];
    h->board = b;
    h->index = (uint8_t)b->n_pins;
    avr_irq_register_notify(irq, on_pin, h);
    return b->n_pins++;
}

size_t gb_edges_read(gb_board_t* b, gb_edge_t* out, size_t cap) {
    RING_READ(b, edges, edge_head, edge_count, EDGE_CAP, out, cap);
}

void gb_stats(const gb_board_t* b, gb_stats_t* out) {
    memset(out, 0, sizeof *out);
    out->cycle = b->avr->cycle;
    out->instructions = b->instructions;
    out->sleep_cycles = b->sleep_cycles;
    out->rx_bytes = b->rx_bytes;
    out->tx_bytes = b->tx_bytes;
    out->rx_overruns = b->rx_overruns;
    out->rx_ignored = b->rx_ignored;
    out->resets = b->resets;
    out->pulses = b->n_pulses;
    out->pulse_faults = b->pulse_faults;
    out->dropped = b->dropped;
    out->log_errors = b->log_errors;
    out->cycles_per_byte = (uint32_t)b->uart0->cycles_per_byte;
    out->sp_min = b->sp_min;
    out->ramend = b->avr->ramend;
    out->state = b->avr->state;
    out->timer1_mode = b->t1_mode;
}

int gb_profile(gb_board_t* b, int enable) {
    if (enable && !b->profile) {
        b->profile = (uint32_t*)calloc(PROFILE_WORDS, sizeof(uint32_t));
        if (!b->profile) return -1;
    } else if (!enable && b->profile) {
        free(b->profile);
        b->profile = NULL;
    }
    return 0;
}

size_t gb_profile_read(gb_board_t* b, uint32_t* out, size_t cap) {
    if (!b->profile) return 0;
    size_t n = cap < PROFILE_WORDS ? cap : PROFILE_WORDS;
    memcpy(out, b->profile, n * sizeof(uint32_t));
    memset(b->profile, 0, PROFILE_WORDS * sizeof(uint32_t));
    return n;
}

void gb_reset_sp_min(gb_board_t* b) { b->sp_min = b->avr->ramend; }

const char* gb_last_log(const gb_board_t* b) { return b->last_log; }
