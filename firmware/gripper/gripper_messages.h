// gripper_messages.h - GENERATED from firmware/protocol.toml by
// `python -m gripper_env.hardware.layouts`. Do not edit: change the description and
// regenerate (tests/hardware/test_hw_layouts.py fails while this file is out of date).
//
// The protocol's constants, enums and messages. Each message has TYPE, its fixed SIZE
// (or HEADER and ENTRY_SIZE), encode(out) -> payload length, and decode(in, len) -> bool
// (false for a payload length the type does not allow). Fields are packed little-endian,
// field by field (gripper_wire.h), never by struct memcpy.

#ifndef GRIPPER_MESSAGES_H
#define GRIPPER_MESSAGES_H

#include <stddef.h>
#include <stdint.h>

#include "gripper_wire.h"

namespace gripper {

const uint16_t PROTOCOL_VERSION = 3; // bumped by any incompatible change
const size_t MAX_PAYLOAD = 240; // bytes of payload in one frame
const uint8_t TELEMETRY_MAX_SAMPLES = 32; // samples in one TELEMETRY frame
const uint8_t PROFILE_CHUNK_MAX_SAMPLES = 100; // samples in one PROFILE_CHUNK frame
const int16_t CDEG_NONE = -32768; // "no value" in a centi-degree field

// Message type ids. Host -> device below 0x80, device -> host from 0x80.
enum MessageType {
    MSG_HELLO = 0x01,
    MSG_CONFIGURE = 0x02,
    MSG_SET_MODE = 0x03,
    MSG_SETPOINT = 0x04,
    MSG_PROFILE_CHUNK = 0x05,
    MSG_HEARTBEAT = 0x06,
    MSG_ESTOP = 0x07,
    MSG_INFO = 0x81,
    MSG_TELEMETRY = 0x82,
    MSG_STATUS = 0x83,
    MSG_ERROR = 0x84
};

// device modes (SET_MODE.mode, STATUS.mode)
enum Mode {
    MODE_IDLE = 0, // control stopped, servo at the safe position
    MODE_OPEN_LOOP = 1, // the setpoint is the servo command
    MODE_CLOSED_LOOP = 2 // the setpoint is the PID reference
};

// anti-windup of the PID (CONFIGURE.anti_windup), as in gripper_env.model.pid
enum AntiWindup {
    AW_NONE = 0,
    AW_CLAMPING = 1,
    AW_BACK_CALCULATION = 2
};

// latched faults (STATUS.faults); any keeps the device idle until HELLO or SET_MODE(IDLE)
enum Fault {
    FAULT_WATCHDOG = 0x01, // no valid host frame for 500 ms in an active mode
    FAULT_ESTOP = 0x02, // ESTOP received
    FAULT_NUMERIC = 0x04, // the PID produced a non-finite value
    FAULT_SENSOR = 0x08 // the potentiometer reading sat at a rail in closed loop
};

// bits of STATUS.flags
enum StatusFlag {
    STATUS_SESSION = 0x01,
    STATUS_CONFIGURED = 0x02,
    STATUS_SERVO_ON = 0x04
};

// bits of a TELEMETRY sample's flags; bits 0-1 hold the mode
enum SampleFlag {
    SAMPLE_MODE_MASK = 0x03,
    SAMPLE_SATURATED = 0x04, // PID output limited (u != v)
    SAMPLE_OVERRUN = 0x08, // the control tick started late
    SAMPLE_FAULT = 0x10, // a fault is latched
    SAMPLE_SERVO_ON = 0x20, // servo pulses are being generated
    SAMPLE_CLAMPED = 0x40, // the requested setpoint lay outside the jaw range
    SAMPLE_GRASP = 0x80 // the PID's grasp mode holds the command past a blocked jaw
};

// ERROR.code
enum ErrorCode {
    ERR_NO_SESSION = 1, // 0: a command other than HELLO/ESTOP before a matching HELLO
    ERR_VERSION_MISMATCH = 2, // the device's protocol version
    ERR_BAD_LENGTH = 3, // the received payload length
    ERR_BAD_VALUE = 4, // CONFIGURE field index; 0 for SETPOINT and SET_MODE
    ERR_UNKNOWN_TYPE = 5, // the type id
    ERR_FAULT_LATCHED = 6, // the latched fault bits
    ERR_NOT_CONFIGURED = 7, // 0
    ERR_UNSUPPORTED = 8, // 0
    ERR_FRAMES_LOST = 9 // host frames missing from the sequence, `seq` being the first of them (a report, not a refusal)
};

// Field indices of CONFIGURE (ERROR.detail of BAD_VALUE), in wire order.
enum ConfigureField {
    CF_P = 0,
    CF_I = 1,
    CF_D = 2,
    CF_N = 3,
    CF_U_MIN = 4,
    CF_U_MAX = 5,
    CF_KB = 6,
    CF_JAW_MIN = 7,
    CF_JAW_MAX = 8,
    CF_ADC_AT_LO = 9,
    CF_ADC_AT_HI = 10,
    CF_SERVO_US_AT_0 = 11,
    CF_SERVO_US_AT_180 = 12,
    CF_DECIMATION = 13,
    CF_ANTI_WINDUP = 14,
    CF_SIGN = 15,
    CF_D_ON_MEAS = 16,
    CF_TELEMETRY_BATCH = 17,
    CF_GRASP = 18,
    CF_GRASP_SQUEEZE_DEG = 19,
    CF_GRASP_PUSH_DEG = 20,
    CF_GRASP_SHORT_DEG = 21,
    CF_GRASP_STILL_DEG = 22,
    CF_GRASP_DWELL_TICKS = 23
};

struct TelemetrySample {
    int16_t reference_cdeg; // closed-loop reference, open-loop setpoint, or the safe position when idle
    int16_t command_cdeg; // the servo command; -32768 while the servo gets no pulses
    uint16_t adc; // potentiometer reading (counts)
    uint8_t flags; // bits 0-1 mode, 0x04 SATURATED (PID `u != v`), 0x08 OVERRUN (tick started late), 0x10 FAULT latched, 0x20 SERVO_ON, 0x40 CLAMPED (setpoint outside the jaw range), 0x80 GRASP (the grasp mode holds the command)
};

// HELLO (0x01, host -> device)
struct Hello {
    enum { TYPE = MSG_HELLO, SIZE = 2 };
    uint16_t protocol_version; // the protocol version the host speaks (= 3)
    size_t encode(uint8_t* b) const {
        put_u16(b, protocol_version);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        protocol_version = get_u16(b);
        return true;
    }
};

// CONFIGURE (0x02, host -> device)
struct Configure {
    enum { TYPE = MSG_CONFIGURE, SIZE = 69 };
    float p; // deg/deg, finite
    float i; // 1/s, finite
    float d; // s, finite
    float n; // 1/s, `0 < n * 0.001 < 2`
    float u_min; // deg, not NaN, not +inf
    float u_max; // deg, not NaN, not -inf, `> u_min`
    float kb; // 1/s, finite
    float jaw_min; // deg, inside the image's hard jaw range (INFO: 21..92 by default)
    float jaw_max; // deg, inside the hard jaw range, `> jaw_min`; the safe (open) position
    uint16_t adc_at_lo; // ADC counts with the jaw at 21 deg, in [4, 1019]
    uint16_t adc_at_hi; // ADC counts at 92 deg, in [4, 1019], at least 20 counts from `adc_at_lo`
    uint16_t servo_us_at_0; // servo pulse (us) for 0 deg, in [400, 2600]; the pulses of `jaw_min` and `jaw_max` must lie in the hard pulse window (INFO)
    uint16_t servo_us_at_180; // pulse for 180 deg, in [400, 2600], at least 500 us from the other
    uint16_t decimation; // telemetry sample every `decimation` ticks, 0 = off, at most 1000
    uint8_t anti_windup; // 0 none, 1 clamping, 2 back-calculation
    int8_t sign; // +1: `e = r - y`; -1: `e = y - r`
    uint8_t d_on_meas; // 0: derivative of `e`; 1: of `-sign * y`
    uint8_t telemetry_batch; // samples per TELEMETRY frame, 1..32
    uint8_t grasp; // 1: the PID's grasp mode on (gripper_env.model.pid.GraspOptions); 0: off, the fields below unchecked
    float grasp_squeeze_deg; // deg the command is held past the contact, finite, `> 0`
    float grasp_push_deg; // deg the command must lie past the jaw to read as blocked, finite, `> grasp_squeeze_deg`
    float grasp_short_deg; // deg the jaw must lie short of the reference to read as blocked, finite, `> 0`
    float grasp_still_deg; // deg the jaw may move and still be still, finite, `> 0`
    uint16_t grasp_dwell_ticks; // control ticks (1 ms) blocked before the mode holds, `>= 1`
    size_t encode(uint8_t* b) const {
        put_f32(b, p);
        put_f32(b + 4, i);
        put_f32(b + 8, d);
        put_f32(b + 12, n);
        put_f32(b + 16, u_min);
        put_f32(b + 20, u_max);
        put_f32(b + 24, kb);
        put_f32(b + 28, jaw_min);
        put_f32(b + 32, jaw_max);
        put_u16(b + 36, adc_at_lo);
        put_u16(b + 38, adc_at_hi);
        put_u16(b + 40, servo_us_at_0);
        put_u16(b + 42, servo_us_at_180);
        put_u16(b + 44, decimation);
        b[46] = anti_windup;
        b[47] = (uint8_t)sign;
        b[48] = d_on_meas;
        b[49] = telemetry_batch;
        b[50] = grasp;
        put_f32(b + 51, grasp_squeeze_deg);
        put_f32(b + 55, grasp_push_deg);
        put_f32(b + 59, grasp_short_deg);
        put_f32(b + 63, grasp_still_deg);
        put_u16(b + 67, grasp_dwell_ticks);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        p = get_f32(b);
        i = get_f32(b + 4);
        d = get_f32(b + 8);
        n = get_f32(b + 12);
        u_min = get_f32(b + 16);
        u_max = get_f32(b + 20);
        kb = get_f32(b + 24);
        jaw_min = get_f32(b + 28);
        jaw_max = get_f32(b + 32);
        adc_at_lo = get_u16(b + 36);
        adc_at_hi = get_u16(b + 38);
        servo_us_at_0 = get_u16(b + 40);
        servo_us_at_180 = get_u16(b + 42);
        decimation = get_u16(b + 44);
        anti_windup = b[46];
        sign = (int8_t)b[47];
        d_on_meas = b[48];
        telemetry_batch = b[49];
        grasp = b[50];
        grasp_squeeze_deg = get_f32(b + 51);
        grasp_push_deg = get_f32(b + 55);
        grasp_short_deg = get_f32(b + 59);
        grasp_still_deg = get_f32(b + 63);
        grasp_dwell_ticks = get_u16(b + 67);
        return true;
    }
};

// SET_MODE (0x03, host -> device)
struct SetMode {
    enum { TYPE = MSG_SET_MODE, SIZE = 1 };
    uint8_t mode; // 0 IDLE, 1 OPEN_LOOP, 2 CLOSED_LOOP
    size_t encode(uint8_t* b) const {
        b[0] = mode;
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        mode = b[0];
        return true;
    }
};

// SETPOINT (0x04, host -> device)
struct Setpoint {
    enum { TYPE = MSG_SETPOINT, SIZE = 4 };
    float angle_deg; // deg: the open-loop command or the closed-loop reference; finite
    size_t encode(uint8_t* b) const {
        put_f32(b, angle_deg);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        angle_deg = get_f32(b);
        return true;
    }
};

// PROFILE_CHUNK (0x05, host -> device)
struct ProfileChunk {
    enum { TYPE = MSG_PROFILE_CHUNK, HEADER = 4, ENTRY_SIZE = 2 };
    uint16_t start_index; // index of the first sample in the whole profile
    uint16_t total_length; // samples in the whole profile
    uint8_t count; // entries in this message (from the payload length)
    int16_t samples_cdeg[PROFILE_CHUNK_MAX_SAMPLES]; // reference, one sample per control tick
    size_t encode(uint8_t* b) const {
        put_u16(b, start_index);
        put_u16(b + 2, total_length);
        for (uint8_t k = 0; k < count; ++k) {
            uint8_t* e = b + HEADER + ENTRY_SIZE * k;
            put_i16(e, samples_cdeg[k]);
        }
        return HEADER + ENTRY_SIZE * (size_t)count;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len < HEADER + ENTRY_SIZE * 1 || (len - HEADER) % ENTRY_SIZE != 0) return false;
        if ((len - HEADER) / ENTRY_SIZE > PROFILE_CHUNK_MAX_SAMPLES) return false;
        start_index = get_u16(b);
        total_length = get_u16(b + 2);
        count = (uint8_t)((len - HEADER) / ENTRY_SIZE);
        for (uint8_t k = 0; k < count; ++k) {
            const uint8_t* e = b + HEADER + ENTRY_SIZE * k;
            samples_cdeg[k] = get_i16(e);
        }
        return true;
    }
};

