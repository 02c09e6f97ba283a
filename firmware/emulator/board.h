// board.h - the firmware-in-the-loop harness: the compiled Mega 2560 image under simavr.
//
// A small C library over libsimavr (Debian's libsimavr-dev) that runs firmware/build-mega/
// gripper.elf on an emulated ATmega2560 at 16 MHz and exposes what the rig around a real board
// sees and does:
//
//   UART0     bytes to the board are put on the RX line one frame time apart (the line rate the
//             firmware configured); bytes the board writes to UDR0 are collected with their cycle.
//   ADC       the potentiometer: the voltage on an ADC channel, set in counts of the 10-bit
//             converter (AVcc = 5 V reference).
//   Timer1    the servo pulse on OC1A (pin 11, PB5), modelled from the registers as the
//             datasheet specifies for fast PWM with TOP = ICR1 (mode 14): OCR1A is double-
//             buffered and latched at BOTTOM, the pin is set at BOTTOM and cleared at the compare
//             match, so a pulse is (OCR1A + 1) timer ticks long. (simavr 1.6 applies an OCR1A
//             write immediately, mid-period, which a real timer never does.)
//   pins      edges of watched output pins with their cycle (the firmware's timing marks).
//   stack     the lowest stack pointer reached, for the stack high-water mark.
//
// Emulated time (avr->cycle at 16 MHz) is the only clock: a run is deterministic and goes as
// fast as the host CPU allows. The Python side is gripper_env/hardware/mega2560.py (ctypes).
// Build: firmware/emulator/build.sh.

#ifndef GRIPPER_BOARD_H
#define GRIPPER_BOARD_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define GB_ABI_VERSION 1

typedef struct gb_board gb_board_t;

typedef struct {
    uint64_t start; // cycle the pin went high (a Timer1 BOTTOM)
    uint32_t width; // cycles high
    uint16_t ocr;   // the latched OCR1A
    uint16_t top;   // ICR1 for this period
} gb_pulse_t;

typedef struct {
    uint64_t cycle;
    uint8_t pin;   // index returned by gb_watch_pin
    uint8_t level; // level after the edge
} gb_edge_t;

typedef struct {
    uint64_t cycle; // cycle the firmware wrote the byte to UDR0
    uint8_t byte;
} gb_tx_t;

typedef struct {
    uint64_t cycle;        // current emulated cycle
    uint64_t instructions; // instructions executed
    uint64_t sleep_cycles; // cycles the CPU spent in a sleep mode
    uint64_t rx_bytes;     // bytes delivered to the UART receiver
    uint64_t tx_bytes;     // bytes the firmware transmitted
    uint32_t rx_overruns;  // bytes lost: the receiver already held 2 unread bytes (DOR)
    uint32_t rx_ignored;   // bytes that arrived while the receiver was disabled (boot, reset)
    uint32_t resets;       // resets of any cause after power-on (external, watchdog)
    uint32_t pulses;       // servo pulses generated
    uint32_t pulse_faults; // Timer1 periods whose OC1A output was not a plain PWM pulse
    uint32_t dropped;      // records lost because the caller did not read them in time
    uint32_t log_errors;   // simavr warnings and errors
    uint32_t cycles_per_byte; // UART frame time (cycles) at the configured baud rate
    uint16_t sp_min;       // lowest stack pointer seen
    uint16_t ramend;       // highest SRAM address
    int32_t state;         // simavr cpu state (cpu_Running, cpu_Sleeping, cpu_Crashed...)
    int32_t timer1_mode;   // WGM of Timer1 when it was started, -1 before
} gb_stats_t;

// Load an ELF (or Intel hex) image into a fresh ATmega2560 at freq_hz. NULL on failure, with the
// reason in err.
gb_board_t* gb_open(const char* image_path, uint32_t freq_hz, char* err, size_t err_len);
void gb_close(gb_board_t* b);
int gb_abi_version(void);

// Pull the reset pin: the firmware restarts; queued RX bytes keep arriving on the line.
void gb_reset(gb_board_t* b);
// Run until the cycle counter reaches `cycle`. Returns the simavr cpu state (see gb_stats_t).
int gb_run_until(gb_board_t* b, uint64_t cycle);
uint64_t gb_cycle(const gb_board_t* b);

// EEPROM contents (e.g. the board id at address 0).
int gb_eeprom_write(gb_board_t* b, uint16_t address, const uint8_t* data, uint32_t n);
// Put a voltage that converts to `counts` (0..1023 with the AVcc reference) on ADC `channel`.
void gb_set_adc_counts(gb_board_t* b, int channel, uint32_t counts);

// Queue bytes on the line to the board. Returns how many were accepted (the line buffer holds
// 64 KiB; the rest is refused).
size_t gb_rx_write(gb_board_t* b, const uint8_t* data, size_t n);
size_t gb_rx_pending(const gb_board_t* b);
// Cycle at which the last byte queued so far has completely arrived (0 if none ever).
uint64_t gb_rx_last_cycle(const gb_board_t* b);

size_t gb_tx_read(gb_board_t* b, gb_tx_t* out, size_t cap);
size_t gb_pulses_read(gb_board_t* b, gb_pulse_t* out, size_t cap);
// The last pulse generated (start 0 if none yet) and whether OC1A is driving pulses now.
gb_pulse_t gb_last_pulse(const gb_board_t* b);

// Record edges of an output pin (port 'A'..'L', bit 0..7); returns its index or -1.
int gb_watch_pin(gb_board_t* b, char port, int bit);
size_t gb_edges_read(gb_board_t* b, gb_edge_t* out, size_t cap);

void gb_stats(const gb_board_t* b, gb_stats_t* out);
// Cycle profile: count the cycles spent at each flash word address (enable 1/0), and read it
// (words 0..cap-1; reading clears it).
int gb_profile(gb_board_t* b, int enable);
size_t gb_profile_read(gb_board_t* b, uint32_t* out, size_t cap);
// Reset the stack high-water mark (after boot, to measure one phase).
void gb_reset_sp_min(gb_board_t* b);
const char* gb_last_log(const gb_board_t* b);

#ifdef __cplusplus
}
#endif

#endif // GRIPPER_BOARD_H
