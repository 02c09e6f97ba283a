// gripper.ino - Arduino Mega 2560 firmware for the hobby-servo gripper.
//
// The board runs the 1 kHz PID; the host sends gains and references and receives batched
// telemetry over binary frames (firmware/PROTOCOL.md). All protocol, mode and safety logic
// lives in gripper_core.h, which the host tests compile and exercise; this file only touches
// hardware:
//
//   servo      Timer1 fast PWM (mode 14), prescaler 8 -> 0.5 us ticks, TOP 39999 -> 50 Hz,
//              pulse on OC1A = digital pin 11. No Servo library (not packaged on Debian).
//   feedback   potentiometer on A0, one 10-bit conversion (104 us) started by the tick interrupt;
//              its end (the ADC interrupt) makes the tick due, so the CPU never waits for it.
//   schedule   Timer3 CTC interrupt at exactly 1 kHz samples the jaw; loop() runs a due tick
//              first, stops parsing host bytes as soon as one falls due, and sleeps (idle mode)
//              when there is nothing to do. A tick that starts more than 250 us after its
//              measurement is ready is flagged as an overrun.
//   serial     UART0 at 1 000 000 baud (exact at 16 MHz with U2X, UBRR = 1), driven here, not by
//              the core's HardwareSerial: received bytes go into a 256-byte ring from the receive
//              interrupt, and every byte lost before the decoder (ring full, UART overrun or
//              framing error) is counted and drops the frame it belonged to; the device's
//              transmit queue is drained by the data-register-empty interrupt directly (paused
//              while the control path runs), so the control loop never blocks on serial output.
//   watchdog   the AVR hardware watchdog resets a hung board (servo pulses stop on reset).
//   timing     pin 13 (PB7, the LED) is high while a tick computes and updates the servo, pin 12
//              (PB6) while it queues a telemetry frame: a scope (or the simavr harness,
//              firmware/emulator) reads the loop's cycle budget from them.
//
// Serial rate: one TELEMETRY frame of 10 samples is 7 + 10*7 = 77 payload bytes, 81 raw, 83 on
// the wire. At decimation 1 that is 100 frames/s = 8.3 kB/s = 83 kbit/s with 10 bits per byte:
// 72 % of 115200 baud (which is also 2.1 % off at 16 MHz), 8 % of 1 Mbaud.

#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "gripper_core.h"

#ifndef GRIPPER_BAUD
#define GRIPPER_BAUD 1000000UL
#endif

// Set to 0 on boards whose bootloader cannot cope with a watchdog reset (very old Mega
// stk500v2 bootloaders loop forever after one).
#ifndef GRIPPER_USE_HW_WATCHDOG
#define GRIPPER_USE_HW_WATCHDOG 1
#endif

// File-local (static) rather than an anonymous namespace: the Arduino builder generates
// prototypes for .ino functions and handles plain static functions reliably.
static const uint8_t SERVO_PIN = 11;            // OC1A on the Mega 2560 (PB5)
static const uint8_t POT_ADC_CHANNEL = 0;       // A0
static const uint16_t SERVO_FRAME_TICKS = 40000; // 20 ms in 0.5 us ticks
static const uint16_t TICK_TIMER_COUNTS = 2000; // Timer3 at clk/8 = 2 MHz: 1 ms
static const uint16_t OVERRUN_LATE_US = 250;    // a tick starting this late is flagged
static const uint8_t RESYNC_TICKS = 10;         // this far behind: skip ticks instead of bursting
static const uint16_t ADC_CONVERSION_US = 104;  // 13 ADC clocks at 125 kHz
// How long handling a valid frame may take, its answer included (measured under simavr: a
// SETPOINT ~400 cycles; a STATUS answer ~3,400, ~4,400 with the receive interrupts of a busy
// line; a CONFIGURE with its derived coefficients, the grasp mode's settings and STATUS ~9,800,
// 610 us; a FRAMES_LOST report ~1,000 more). A valid frame is let in only when the tick after it
// would start less than LATE_ALLOWED_US late (well inside the 250 us that flag an overrun; a
// rejected frame costs nothing): in practice a CONFIGURE waits for the tick when it arrives less
// than ~0.55 ms before one, a frame with an answer when it arrives less than 0.15 ms before, a
// SETPOINT never. A
// frame that waited for MAX_DEFERRED_TICKS ticks, or while the receive ring filled past
// RX_DEFER_LIMIT bytes, goes in anyway: a late tick is flagged, a byte lost would lose a command.
static const uint16_t SETPOINT_BUDGET_US = 120;
static const uint16_t FRAME_BUDGET_US = 300;
static const uint16_t CONFIGURE_BUDGET_US = 700;
static const uint16_t LATE_ALLOWED_US = 150;
static const uint8_t MAX_DEFERRED_TICKS = 2;
static const uint8_t RX_DEFER_LIMIT = 96;
// Timing marks (PORTB bits): high while the control path runs, and while telemetry is queued.
static const uint8_t MARK_CONTROL = _BV(PB7); // pin 13
static const uint8_t MARK_TELEMETRY = _BV(PB6); // pin 12