// HEARTBEAT (0x06, host -> device)
struct Heartbeat {
    enum { TYPE = MSG_HEARTBEAT, SIZE = 4 };
    uint32_t token; // echoed in STATUS.echo
    size_t encode(uint8_t* b) const {
        put_u32(b, token);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        token = get_u32(b);
        return true;
    }
};

// ESTOP (0x07, host -> device)
struct Estop {
    enum { TYPE = MSG_ESTOP, SIZE = 0 };
    size_t encode(uint8_t*) const { return SIZE; }
    bool decode(const uint8_t*, size_t len) { return len == SIZE; }
};

// INFO (0x81, device -> host)
struct Info {
    enum { TYPE = MSG_INFO, SIZE = 29 };
    uint16_t protocol_version; // the firmware's protocol version
    uint8_t fw_major; // firmware version (informational)
    uint8_t fw_minor; // firmware version
    uint8_t fw_patch; // firmware version
    uint32_t device_id; // EEPROM bytes 0-3; 0xFFFFFFFF if never written
    uint16_t tick_period_us; // the control period (1000)
    uint8_t max_batch; // largest `telemetry_batch` (32)
    uint8_t max_payload; // largest payload in bytes (240)
    float hard_jaw_min_deg; // the hard jaw range compiled into the image: no CONFIGURE can move the jaw outside it (21)
    float hard_jaw_max_deg; // (92)
    float hard_pulse_min_us; // the hard pulse window: every servo pulse lies in it, the pulses of the hard jaw range under the servo mapping the image was built for (760.5 us for 21 deg with 544/2400 us)
    float hard_pulse_max_us; // (1492.5 us for 92 deg)
    size_t encode(uint8_t* b) const {
        put_u16(b, protocol_version);
        b[2] = fw_major;
        b[3] = fw_minor;
        b[4] = fw_patch;
        put_u32(b + 5, device_id);
        put_u16(b + 9, tick_period_us);
        b[11] = max_batch;
        b[12] = max_payload;
        put_f32(b + 13, hard_jaw_min_deg);
        put_f32(b + 17, hard_jaw_max_deg);
        put_f32(b + 21, hard_pulse_min_us);
        put_f32(b + 25, hard_pulse_max_us);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        protocol_version = get_u16(b);
        fw_major = b[2];
        fw_minor = b[3];
        fw_patch = b[4];
        device_id = get_u32(b + 5);
        tick_period_us = get_u16(b + 9);
        max_batch = b[11];
        max_payload = b[12];
        hard_jaw_min_deg = get_f32(b + 13);
        hard_jaw_max_deg = get_f32(b + 17);
        hard_pulse_min_us = get_f32(b + 21);
        hard_pulse_max_us = get_f32(b + 25);
        return true;
    }
};

