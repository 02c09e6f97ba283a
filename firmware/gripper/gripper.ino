// gripper.ino - Arduino Mega 2560 firmware for the hobby-servo gripper.
//
// The board runs the 1 kHz PID; the host sends gains and references and receives batched
// telemetry over binary frames (firmware/PROTOCOL.md). All protocol, mode and safety logic
// lives in gripper_core.h, which the host tests compile and exercise; this file only touches
// hardware:
//
//   servo      Timer1 fast PWM (mode 14), prescaler 8 -> 0.5 us ticks, TOP 39999 -> 50 Hz,
//              pulse on OC1A = digital pin 11. No Servo library (not packaged on Debian).
//   feedback   potentiometer on A0, one 10-bit conversion at the start of every tick (~104 us).
//   schedule   micros()-based 1 kHz tick in loop(); a late tick is flagged as an overrun.
//   serial     1 000 000 baud (exact at 16 MHz with U2X, UBRR = 1); output goes through the
//              core's transmit queue and is drained only as far as the UART buffer has room,
//              so the control loop never blocks on Serial.
//   watchdog   the AVR hardware watchdog resets a hung board (servo pulses stop on reset).
//
// Serial rate: one TELEMETRY frame of 10 samples is 7 + 10*7 = 77 payload bytes, 81 raw, 83 on
// the wire. At decimation 1 that is 100 frames/s = 8.3 kB/s = 83 kbit/s with 10 bits per byte:
// 72 % of 115200 baud (which is also 2.1 % off at 16 MHz), 8 % of 1 Mbaud.

#include <avr/eeprom.h>
#include <avr/io.h>
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
static const uint32_t OVERRUN_LATE_US = 250;    // a tick starting this late is flagged
static const uint32_t RESYNC_LATE_US = 10000;   // this far behind: skip ticks instead of bursting
static const uint8_t RX_BYTES_PER_LOOP = 64;    // bound the time spent parsing per loop pass

static gripper::Device device;
static uint32_t next_tick_us;
static bool servo_output_on = false;

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
        uint16_t ticks = device.servo_ticks();
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

static uint16_t adc_read() {
    ADCSRA |= _BV(ADSC);
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
    servo_timer_begin();
    adc_begin();
    Serial.begin(GRIPPER_BAUD);
    device.begin(read_device_id(), micros());
    next_tick_us = micros() + gripper::TICK_PERIOD_US;
#if GRIPPER_USE_HW_WATCHDOG
    wdt_enable(WDTO_120MS);
#endif
}

void loop() {
#if GRIPPER_USE_HW_WATCHDOG
    wdt_reset();
#endif
    // Host bytes.
    for (uint8_t k = 0; k < RX_BYTES_PER_LOOP; ++k) {
        int c = Serial.read();
        if (c < 0) break;
        device.receive((uint8_t)c, micros());
    }

    // Control tick.
    uint32_t now = micros();
    uint32_t late = now - next_tick_us;
    if (late < 0x80000000UL) { // now >= next_tick_us, modulo the micros() wrap
        uint16_t adc = adc_read();
        device.tick(now, adc, late > OVERRUN_LATE_US);
        servo_apply();
        next_tick_us += gripper::TICK_PERIOD_US;
        if (late > RESYNC_LATE_US) next_tick_us = now + gripper::TICK_PERIOD_US;
    }

    // Device bytes, only as many as fit in the UART buffer without blocking.
    int room = Serial.availableForWrite();
    while (room-- > 0 && device.tx.size() > 0) Serial.write(device.tx.pop());
}