static gripper::Device device;
static bool servo_output_on = false;
static volatile uint8_t ticks_due = 0; // measurements taken and not yet served by a tick
static volatile uint16_t adc_value = 0; // the latest measurement (counts)

// The tick: start the potentiometer's conversion now, so the jaw is sampled exactly every 1 ms
// whatever the loop is busy with.
ISR(TIMER3_COMPA_vect) { ADCSRA |= _BV(ADSC); }

// The conversion is done (104 us later): the tick is due. Before, the tick busy-waited for it:
// ~1,600 cycles of every control path (found under simavr).
ISR(ADC_vect) {
    adc_value = ADC; // reads ADCL then ADCH
    if (ticks_due < 255) ++ticks_due;
}

// ---- UART0 ---------------------------------------------------------------------------------

// Received bytes: a ring of 256 (u8 indices wrap by themselves; one writer each, so no locks).
// rx_lost[k] counts bytes lost on the line just before the byte in slot k; rx_pending_lost
// holds losses until the next byte is stored.
static uint8_t rx_ring[256];
static uint8_t rx_lost[256];
static volatile uint8_t rx_head = 0; // written by the interrupt
static volatile uint8_t rx_tail = 0; // written by loop()
static uint8_t rx_pending_lost = 0;  // interrupt only
static bool frame_waits = false;     // a complete valid frame waits for the tick (frame_fits)
static uint8_t deferred_ticks = 0;   // ticks run while it waited

static void uart_begin() {
    uint16_t ubrr = (uint16_t)((F_CPU / 4 / GRIPPER_BAUD - 1) / 2); // U2X: 1 Mbaud -> 1
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); // 8N1
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

static inline uint8_t add_sat(uint8_t a, uint8_t b) { return a > 255 - b ? 255 : a + b; }

ISR(USART0_RX_vect) {
    uint8_t status = UCSR0A; // error flags belong to the byte in UDR0: read them first
    uint8_t byte = UDR0;
    uint8_t lost = rx_pending_lost;
    if (status & _BV(DOR0)) lost = add_sat(lost, 1); // a byte before this one was overwritten
    if (status & _BV(FE0)) lost = add_sat(lost, 1);  // this one is damaged: drop its frame too
    uint8_t head = rx_head;
    if ((uint8_t)(head + 1) == rx_tail) { // full: this byte is lost too
        rx_pending_lost = add_sat(lost, 1);
        return;
    }
    rx_ring[head] = byte;
    rx_lost[head] = lost;
    rx_pending_lost = 0;
    rx_head = (uint8_t)(head + 1);
}

// Transmit: the next queued byte, until the device's queue is empty.
ISR(USART0_UDRE_vect) {
    uint8_t byte;
    if (device.tx.pop(&byte))
        UDR0 = byte;
    else
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
}

static inline void tx_resume() {
    if (device.tx.size() > 0) UCSR0B |= _BV(UDRIE0);
}