// TELEMETRY (0x82, device -> host)
struct Telemetry {
    enum { TYPE = MSG_TELEMETRY, HEADER = 7, ENTRY_SIZE = 7 };
    uint32_t t0_us; // device time (micros(), wraps every 71.6 min) of sample 0
    uint16_t decimation; // sample `j` was taken at `t0_us + j * decimation * 1000`
    uint8_t count; // = k, the number of samples
    TelemetrySample samples[TELEMETRY_MAX_SAMPLES];
    size_t encode(uint8_t* b) const {
        put_u32(b, t0_us);
        put_u16(b + 4, decimation);
        b[6] = count;
        for (uint8_t k = 0; k < count; ++k) {
            uint8_t* e = b + HEADER + ENTRY_SIZE * k;
            put_i16(e, samples[k].reference_cdeg);
            put_i16(e + 2, samples[k].command_cdeg);
            put_u16(e + 4, samples[k].adc);
            e[6] = samples[k].flags;
        }
        return HEADER + ENTRY_SIZE * (size_t)count;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len < HEADER) return false;
        uint8_t c = b[6];
        if (c < 1 || c > TELEMETRY_MAX_SAMPLES || len != HEADER + ENTRY_SIZE * (size_t)c) return false;
        t0_us = get_u32(b);
        decimation = get_u16(b + 4);
        count = c;
        for (uint8_t k = 0; k < count; ++k) {
            const uint8_t* e = b + HEADER + ENTRY_SIZE * k;
            samples[k].reference_cdeg = get_i16(e);
            samples[k].command_cdeg = get_i16(e + 2);
            samples[k].adc = get_u16(e + 4);
            samples[k].flags = e[6];
        }
        return true;
    }
};

