// gripper.ino - Arduino Mega 2560 firmware for the hobby-servo gripper.
//
// The board runs the 1 kHz PID; the host sends gains and references and receives batched
// telemetry over binary frames (firmware/PROTOCOL.md). All protocol, mode and safety logic
// lives in gripper_core.h, which the host tests compile and exercise; this file only touches
// hardware:
//
//   servo      Timer1 fast PWM (mode 14), prescaler 8 -> 0.5 us ticks, TOP 39999 -> 50 Hz,
//              pulse on OC1A = digital pin 11. No Servo library (not packaged on Debian).
//   feedback   potentiometer on A0, one 10-bit conversion (104 us) started by the tick interrupt.
//   schedule   Timer3 CTC interrupt at exactly 1 kHz marks a tick due; loop() runs it first,
//              stops parsing host bytes or draining output as soon as one falls due, and
//              sleeps (idle mode) when there is nothing to do. A tick that starts more than
//              250 us after its timer interrupt is flagged as an overrun.
//   serial     1 000 000 baud (exact at 16 MHz with U2X, UBRR = 1); output goes through the
//              core's transmit queue and is drained only as far as the UART buffer has room,
//              so the control loop never blocks on Serial.
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
static const uint8_t RX_BYTES_PER_LOOP = 64;    // bound the time spent parsing per loop pass
// Timing marks (PORTB bits): high while the control path runs, and while telemetry is queued.
static const uint8_t MARK_CONTROL = _BV(PB7); // pin 13
static const uint8_t MARK_TELEMETRY = _BV(PB6); // pin 12

static gripper::Device device;
static bool servo_output_on = false;
static volatile uint8_t ticks_due = 0; // Timer3 compare matches not yet served

// The tick: mark it due and start the potentiometer's conversion now, so the jaw is sampled
// exactly every 1 ms whatever the loop is busy with (run_tick reads the result).
ISR(TIMER3_COMPA_vect) {
    if (ticks_due < 255) ++ticks_due;
    ADCSRA |= _BV(ADSC);
}

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
    // accuracy), 13 cycles = 104 us per conversion.
    ADMUX = _BV(REFS0) | (POT_ADC_CHANNEL & 0x07);
    ADCSRB &= (uint8_t)~_BV(MUX5);
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
}

// The conversion the tick interrupt started (104 us long): wait for it, read it. Ticks run back to
// back after a stall share the latest conversion.
static uint16_t adc_read() {
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC; // reads ADCL then ADCH
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
    Serial.begin(GRIPPER_BAUD);
    // A delimiter first: a frame cut by a reset would otherwise swallow the first frame of this
    // boot on the host's side (found under simavr: the host lost the NO_SESSION that tells it
    // the board reset).
    Serial.write((uint8_t)0);
    device.begin(read_device_id(), micros());
    tick_timer_begin();
#if GRIPPER_USE_HW_WATCHDOG
    wdt_enable(WDTO_120MS);
#endif
}

// One control tick: ADC, safety, PID, servo update, then the telemetry frame if one is complete.
static void run_tick() {
    PORTB |= MARK_CONTROL;
    uint8_t due;
    uint16_t since;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        due = ticks_due;
        since = TCNT3; // timer counts (0.5 us) since the last compare match
        if (due > RESYNC_TICKS) due = 1; // far behind (a stall): drop the backlog, run one
        ticks_due = due - 1;
    }
    // The tick being served fell due (due - 1) periods before the latest compare match.
    uint32_t late_us = (uint32_t)(due - 1) * gripper::TICK_PERIOD_US + since / 2;
    uint16_t adc = adc_read();
    device.control(micros(), adc, late_us > OVERRUN_LATE_US);
    servo_apply();
    PORTB = (uint8_t)((PORTB & ~MARK_CONTROL) | MARK_TELEMETRY);
    device.finish_tick();
    PORTB &= (uint8_t)~MARK_TELEMETRY;
}

// Sleep (idle mode: timers, UART and ADC keep running) until the next interrupt, unless there is
// work. Interrupts are off while deciding; `sei` then `sleep` run back to back, so an interrupt
// arriving in between wakes the CPU at once instead of being slept through.
static void idle() {
    cli();
    bool work = ticks_due || Serial.available() > 0 ||
                (device.tx.size() > 0 && Serial.availableForWrite() > 0);
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
    if (ticks_due) run_tick();

    // Host bytes, until a tick falls due.
    for (uint8_t k = 0; k < RX_BYTES_PER_LOOP && !ticks_due; ++k) {
        int c = Serial.read();
        if (c < 0) break;
        device.receive((uint8_t)c, micros());
    }

    // Device bytes, only as many as fit in the UART buffer without blocking, until a tick falls due.
    int room = Serial.availableForWrite();
    while (room-- > 0 && device.tx.size() > 0 && !ticks_due) Serial.write(device.tx.pop());

    idle();
}