static inline void tx_pause() { UCSR0B &= (uint8_t)~_BV(UDRIE0); }

// Timer3 in CTC mode (WGM3 = 4, TOP = OCR3A) at clk/8: a compare interrupt every 1 ms, exact to
// the crystal and independent of how long loop() passes take.
static void tick_timer_begin() {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        TCCR3A = 0;
        TCCR3B = 0;
        TCNT3 = 0;
        OCR3A = TICK_TIMER_COUNTS - 1;
        TIFR3 = _BV(OCF3A);
        TIMSK3 = _BV(OCIE3A);
        TCCR3B = _BV(WGM32) | _BV(CS31);
    }
}

static void servo_timer_begin() {
    pinMode(SERVO_PIN, OUTPUT);
    digitalWrite(SERVO_PIN, LOW);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        TCCR1A = 0;
        TCCR1B = 0;
        TCNT1 = 0;
        ICR1 = SERVO_FRAME_TICKS - 1;
        OCR1A = 0;
        // Fast PWM, TOP = ICR1 (WGM13:0 = 14); output compare stays disconnected until enabled.
        TCCR1A = _BV(WGM11);
        TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS11); // clk/8 = 2 MHz
    }
}

// Apply the device's servo output. OCR1A is double-buffered in fast PWM (updated at BOTTOM), so a
// change never produces a runt pulse.
static void servo_apply() {
    if (device.servo_enabled()) {
        // In fast PWM the output is high from BOTTOM through the compare match, OCR1A + 1 timer
        // ticks: OCR1A = ticks - 1 gives a pulse of exactly `ticks` (found under simavr: the pulse
        // was half a microsecond, ~0.05 deg, too long).
        uint16_t ticks = device.servo_ticks() - 1;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { OCR1A = ticks; }
        if (!servo_output_on) {
            TCCR1A |= _BV(COM1A1); // non-inverting: high from BOTTOM until OCR1A
            servo_output_on = true;
        }
    } else if (servo_output_on) {
        TCCR1A &= (uint8_t)~(_BV(COM1A1) | _BV(COM1A0));
        digitalWrite(SERVO_PIN, LOW);
        servo_output_on = false;
    }
}

static void adc_begin() {
    // AVcc reference, right-adjusted, channel A0; prescaler 128 -> 125 kHz ADC clock (10-bit
    // accuracy), 13 cycles = 104 us per conversion; the conversion-complete interrupt on.
    ADMUX = _BV(REFS0) | (POT_ADC_CHANNEL & 0x07);
    ADCSRB &= (uint8_t)~_BV(MUX5);
    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
}

static uint32_t read_device_id() {
    return eeprom_read_dword(reinterpret_cast<const uint32_t*>(0)); // 0xFFFFFFFF when unset
}

void setup() {
    MCUSR = 0;
    wdt_disable();
    DDRB |= MARK_CONTROL | MARK_TELEMETRY;
    servo_timer_begin();
    adc_begin();
    uart_begin();
    // A delimiter first: a frame cut by a reset would otherwise swallow the first frame of this
    // boot on the host's side (found under simavr: the host lost the NO_SESSION that tells it
    // the board reset).
    UDR0 = 0;
    device.begin(read_device_id(), micros());
    tick_timer_begin();
#if GRIPPER_USE_HW_WATCHDOG
    wdt_enable(WDTO_120MS);
#endif
}