// STATUS (0x83, device -> host)
struct Status {
    enum { TYPE = MSG_STATUS, SIZE = 34 };
    uint32_t device_time_us; // device time (micros()) when the STATUS was built
    uint32_t echo; // token of the last HEARTBEAT
    uint8_t mode; // 0 IDLE, 1 OPEN_LOOP, 2 CLOSED_LOOP
    uint8_t faults; // 0x01 WATCHDOG, 0x02 ESTOP, 0x04 NUMERIC, 0x08 SENSOR (latched)
    uint8_t flags; // 0x01 SESSION, 0x02 CONFIGURED, 0x04 SERVO_ON
    uint8_t last_rx_seq; // seq of the last valid host frame
    uint32_t frames_ok; // valid host frames since reset
    uint16_t frames_lost; // host frames missing from the sequence
    uint16_t bad_crc; // host frames with a CRC mismatch
    uint16_t bad_frame; // invalid COBS, truncated, oversized, or damaged by bytes lost on the receive path
    uint16_t refused; // commands answered by ERROR
    uint16_t tx_dropped; // device frames dropped for lack of transmit buffer
    uint16_t overruns; // control ticks that started more than 250 us late
    uint16_t rx_overflow; // host bytes lost before the decoder (receive buffer full, UART overrun or framing error)
    float setpoint_deg; // the setpoint the device holds (deg, as received, before the jaw clamp); NaN before any
    size_t encode(uint8_t* b) const {
        put_u32(b, device_time_us);
        put_u32(b + 4, echo);
        b[8] = mode;
        b[9] = faults;
        b[10] = flags;
        b[11] = last_rx_seq;
        put_u32(b + 12, frames_ok);
        put_u16(b + 16, frames_lost);
        put_u16(b + 18, bad_crc);
        put_u16(b + 20, bad_frame);
        put_u16(b + 22, refused);
        put_u16(b + 24, tx_dropped);
        put_u16(b + 26, overruns);
        put_u16(b + 28, rx_overflow);
        put_f32(b + 30, setpoint_deg);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        device_time_us = get_u32(b);
        echo = get_u32(b + 4);
        mode = b[8];
        faults = b[9];
        flags = b[10];
        last_rx_seq = b[11];
        frames_ok = get_u32(b + 12);
        frames_lost = get_u16(b + 16);
        bad_crc = get_u16(b + 18);
        bad_frame = get_u16(b + 20);
        refused = get_u16(b + 22);
        tx_dropped = get_u16(b + 24);
        overruns = get_u16(b + 26);
        rx_overflow = get_u16(b + 28);
        setpoint_deg = get_f32(b + 30);
        return true;
    }
};

// ERROR (0x84, device -> host)
struct Error {
    enum { TYPE = MSG_ERROR, SIZE = 5 };
    uint8_t code; // ErrorCode (table below)
    uint8_t msg_type; // type of the refused frame
    uint8_t seq; // seq of the refused frame
    uint16_t detail; // depends on the code (table below)
    size_t encode(uint8_t* b) const {
        b[0] = code;
        b[1] = msg_type;
        b[2] = seq;
        put_u16(b + 3, detail);
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        code = b[0];
        msg_type = b[1];
        seq = b[2];
        detail = get_u16(b + 3);
        return true;
    }
};

} // namespace gripper

#endif // GRIPPER_MESSAGES_H