// One control tick: safety, PID, servo update, then the telemetry sample (and the frame, if the
// batch is complete). The transmit interrupt waits meanwhile: the tick's time is the control's.
static void run_tick() {
    PORTB |= MARK_CONTROL;
    tx_pause();
    uint8_t due;
    uint16_t since;
    uint16_t adc;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        due = ticks_due;
        since = TCNT3; // timer counts (0.5 us) since the last compare match
        adc = adc_value;
        if (due > RESYNC_TICKS) due = 1; // far behind (a stall): drop the backlog, run one
        ticks_due = due - 1;
    }
    // The tick being served fell due (due - 1) periods before the latest measurement was ready,
    // which was ADC_CONVERSION_US after the latest compare match.
    uint32_t late_us = (uint32_t)(due - 1) * gripper::TICK_PERIOD_US + since / 2;
    late_us = late_us > ADC_CONVERSION_US ? late_us - ADC_CONVERSION_US : 0;
    device.control(micros(), adc, late_us > OVERRUN_LATE_US);
    servo_apply();
    PORTB = (uint8_t)((PORTB & ~MARK_CONTROL) | MARK_TELEMETRY);
    device.finish_tick();
    PORTB &= (uint8_t)~MARK_TELEMETRY;
    tx_resume();
}

// Microseconds until the next tick falls due: when this period's measurement is ready (TCNT3
// counts 0.5 us from the compare match that started it, 104 us of conversion), or the next's.
// A compare match whose interrupt is still pending (OCF3A) or a conversion under way (ADSC) means
// the tick is imminent (found under simavr: reading only TCNT3, a frame was let in just after a
// compare match and the tick behind it started 164 us late).
static uint16_t us_to_next_tick() {
    uint16_t counts;
    bool imminent;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        counts = TCNT3;
        imminent = (TIFR3 & _BV(OCF3A)) || (ADCSRA & _BV(ADSC));
    }
    const uint16_t ready = 2 * ADC_CONVERSION_US + 16; // counts: conversion + interrupt latency
    if (ticks_due || imminent) return 0;
    if (counts < ready) return (uint16_t)((ready - counts) / 2);
    return (uint16_t)((TICK_TIMER_COUNTS - counts + ready) / 2);
}

// Whether the frame that the delimiter at hand completes may be handled now: its handling ends
// before the next tick, or it has waited long enough.
static bool frame_fits() {
    const gripper::StreamDecoder& rx = device.decoder();
    if (!rx.pending_valid() || deferred_ticks >= MAX_DEFERRED_TICKS) return true;
    if ((uint8_t)(rx_head - rx_tail) > RX_DEFER_LIMIT) return true;
    uint8_t type = rx.pending_type();
    uint16_t budget = type == gripper::MSG_SETPOINT    ? SETPOINT_BUDGET_US
                      : type == gripper::MSG_CONFIGURE ? CONFIGURE_BUDGET_US
                                                        : FRAME_BUDGET_US;
    return us_to_next_tick() + LATE_ALLOWED_US >= budget;
}

// Sleep (idle mode: timers, UART and ADC keep running) until the next interrupt, unless there is
// work. Interrupts are off while deciding; `sei` then `sleep` run back to back, so an interrupt
// arriving in between wakes the CPU at once instead of being slept through. (Transmission goes on
// in the UART interrupt while the CPU sleeps.)
static void idle(bool frame_waits) {
    cli();
    bool work = ticks_due || (rx_head != rx_tail && !frame_waits);
    if (!work) {
        set_sleep_mode(SLEEP_MODE_IDLE);
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
}

void loop() {
#if GRIPPER_USE_HW_WATCHDOG
    wdt_reset();
#endif
    if (ticks_due) {
        run_tick();
        if (frame_waits && deferred_ticks < 255) ++deferred_ticks;
    }

    // Host bytes, until a tick falls due; a frame is completed (its delimiter let in, and the
    // frame handled) only when its handling ends before the next tick (frame_fits).
    uint8_t tail = rx_tail;
    if (tail != rx_head && !ticks_due) {
        uint32_t now = micros();
        while (tail != rx_head && !ticks_due) {
            uint8_t byte = rx_ring[tail];
            if (byte == 0) {
                frame_waits = !frame_fits();
                if (frame_waits) break;
                deferred_ticks = 0;
            }
            uint8_t lost = rx_lost[tail];
            if (lost) device.rx_lost(lost);
            device.receive(byte, now);
            rx_tail = ++tail;
        }
        tx_resume(); // the answers to the host's frames
    }

    idle(frame_waits);
}
