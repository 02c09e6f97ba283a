// gripper_core.h - hardware-independent logic of the gripper firmware.
//
// Shared by the Arduino Mega 2560 sketch (gripper.ino, avr-gcc 5.4, -std=gnu++11, 32-bit double)
// and the host test harness (firmware/host/harness.cpp, g++ -std=c++17). Plain C++11: no Arduino
// headers, no C++ standard library, no heap, no exceptions.
//
// Contents, in order:
//   1. constants and wire-level helpers (explicit little-endian packing, never struct memcpy)
//   2. CRC-16/CCITT-FALSE and COBS
//   3. message types and their payload codecs
//   4. frame encoder and the byte-at-a-time stream decoder
//   5. the PID (the same equations as gripper_env.pid.pid_update)
//   6. safety functions: jaw clamp, ADC <-> angle, servo pulse, watchdog
//   7. Device: the protocol and mode state machine the sketch drives
//
// The wire format is specified in firmware/PROTOCOL.md; the Python twin is
// gripper_env/hardware/protocol.py. Change all three together.

#ifndef GRIPPER_CORE_H
#define GRIPPER_CORE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

// The controller's arithmetic type: float on the board (avr-gcc's double is 32-bit anyway),
// double on the host so the parity tests can compare with the Python PID to 1e-6.
#ifndef GRIPPER_REAL
#if defined(__AVR__)
#define GRIPPER_REAL float
#else
#define GRIPPER_REAL double
#endif
#endif

namespace gripper {

typedef GRIPPER_REAL real_t;

// ---------------------------------------------------------------------------------------------
// 1. Constants
// ---------------------------------------------------------------------------------------------

const uint16_t PROTOCOL_VERSION = 1;
const uint8_t FIRMWARE_VERSION_MAJOR = 0;
const uint8_t FIRMWARE_VERSION_MINOR = 1;
const uint8_t FIRMWARE_VERSION_PATCH = 0;

const size_t MAX_PAYLOAD = 240;                     // bytes of payload in one frame
const size_t MAX_RAW_FRAME = MAX_PAYLOAD + 4;       // seq + type + payload + crc16
const size_t MAX_ENCODED_FRAME = MAX_RAW_FRAME + 2; // COBS overhead for <= 254 bytes is 1 (+1)
const size_t MAX_WIRE_FRAME = MAX_ENCODED_FRAME + 1;  // plus the 0x00 delimiter

const uint32_t TICK_PERIOD_US = 1000;        // control period (1 kHz)
const uint32_t WATCHDOG_TIMEOUT_US = 500000; // host silence that triggers the safe stop
const uint8_t TELEMETRY_MAX_SAMPLES = 32;    // samples in one TELEMETRY frame
const uint8_t PROFILE_CHUNK_MAX_SAMPLES = 100;

// Servo and jaw geometry (deg). The jaw range is configurable but must lie inside the servo range.
const float SERVO_MIN_DEG = 0.0f;
const float SERVO_MAX_DEG = 180.0f;
const float JAW_CLOSED_DEG = 21.0f; // default jaw_min: grip
const float JAW_OPEN_DEG = 92.0f;   // default jaw_max: un-grip, the safe position
// Two-point ADC calibration is taken at the jaw's mechanical ends.
const float CAL_ANGLE_LO_DEG = 21.0f;
const float CAL_ANGLE_HI_DEG = 92.0f;
const uint16_t ADC_MAX_COUNT = 1023;
const uint16_t ADC_RAIL_MARGIN = 4;     // readings this close to 0 or 1023 mean a broken wire
const uint16_t ADC_MIN_CAL_SPAN = 20;   // counts between the two calibration points
const uint16_t SENSOR_FAULT_TICKS = 20; // consecutive rail readings before a SENSOR fault
// Servo pulse (us): Servo-library defaults for 0 and 180 deg, and hard limits for any calibration.
const uint16_t SERVO_US_AT_0_DEFAULT = 544;
const uint16_t SERVO_US_AT_180_DEFAULT = 2400;
const uint16_t SERVO_PULSE_MIN_US = 400;
const uint16_t SERVO_PULSE_MAX_US = 2600;
const uint16_t SERVO_MIN_CAL_SPAN_US = 500;
const uint16_t MAX_DECIMATION = 1000;

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

enum Mode { MODE_IDLE = 0, MODE_OPEN_LOOP = 1, MODE_CLOSED_LOOP = 2 };

enum AntiWindup { AW_NONE = 0, AW_CLAMPING = 1, AW_BACK_CALCULATION = 2 };

// Latched faults (STATUS.faults). Any latched fault keeps the device idle until cleared by
// HELLO or SET_MODE(IDLE).
enum Fault {
    FAULT_WATCHDOG = 0x01, // no valid host frame for WATCHDOG_TIMEOUT_US in an active mode
    FAULT_ESTOP = 0x02,    // ESTOP received
    FAULT_NUMERIC = 0x04,  // the PID produced a non-finite value
    FAULT_SENSOR = 0x08    // the potentiometer reading sat at a rail in closed loop
};

// STATUS.flags
enum StatusFlag { STATUS_SESSION = 0x01, STATUS_CONFIGURED = 0x02, STATUS_SERVO_ON = 0x04 };

// TELEMETRY sample flags; bits 0-1 hold the mode.
enum SampleFlag {
    SAMPLE_MODE_MASK = 0x03,
    SAMPLE_SATURATED = 0x04, // PID output limited (u != v)
    SAMPLE_OVERRUN = 0x08,   // the control tick started late
    SAMPLE_FAULT = 0x10,     // a fault is latched
    SAMPLE_SERVO_ON = 0x20,  // servo pulses are being generated
    SAMPLE_CLAMPED = 0x40    // the requested setpoint lay outside the jaw range
};

const int16_t CDEG_NONE = -32768; // "no value" in a centi-degree field

enum ErrorCode {
    ERR_NO_SESSION = 1,       // command before a matching HELLO
    ERR_VERSION_MISMATCH = 2, // HELLO with another protocol version; detail = ours
    ERR_BAD_LENGTH = 3,       // payload length wrong for the type; detail = received length
    ERR_BAD_VALUE = 4,        // a field is out of range / not finite; detail = field index
    ERR_UNKNOWN_TYPE = 5,     // type id not a host -> device message
    ERR_FAULT_LATCHED = 6,    // SET_MODE active while a fault is latched; detail = faults
    ERR_NOT_CONFIGURED = 7,   // closed loop before any accepted CONFIGURE
    ERR_UNSUPPORTED = 8       // valid message this firmware does not implement (PROFILE_CHUNK)
};

// ---------------------------------------------------------------------------------------------
// Little-endian packing
// ---------------------------------------------------------------------------------------------

inline void put_u16(uint8_t* p, uint16_t v) {
    p[0] = (uint8_t)(v & 0xFF);
    p[1] = (uint8_t)(v >> 8);
}
inline void put_u32(uint8_t* p, uint32_t v) {
    p[0] = (uint8_t)(v & 0xFF);
    p[1] = (uint8_t)((v >> 8) & 0xFF);
    p[2] = (uint8_t)((v >> 16) & 0xFF);
    p[3] = (uint8_t)(v >> 24);
}
inline void put_i16(uint8_t* p, int16_t v) { put_u16(p, (uint16_t)v); }
inline void put_f32(uint8_t* p, float v) {
    uint32_t bits;
    memcpy(&bits, &v, 4); // bit cast of one scalar, both IEEE-754 binary32
    put_u32(p, bits);
}
inline uint16_t get_u16(const uint8_t* p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
inline uint32_t get_u32(const uint8_t* p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
inline int16_t get_i16(const uint8_t* p) { return (int16_t)get_u16(p); }
inline float get_f32(const uint8_t* p) {
    uint32_t bits = get_u32(p);
    float v;
    memcpy(&v, &bits, 4);
    return v;
}

template <typename Real>
inline bool is_finite(Real x) {
    // inf - inf and NaN - NaN are NaN, which compares unequal to everything.
    return (x - x) == (x - x);
}

// Saturating conversion of an angle (deg) to centi-degrees; NaN becomes CDEG_NONE.
template <typename Real>
inline int16_t to_cdeg(Real deg) {
    if (deg != deg) return CDEG_NONE;
    Real c = deg * Real(100);
    if (c >= Real(32767)) return 32767;
    if (c <= Real(-32767)) return -32767;
    return (int16_t)(c < Real(0) ? c - Real(0.5) : c + Real(0.5));
}

// ---------------------------------------------------------------------------------------------
// 2. CRC-16/CCITT-FALSE and COBS
// ---------------------------------------------------------------------------------------------

// One byte of CRC-16/CCITT-FALSE (poly 0x1021, not reflected). Table-free, a few cycles per byte.
inline uint16_t crc16_update(uint16_t crc, uint8_t data) {
    uint8_t x = (uint8_t)((crc >> 8) ^ data);
    x ^= (uint8_t)(x >> 4);
    return (uint16_t)((crc << 8) ^ ((uint16_t)x << 12) ^ ((uint16_t)x << 5) ^ (uint16_t)x);
}

// CRC-16/CCITT-FALSE: init 0xFFFF, xorout 0; check("123456789") == 0x29B1.
inline uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFF) {
    for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
    return crc;
}

// COBS-encode n bytes into out (capacity cap). Returns the encoded length, 0 if it does not fit.
// A block of 254 non-zero bytes at the very end gets no trailing 0x01 code (canonical COBS).
inline size_t cobs_encode(const uint8_t* in, size_t n, uint8_t* out, size_t cap) {
    if (cap < 1) return 0;
    size_t code_at = 0;
    size_t o = 1;
    uint8_t code = 1;
    for (size_t i = 0; i < n; ++i) {
        if (in[i] != 0) {
            if (o >= cap) return 0;
            out[o++] = in[i];
            ++code;
        }
        if (in[i] == 0 || code == 0xFF) {
            out[code_at] = code;
            code = 1;
            if (in[i] == 0 || i + 1 < n) {
                if (o >= cap) return 0;
                code_at = o++;
            } else {
                return o; // the block ended exactly with the data
            }
        }
    }
    out[code_at] = code;
    return o;
}

// COBS-decode n bytes (no delimiter) into out; in == out is allowed. Returns the decoded length,
// or -1 for a zero byte in the input, a block running past the end, or out of space.
inline long cobs_decode(const uint8_t* in, size_t n, uint8_t* out, size_t cap) {
    size_t i = 0;
    size_t o = 0;
    while (i < n) {
        uint8_t code = in[i++];
        if (code == 0) return -1;
        for (uint8_t k = 1; k < code; ++k) {
            if (i >= n || in[i] == 0 || o >= cap) return -1;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < n) {
            if (o >= cap) return -1;
            out[o++] = 0;
        }
    }
    return (long)o;
}

// ---------------------------------------------------------------------------------------------
// 3. Messages. Each has TYPE, encode(out) -> payload length, decode(in, n) -> bool (exact length).
// ---------------------------------------------------------------------------------------------

struct Hello {
    enum { TYPE = MSG_HELLO, SIZE = 2 };
    uint16_t protocol_version;
    size_t encode(uint8_t* p) const {
        put_u16(p, protocol_version);
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        protocol_version = get_u16(p);
        return true;
    }
};

struct Configure {
    enum { TYPE = MSG_CONFIGURE, SIZE = 50 };
    float p, i, d, n;          // gains: deg/deg, 1/s, s, 1/s
    float u_min, u_max;        // PID output limits (deg), may be -inf/+inf
    float kb;                  // back-calculation gain (1/s)
    float jaw_min, jaw_max;    // jaw range (deg), inside the servo range
    uint16_t adc_at_lo;        // ADC counts at CAL_ANGLE_LO_DEG (21 deg)
    uint16_t adc_at_hi;        // ADC counts at CAL_ANGLE_HI_DEG (92 deg)
    uint16_t servo_us_at_0;    // servo pulse (us) for 0 deg
    uint16_t servo_us_at_180;  // servo pulse (us) for 180 deg
    uint16_t decimation;       // telemetry: one sample every `decimation` ticks, 0 = off
    uint8_t anti_windup;       // AntiWindup
    int8_t sign;               // +1: e = r - y, -1: e = y - r
    uint8_t d_on_meas;         // 1: derivative of -sign*y instead of e
    uint8_t telemetry_batch;   // samples per TELEMETRY frame, 1..TELEMETRY_MAX_SAMPLES
    size_t encode(uint8_t* b) const {
        put_f32(b + 0, p);
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
        return SIZE;
    }
    bool decode(const uint8_t* b, size_t len) {
        if (len != SIZE) return false;
        p = get_f32(b + 0);
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
        return true;
    }
};

// Field indices reported in ERROR.detail for ERR_BAD_VALUE on CONFIGURE (declaration order).
enum ConfigureField {
    CF_P = 0, CF_I, CF_D, CF_N, CF_U_MIN, CF_U_MAX, CF_KB, CF_JAW_MIN, CF_JAW_MAX, CF_ADC_AT_LO,
    CF_ADC_AT_HI, CF_SERVO_US_AT_0, CF_SERVO_US_AT_180, CF_DECIMATION, CF_ANTI_WINDUP, CF_SIGN,
    CF_D_ON_MEAS, CF_TELEMETRY_BATCH
};

struct SetMode {
    enum { TYPE = MSG_SET_MODE, SIZE = 1 };
    uint8_t mode;
    size_t encode(uint8_t* p) const {
        p[0] = mode;
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        mode = p[0];
        return true;
    }
};

struct Setpoint {
    enum { TYPE = MSG_SETPOINT, SIZE = 4 };
    float angle_deg;
    size_t encode(uint8_t* p) const {
        put_f32(p, angle_deg);
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        angle_deg = get_f32(p);
        return true;
    }
};

// A chunk of a reference profile (centi-deg samples). The codec is complete; this firmware
// version answers ERR_UNSUPPORTED (profile playback is phase 2).
struct ProfileChunk {
    enum { TYPE = MSG_PROFILE_CHUNK, HEADER = 4 };
    uint16_t start_index;  // index of samples_cdeg[0] in the whole profile
    uint16_t total_length; // samples in the whole profile
    uint8_t count;         // samples in this chunk, 1..PROFILE_CHUNK_MAX_SAMPLES
    int16_t samples_cdeg[PROFILE_CHUNK_MAX_SAMPLES];
    size_t encode(uint8_t* p) const {
        put_u16(p, start_index);
        put_u16(p + 2, total_length);
        for (uint8_t k = 0; k < count; ++k) put_i16(p + HEADER + 2 * k, samples_cdeg[k]);
        return HEADER + 2 * (size_t)count;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n < HEADER + 2 || (n - HEADER) % 2 != 0) return false;
        if ((n - HEADER) / 2 > PROFILE_CHUNK_MAX_SAMPLES) return false;
        start_index = get_u16(p);
        total_length = get_u16(p + 2);
        count = (uint8_t)((n - HEADER) / 2);
        for (uint8_t k = 0; k < count; ++k) samples_cdeg[k] = get_i16(p + HEADER + 2 * k);
        return true;
    }
};

struct Heartbeat {
    enum { TYPE = MSG_HEARTBEAT, SIZE = 4 };
    uint32_t token; // echoed in STATUS.echo
    size_t encode(uint8_t* p) const {
        put_u32(p, token);
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        token = get_u32(p);
        return true;
    }
};

struct Estop {
    enum { TYPE = MSG_ESTOP, SIZE = 0 };
    size_t encode(uint8_t*) const { return SIZE; }
    bool decode(const uint8_t*, size_t n) { return n == SIZE; }
};

struct Info {
    enum { TYPE = MSG_INFO, SIZE = 13 };
    uint16_t protocol_version;
    uint8_t fw_major, fw_minor, fw_patch;
    uint32_t device_id;      // from EEPROM, 0xFFFFFFFF if never written
    uint16_t tick_period_us; // control period
    uint8_t max_batch;       // TELEMETRY_MAX_SAMPLES
    uint8_t max_payload;     // MAX_PAYLOAD
    size_t encode(uint8_t* p) const {
        put_u16(p, protocol_version);
        p[2] = fw_major;
        p[3] = fw_minor;
        p[4] = fw_patch;
        put_u32(p + 5, device_id);
        put_u16(p + 9, tick_period_us);
        p[11] = max_batch;
        p[12] = max_payload;
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        protocol_version = get_u16(p);
        fw_major = p[2];
        fw_minor = p[3];
        fw_patch = p[4];
        device_id = get_u32(p + 5);
        tick_period_us = get_u16(p + 9);
        max_batch = p[11];
        max_payload = p[12];
        return true;
    }
};

struct TelemetrySample {
    int16_t reference_cdeg; // reference (closed loop) or setpoint (open loop), centi-deg
    int16_t command_cdeg;   // servo command, centi-deg; CDEG_NONE while the servo is off
    uint16_t adc;           // potentiometer, ADC counts
    uint8_t flags;          // SampleFlag
};

struct Telemetry {
    enum { TYPE = MSG_TELEMETRY, HEADER = 7, SAMPLE_SIZE = 7 };
    uint32_t t0_us;      // device time (micros) of samples[0]
    uint16_t decimation; // samples are decimation * TICK_PERIOD_US apart
    uint8_t count;       // 1..TELEMETRY_MAX_SAMPLES
    TelemetrySample samples[TELEMETRY_MAX_SAMPLES];
    size_t encode(uint8_t* p) const {
        put_u32(p, t0_us);
        put_u16(p + 4, decimation);
        p[6] = count;
        for (uint8_t k = 0; k < count; ++k) {
            uint8_t* s = p + HEADER + SAMPLE_SIZE * k;
            put_i16(s, samples[k].reference_cdeg);
            put_i16(s + 2, samples[k].command_cdeg);
            put_u16(s + 4, samples[k].adc);
            s[6] = samples[k].flags;
        }
        return HEADER + SAMPLE_SIZE * (size_t)count;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n < HEADER) return false;
        uint8_t c = p[6];
        if (c < 1 || c > TELEMETRY_MAX_SAMPLES || n != HEADER + SAMPLE_SIZE * (size_t)c)
            return false;
        t0_us = get_u32(p);
        decimation = get_u16(p + 4);
        count = c;
        for (uint8_t k = 0; k < count; ++k) {
            const uint8_t* s = p + HEADER + SAMPLE_SIZE * k;
            samples[k].reference_cdeg = get_i16(s);
            samples[k].command_cdeg = get_i16(s + 2);
            samples[k].adc = get_u16(s + 4);
            samples[k].flags = s[6];
        }
        return true;
    }
};

struct Status {
    enum { TYPE = MSG_STATUS, SIZE = 28 };
    uint32_t device_time_us;
    uint32_t echo;         // token of the last HEARTBEAT
    uint8_t mode;          // Mode
    uint8_t faults;        // Fault bits, latched
    uint8_t flags;         // StatusFlag bits
    uint8_t last_rx_seq;   // seq of the last valid host frame
    uint32_t frames_ok;    // valid host frames received
    uint16_t frames_lost;  // host frames missing from the sequence (sum of gaps)
    uint16_t bad_crc;      // frames with a CRC mismatch
    uint16_t bad_frame;    // COBS errors, truncated and oversized frames
    uint16_t refused;      // commands answered by ERROR
    uint16_t tx_dropped;   // device frames dropped for lack of transmit buffer
    uint16_t overruns;     // control ticks that started late
    size_t encode(uint8_t* p) const {
        put_u32(p, device_time_us);
        put_u32(p + 4, echo);
        p[8] = mode;
        p[9] = faults;
        p[10] = flags;
        p[11] = last_rx_seq;
        put_u32(p + 12, frames_ok);
        put_u16(p + 16, frames_lost);
        put_u16(p + 18, bad_crc);
        put_u16(p + 20, bad_frame);
        put_u16(p + 22, refused);
        put_u16(p + 24, tx_dropped);
        put_u16(p + 26, overruns);
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        device_time_us = get_u32(p);
        echo = get_u32(p + 4);
        mode = p[8];
        faults = p[9];
        flags = p[10];
        last_rx_seq = p[11];
        frames_ok = get_u32(p + 12);
        frames_lost = get_u16(p + 16);
        bad_crc = get_u16(p + 18);
        bad_frame = get_u16(p + 20);
        refused = get_u16(p + 22);
        tx_dropped = get_u16(p + 24);
        overruns = get_u16(p + 26);
        return true;
    }
};

struct Error {
    enum { TYPE = MSG_ERROR, SIZE = 5 };
    uint8_t code;     // ErrorCode
    uint8_t msg_type; // type id of the refused frame
    uint8_t seq;      // seq of the refused frame
    uint16_t detail;  // see ErrorCode
    size_t encode(uint8_t* p) const {
        p[0] = code;
        p[1] = msg_type;
        p[2] = seq;
        put_u16(p + 3, detail);
        return SIZE;
    }
    bool decode(const uint8_t* p, size_t n) {
        if (n != SIZE) return false;
        code = p[0];
        msg_type = p[1];
        seq = p[2];
        detail = get_u16(p + 3);
        return true;
    }
};

// ---------------------------------------------------------------------------------------------
// 4. Frames
// ---------------------------------------------------------------------------------------------

// Build the wire frame COBS(seq | type | payload | crc16 LE) + 0x00 into out (capacity cap).
// Returns its length, 0 if the payload is too long or out is too small.
inline size_t encode_frame(uint8_t seq, uint8_t type, const uint8_t* payload, size_t n,
                           uint8_t* out, size_t cap) {
    if (n > MAX_PAYLOAD) return 0;
    uint8_t raw[MAX_RAW_FRAME];
    raw[0] = seq;
    raw[1] = type;
    for (size_t k = 0; k < n; ++k) raw[2 + k] = payload[k];
    uint16_t crc = crc16(raw, n + 2);
    put_u16(raw + 2 + n, crc);
    if (cap < 1) return 0;
    size_t len = cobs_encode(raw, n + 4, out, cap - 1);
    if (len == 0) return 0;
    out[len] = 0;
    return len + 1;
}

template <typename Msg>
inline size_t encode_message(uint8_t seq, const Msg& msg, uint8_t* out, size_t cap) {
    uint8_t payload[MAX_PAYLOAD];
    size_t n = msg.encode(payload);
    return encode_frame(seq, (uint8_t)Msg::TYPE, payload, n, out, cap);
}

// Byte-at-a-time frame decoder. push() returns FRAME when a CRC-valid frame is complete (read it
// with seq()/type()/payload()/payload_len() before the next push), REJECTED when a frame was
// discarded (counters say why), NONE otherwise. Never fails; resynchronises on every 0x00.
class StreamDecoder {
  public:
    enum Result { NONE = 0, FRAME = 1, REJECTED = 2 };

    StreamDecoder() { reset(); }

    void reset() {
        len_ = 0;
        overflow_ = false;
        have_seq_ = false;
        last_seq_ = 0;
        last_gap_ = 0;
        frames_ok = bad_cobs = bad_crc = truncated = oversized = lost = discarded_bytes = 0;
    }

    // Forget the sequence history: the next frame is accepted as the new reference.
    void resync_sequence() { have_seq_ = false; }

    // The last frame starts a new sequence (a HELLO): do not count its gap as lost frames.
    void forgive_last_gap() {
        lost -= last_gap_;
        last_gap_ = 0;
    }

    Result push(uint8_t b) {
        if (b != 0) {
            if (len_ < MAX_ENCODED_FRAME) {
                buf_[len_++] = b;
            } else {
                overflow_ = true;
                ++discarded_bytes;
            }
            return NONE;
        }
        // Delimiter: finish the frame collected so far.
        size_t n = len_;
        bool overflow = overflow_;
        len_ = 0;
        overflow_ = false;
        if (overflow) {
            ++oversized;
            discarded_bytes += n;
            return REJECTED;
        }
        if (n == 0) return NONE; // consecutive delimiters are idle fill
        long raw = cobs_decode(buf_, n, buf_, MAX_ENCODED_FRAME);
        if (raw < 0) {
            ++bad_cobs;
            discarded_bytes += n;
            return REJECTED;
        }
        if (raw < 4) {
            ++truncated;
            discarded_bytes += n;
            return REJECTED;
        }
        if ((size_t)raw > MAX_RAW_FRAME) {
            ++oversized;
            discarded_bytes += n;
            return REJECTED;
        }
        size_t body = (size_t)raw - 2;
        if (crc16(buf_, body) != get_u16(buf_ + body)) {
            ++bad_crc;
            discarded_bytes += n;
            return REJECTED;
        }
        payload_len_ = body - 2;
        uint8_t seq = buf_[0];
        last_gap_ = have_seq_ ? (uint8_t)(seq - (uint8_t)(last_seq_ + 1)) : 0;
        lost += last_gap_;
        have_seq_ = true;
        last_seq_ = seq;
        ++frames_ok;
        return FRAME;
    }

    uint8_t seq() const { return buf_[0]; }
    uint8_t type() const { return buf_[1]; }
    const uint8_t* payload() const { return buf_ + 2; }
    size_t payload_len() const { return payload_len_; }
    uint8_t last_gap() const { return last_gap_; } // frames missing before the last FRAME

    uint32_t frames_ok, bad_cobs, bad_crc, truncated, oversized, lost, discarded_bytes;

  private:
    uint8_t buf_[MAX_ENCODED_FRAME];
    size_t len_;
    size_t payload_len_;
    bool overflow_;
    bool have_seq_;
    uint8_t last_seq_;
    uint8_t last_gap_;
};

// ---------------------------------------------------------------------------------------------
// 5. PID: Simulink parallel form, Forward Euler, exactly gripper_env.pid.pid_update.
// ---------------------------------------------------------------------------------------------

template <typename Real>
struct PidGains {
    Real p, i, d, n;     // deg/deg, 1/s, s, 1/s
    Real u_min, u_max;   // output limits (deg)
    uint8_t anti_windup; // AntiWindup
    Real kb;             // back-calculation gain (1/s)
    Real sign;           // +1 or -1
    bool d_on_meas;
};

// One PID sample. state[0] = xi (integral term), state[1] = xf (filtered derivative input),
// updated in place. Returns u (saturated); *v_out receives v (unsaturated) when not null.
template <typename Real>
inline Real pid_update(Real r, Real y, const PidGains<Real>& g, Real dt, Real* state,
                       Real* v_out) {
    Real e = g.sign * (r - y);
    Real s = g.d_on_meas ? -g.sign * y : e;
    Real xi = state[0];
    Real xf = state[1];
    Real deriv = g.d * g.n * (s - xf);
    Real v = g.p * e + xi + deriv;
    Real u = v;
    if (u > g.u_max) {
        u = g.u_max;
    } else if (u < g.u_min) {
        u = g.u_min;
    }
    Real ui = g.i * e;
    if (g.anti_windup == AW_CLAMPING) {
        if (u != v && ui * (v - u) > Real(0)) ui = Real(0);
    } else if (g.anti_windup == AW_BACK_CALCULATION) {
        ui += g.kb * (u - v);
    }
    state[0] = xi + dt * ui;
    state[1] = xf + dt * g.n * (s - xf);
    if (v_out) *v_out = v;
    return u;
}

// Start at rest like gripper_env.pid.PID.reset: output u0 from the integrator and, with the
// derivative on the measurement, no derivative kick at y0.
template <typename Real>
inline void pid_reset(const PidGains<Real>& g, Real u0, Real y0, Real* state) {
    state[0] = u0;
    state[1] = g.d_on_meas ? -g.sign * y0 : Real(0);
}

// ---------------------------------------------------------------------------------------------
// 6. Safety functions
// ---------------------------------------------------------------------------------------------

// Clamp a servo command (deg) into [lo, hi]. NaN goes to `safe`, which must lie in [lo, hi].
template <typename Real>
inline Real clamp_jaw(Real x, Real lo, Real hi, Real safe) {
    if (x != x) return safe;
    if (x < lo) return lo;
    if (x > hi) return hi;
    return x;
}

struct AdcCalibration {
    uint16_t adc_at_lo; // counts at CAL_ANGLE_LO_DEG
    uint16_t adc_at_hi; // counts at CAL_ANGLE_HI_DEG
};

// Measured jaw angle (deg) from ADC counts, by the two-point calibration line.
template <typename Real>
inline Real adc_to_deg(uint16_t adc, const AdcCalibration& c) {
    Real slope = (Real(CAL_ANGLE_HI_DEG) - Real(CAL_ANGLE_LO_DEG)) /
                 (Real(c.adc_at_hi) - Real(c.adc_at_lo));
    return Real(CAL_ANGLE_LO_DEG) + (Real(adc) - Real(c.adc_at_lo)) * slope;
}

// ADC counts (rounded, saturated to 0..1023) that the calibration maps to angle deg.
template <typename Real>
inline uint16_t deg_to_adc(Real deg, const AdcCalibration& c) {
    if (deg != deg) return 0;
    Real counts = Real(c.adc_at_lo) + (deg - Real(CAL_ANGLE_LO_DEG)) *
                                          (Real(c.adc_at_hi) - Real(c.adc_at_lo)) /
                                          (Real(CAL_ANGLE_HI_DEG) - Real(CAL_ANGLE_LO_DEG));
    if (!(counts > Real(0))) return 0;
    if (counts >= Real(ADC_MAX_COUNT)) return ADC_MAX_COUNT;
    return (uint16_t)(counts + Real(0.5));
}

inline bool adc_at_rail(uint16_t adc) {
    return adc < ADC_RAIL_MARGIN || adc > ADC_MAX_COUNT - ADC_RAIL_MARGIN;
}

struct ServoCalibration {
    uint16_t us_at_0;   // pulse (us) for 0 deg
    uint16_t us_at_180; // pulse (us) for 180 deg
};

// Servo pulse width in Timer1 ticks of 0.5 us for an angle (deg), clamped to the servo range
// and to the hard pulse limits whatever the calibration.
template <typename Real>
inline uint16_t servo_pulse_ticks(Real deg, const ServoCalibration& c) {
    deg = clamp_jaw(deg, Real(SERVO_MIN_DEG), Real(SERVO_MAX_DEG), Real(JAW_OPEN_DEG));
    Real us = Real(c.us_at_0) +
              deg * (Real(c.us_at_180) - Real(c.us_at_0)) / Real(SERVO_MAX_DEG - SERVO_MIN_DEG);
    Real ticks = us * Real(2) + Real(0.5);
    if (ticks < Real(2 * SERVO_PULSE_MIN_US)) return 2 * SERVO_PULSE_MIN_US;
    if (ticks > Real(2 * SERVO_PULSE_MAX_US)) return 2 * SERVO_PULSE_MAX_US;
    return (uint16_t)ticks;
}

// True once `timeout_us` has passed since `last_us`; correct across the 71-minute micros() wrap.
inline bool watchdog_expired(uint32_t now_us, uint32_t last_us, uint32_t timeout_us) {
    return (uint32_t)(now_us - last_us) >= timeout_us;
}

// ---------------------------------------------------------------------------------------------
// 7. Device
// ---------------------------------------------------------------------------------------------

// Everything CONFIGURE sets, validated, in controller units.
struct DeviceConfig {
    PidGains<real_t> gains;
    real_t jaw_min, jaw_max;
    AdcCalibration adc;
    ServoCalibration servo;
    uint16_t decimation;
    uint8_t batch;
};

inline DeviceConfig default_config() {
    DeviceConfig c;
    c.gains.p = 0;
    c.gains.i = 0;
    c.gains.d = 0;
    c.gains.n = 100;
    c.gains.u_min = JAW_CLOSED_DEG;
    c.gains.u_max = JAW_OPEN_DEG;
    c.gains.anti_windup = AW_CLAMPING;
    c.gains.kb = 1;
    c.gains.sign = 1;
    c.gains.d_on_meas = false;
    c.jaw_min = JAW_CLOSED_DEG;
    c.jaw_max = JAW_OPEN_DEG;
    c.adc.adc_at_lo = 119; // a 0-5 V pot over 0-180 deg; closed loop needs a CONFIGURE anyway
    c.adc.adc_at_hi = 523;
    c.servo.us_at_0 = SERVO_US_AT_0_DEFAULT;
    c.servo.us_at_180 = SERVO_US_AT_180_DEFAULT;
    c.decimation = 1;
    c.batch = 10;
    return c;
}

inline bool finite_f(float x) { return is_finite(x); }

inline uint16_t abs_diff_u16(uint16_t a, uint16_t b) { return a > b ? a - b : b - a; }

// Validate a CONFIGURE. On success fill *out and return true; otherwise set *bad_field to the
// first offending ConfigureField. The effective PID limits are the intersection of the
// requested limits with the jaw range, so anti-windup acts on the real actuator limits.
inline bool validate_configure(const Configure& m, DeviceConfig* out, uint16_t* bad_field) {
#define GRIPPER_REJECT(field)                                                                    \
    do {                                                                                       \
        *bad_field = (field);                                                                  \
        return false;                                                                          \
    } while (0)
    if (!finite_f(m.p)) GRIPPER_REJECT(CF_P);
    if (!finite_f(m.i)) GRIPPER_REJECT(CF_I);
    if (!finite_f(m.d)) GRIPPER_REJECT(CF_D);
    // Forward Euler filter pole 1 - N*dt must lie inside the unit circle: 0 < N*dt < 2.
    if (!finite_f(m.n) || !(m.n > 0.0f) || !(m.n * (TICK_PERIOD_US * 1e-6f) < 2.0f))
        GRIPPER_REJECT(CF_N);
    if (m.u_min != m.u_min || m.u_min == __builtin_inff()) GRIPPER_REJECT(CF_U_MIN);
    if (m.u_max != m.u_max || m.u_max == -__builtin_inff() || !(m.u_min < m.u_max))
        GRIPPER_REJECT(CF_U_MAX);
    if (!finite_f(m.kb)) GRIPPER_REJECT(CF_KB);
    if (!finite_f(m.jaw_min) || m.jaw_min < SERVO_MIN_DEG || m.jaw_min > SERVO_MAX_DEG)
        GRIPPER_REJECT(CF_JAW_MIN);
    if (!finite_f(m.jaw_max) || m.jaw_max < SERVO_MIN_DEG || m.jaw_max > SERVO_MAX_DEG ||
        !(m.jaw_min < m.jaw_max))
        GRIPPER_REJECT(CF_JAW_MAX);
    // The PID limits must overlap the jaw range.
    if (!(m.u_min < m.jaw_max)) GRIPPER_REJECT(CF_U_MIN);
    if (!(m.u_max > m.jaw_min)) GRIPPER_REJECT(CF_U_MAX);
    if (adc_at_rail(m.adc_at_lo)) GRIPPER_REJECT(CF_ADC_AT_LO);
    if (adc_at_rail(m.adc_at_hi) || abs_diff_u16(m.adc_at_lo, m.adc_at_hi) < ADC_MIN_CAL_SPAN)
        GRIPPER_REJECT(CF_ADC_AT_HI);
    if (m.servo_us_at_0 < SERVO_PULSE_MIN_US || m.servo_us_at_0 > SERVO_PULSE_MAX_US)
        GRIPPER_REJECT(CF_SERVO_US_AT_0);
    if (m.servo_us_at_180 < SERVO_PULSE_MIN_US || m.servo_us_at_180 > SERVO_PULSE_MAX_US ||
        abs_diff_u16(m.servo_us_at_0, m.servo_us_at_180) < SERVO_MIN_CAL_SPAN_US)
        GRIPPER_REJECT(CF_SERVO_US_AT_180);
    if (m.decimation > MAX_DECIMATION) GRIPPER_REJECT(CF_DECIMATION);
    if (m.anti_windup > AW_BACK_CALCULATION) GRIPPER_REJECT(CF_ANTI_WINDUP);
    if (m.sign != 1 && m.sign != -1) GRIPPER_REJECT(CF_SIGN);
    if (m.d_on_meas > 1) GRIPPER_REJECT(CF_D_ON_MEAS);
    if (m.telemetry_batch < 1 || m.telemetry_batch > TELEMETRY_MAX_SAMPLES)
        GRIPPER_REJECT(CF_TELEMETRY_BATCH);
#undef GRIPPER_REJECT
    DeviceConfig c;
    c.gains.p = m.p;
    c.gains.i = m.i;
    c.gains.d = m.d;
    c.gains.n = m.n;
    c.gains.u_min = m.u_min > m.jaw_min ? m.u_min : m.jaw_min;
    c.gains.u_max = m.u_max < m.jaw_max ? m.u_max : m.jaw_max;
    c.gains.anti_windup = m.anti_windup;
    c.gains.kb = m.kb;
    c.gains.sign = m.sign;
    c.gains.d_on_meas = m.d_on_meas != 0;
    c.jaw_min = m.jaw_min;
    c.jaw_max = m.jaw_max;
    c.adc.adc_at_lo = m.adc_at_lo;
    c.adc.adc_at_hi = m.adc_at_hi;
    c.servo.us_at_0 = m.servo_us_at_0;
    c.servo.us_at_180 = m.servo_us_at_180;
    c.decimation = m.decimation;
    c.batch = m.telemetry_batch;
    *out = c;
    return true;
}

inline uint16_t sat_u16(uint32_t v) { return v > 0xFFFF ? 0xFFFF : (uint16_t)v; }

// Transmit queue: whole frames go in or are dropped; the sketch drains it byte by byte as the
// UART has room, so the control loop never blocks on serial output.
class TxQueue {
  public:
    enum { CAPACITY = 512 };
    TxQueue() : head_(0), count_(0) {}
    size_t free_space() const { return CAPACITY - count_; }
    size_t size() const { return count_; }
    bool push(const uint8_t* data, size_t n) {
        if (n > free_space()) return false;
        for (size_t k = 0; k < n; ++k) buf_[(head_ + count_ + k) % CAPACITY] = data[k];
        count_ += n;
        return true;
    }
    uint8_t pop() {
        uint8_t b = buf_[head_];
        head_ = (head_ + 1) % CAPACITY;
        --count_;
        return b;
    }

  private:
    uint8_t buf_[CAPACITY];
    size_t head_;
    size_t count_;
};

// The device: protocol session, modes, PID, safety and telemetry. Hardware-free: the sketch feeds
// it received bytes and 1 kHz ticks with the ADC reading, applies servo_pulse_ticks() when
// servo_enabled(), and drains tx. The host harness does the same with a simulated clock.
class Device {
  public:
    Device() { begin(0xFFFFFFFFUL, 0); }

    void begin(uint32_t device_id, uint32_t now_us) {
        device_id_ = device_id;
        rx_.reset();
        tx_seq_ = 0;
        session_ = false;
        configured_ = false;
        cfg_ = default_config();
        mode_ = MODE_IDLE;
        faults_ = 0;
        servo_on_ = false;
        entry_pending_ = false;
        have_setpoint_ = false;
        setpoint_ = JAW_OPEN_DEG;
        reference_ = JAW_OPEN_DEG;
        command_ = JAW_OPEN_DEG;
        pid_state_[0] = pid_state_[1] = 0;
        last_rx_us_ = now_us;
        now_us_ = now_us;
        echo_ = 0;
        last_rx_seq_ = 0;
        refused_ = tx_dropped_ = overruns_ = 0;
        rail_ticks_ = 0;
        clear_telemetry();
    }

    // Feed one received byte at device time now_us.
    void receive(uint8_t byte, uint32_t now_us) {
        now_us_ = now_us;
        if (rx_.push(byte) == StreamDecoder::FRAME) handle_frame();
    }

    // One control period: now_us is the device time, adc the potentiometer reading taken now,
    // overrun true when this tick started late.
    void tick(uint32_t now_us, uint16_t adc, bool overrun) {
        now_us_ = now_us;
        if (overrun) ++overruns_;
        uint8_t sample_flags = overrun ? (uint8_t)SAMPLE_OVERRUN : (uint8_t)0;
        if (mode_ != MODE_IDLE && watchdog_expired(now_us, last_rx_us_, WATCHDOG_TIMEOUT_US))
            safe_stop(FAULT_WATCHDOG);
        real_t y = adc_to_deg<real_t>(adc, cfg_.adc);
        if (mode_ == MODE_CLOSED_LOOP) {
            rail_ticks_ = adc_at_rail(adc) ? rail_ticks_ + 1 : 0;
            if (rail_ticks_ >= SENSOR_FAULT_TICKS) safe_stop(FAULT_SENSOR);
        }
        if (entry_pending_) enter_mode(y);
        if (have_setpoint_ && clamp_jaw<real_t>(setpoint_, cfg_.jaw_min, cfg_.jaw_max, safe_deg()) !=
                                  setpoint_ && mode_ != MODE_IDLE)
            sample_flags |= SAMPLE_CLAMPED;
        if (mode_ == MODE_OPEN_LOOP) {
            reference_ = clamp_jaw<real_t>(setpoint_, cfg_.jaw_min, cfg_.jaw_max, safe_deg());
            command_ = reference_;
        } else if (mode_ == MODE_CLOSED_LOOP) {
            reference_ = clamp_jaw<real_t>(setpoint_, cfg_.jaw_min, cfg_.jaw_max, safe_deg());
            real_t v = 0;
            real_t u = pid_update<real_t>(reference_, y, cfg_.gains,
                                          real_t(TICK_PERIOD_US) / real_t(1000000), pid_state_, &v);
            if (!is_finite(v) || !is_finite(pid_state_[0]) || !is_finite(pid_state_[1])) {
                safe_stop(FAULT_NUMERIC);
            } else {
                if (u != v) sample_flags |= SAMPLE_SATURATED;
                command_ = clamp_jaw<real_t>(u, cfg_.jaw_min, cfg_.jaw_max, safe_deg());
            }
        }
        if (mode_ == MODE_IDLE) {
            reference_ = safe_deg();
            command_ = safe_deg();
        }
        record_sample(adc, sample_flags);
    }

    // Outputs for the sketch.
    bool servo_enabled() const { return servo_on_; }
    real_t servo_command_deg() const { return command_; }
    uint16_t servo_ticks() const { return servo_pulse_ticks<real_t>(command_, cfg_.servo); }

    // State, for STATUS and tests.
    uint8_t mode() const { return mode_; }
    uint8_t faults() const { return faults_; }
    bool session() const { return session_; }
    real_t jaw_min() const { return cfg_.jaw_min; }
    real_t jaw_max() const { return cfg_.jaw_max; }
    const StreamDecoder& decoder() const { return rx_; }

    TxQueue tx;

  private:
    real_t safe_deg() const { return cfg_.jaw_max; } // the open end of the jaw range

    // Stop controlling: mode idle, servo to the safe open position, latch `fault` (0 for none).
    void safe_stop(uint8_t fault) {
        bool was_active = mode_ != MODE_IDLE;
        mode_ = MODE_IDLE;
        entry_pending_ = false;
        command_ = safe_deg();
        reference_ = safe_deg();
        rail_ticks_ = 0;
        if (fault) {
            faults_ |= fault;
            if (was_active || fault == FAULT_ESTOP) send_status();
        }
    }

    // Finish a SET_MODE at the first tick after it, with a fresh measurement y (deg).
    void enter_mode(real_t y) {
        entry_pending_ = false;
        if (mode_ == MODE_OPEN_LOOP) {
            if (!have_setpoint_) setpoint_ = servo_on_ ? command_ : safe_deg();
        } else if (mode_ == MODE_CLOSED_LOOP) {
            if (!have_setpoint_) setpoint_ = y;
            // Bumpless: the integrator starts from the command the servo holds now.
            real_t u0 = servo_on_ ? command_ : clamp_jaw<real_t>(y, cfg_.jaw_min, cfg_.jaw_max,
                                                                 safe_deg());
            pid_reset<real_t>(cfg_.gains, u0, y, pid_state_);
        }
        have_setpoint_ = true;
        servo_on_ = true;
    }

    void handle_frame() {
        last_rx_seq_ = rx_.seq();
        last_rx_us_ = now_us_;
        uint8_t type = rx_.type();
        const uint8_t* p = rx_.payload();
        size_t n = rx_.payload_len();
        if (type == MSG_ESTOP) { // honoured with or without a session
            Estop m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            safe_stop(FAULT_ESTOP);
            return;
        }
        if (type == MSG_HELLO) {
            Hello m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            safe_stop(0);
            if (m.protocol_version != PROTOCOL_VERSION) {
                session_ = false;
                return refuse(ERR_VERSION_MISMATCH, PROTOCOL_VERSION);
            }
            start_session();
            return;
        }
        if (type >= 0x80 || type < MSG_HELLO || type > MSG_ESTOP)
            return refuse(ERR_UNKNOWN_TYPE, type);
        if (!session_) return refuse(ERR_NO_SESSION, 0);
        switch (type) {
        case MSG_CONFIGURE: {
            Configure m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            DeviceConfig c;
            uint16_t field = 0;
            if (!validate_configure(m, &c, &field)) return refuse(ERR_BAD_VALUE, field);
            apply_config(c);
            send_status();
            return;
        }
        case MSG_SET_MODE: {
            SetMode m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            if (m.mode > MODE_CLOSED_LOOP) return refuse(ERR_BAD_VALUE, 0);
            if (m.mode == MODE_IDLE) {
                safe_stop(0);
                faults_ = 0; // SET_MODE(IDLE) acknowledges latched faults
            } else {
                if (faults_) return refuse(ERR_FAULT_LATCHED, faults_);
                if (m.mode == MODE_CLOSED_LOOP && !configured_)
                    return refuse(ERR_NOT_CONFIGURED, 0);
                if (m.mode != mode_) {
                    mode_ = m.mode;
                    entry_pending_ = true;
                }
            }
            send_status();
            return;
        }
        case MSG_SETPOINT: {
            Setpoint m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            if (!finite_f(m.angle_deg)) return refuse(ERR_BAD_VALUE, 0);
            setpoint_ = m.angle_deg;
            have_setpoint_ = true;
            return;
        }
        case MSG_PROFILE_CHUNK: {
            ProfileChunk m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            return refuse(ERR_UNSUPPORTED, 0);
        }
        case MSG_HEARTBEAT: {
            Heartbeat m;
            if (!m.decode(p, n)) return refuse(ERR_BAD_LENGTH, (uint16_t)n);
            echo_ = m.token;
            send_status();
            return;
        }
        default:
            return refuse(ERR_UNKNOWN_TYPE, type);
        }
    }

    void start_session() {
        session_ = true;
        faults_ = 0;
        apply_config(default_config());
        configured_ = false; // closed loop needs a CONFIGURE in this session
        have_setpoint_ = false;
        rx_.forgive_last_gap(); // a HELLO starts a new host sequence
        Info info;
        info.protocol_version = PROTOCOL_VERSION;
        info.fw_major = FIRMWARE_VERSION_MAJOR;
        info.fw_minor = FIRMWARE_VERSION_MINOR;
        info.fw_patch = FIRMWARE_VERSION_PATCH;
        info.device_id = device_id_;
        info.tick_period_us = (uint16_t)TICK_PERIOD_US;
        info.max_batch = TELEMETRY_MAX_SAMPLES;
        info.max_payload = (uint8_t)MAX_PAYLOAD;
        send(info);
    }

    void apply_config(const DeviceConfig& c) {
        bool structure_changed = c.gains.sign != cfg_.gains.sign ||
                                 c.gains.d_on_meas != cfg_.gains.d_on_meas;
        bool telemetry_changed = c.decimation != cfg_.decimation || c.batch != cfg_.batch;
        if (telemetry_changed) flush_telemetry();
        cfg_ = c;
        configured_ = true;
        // A new sign or derivative input changes what xf means: re-enter bumplessly.
        if (structure_changed && mode_ == MODE_CLOSED_LOOP) entry_pending_ = true;
    }

    void refuse(uint8_t code, uint16_t detail) {
        ++refused_;
        Error e;
        e.code = code;
        e.msg_type = rx_.type();
        e.seq = rx_.seq();
        e.detail = detail;
        send(e);
    }

    void send_status() {
        Status s;
        s.device_time_us = now_us_;
        s.echo = echo_;
        s.mode = mode_;
        s.faults = faults_;
        s.flags = (uint8_t)((session_ ? STATUS_SESSION : 0) | (configured_ ? STATUS_CONFIGURED : 0) |
                            (servo_on_ ? STATUS_SERVO_ON : 0));
        s.last_rx_seq = last_rx_seq_;
        s.frames_ok = rx_.frames_ok;
        s.frames_lost = sat_u16(rx_.lost);
        s.bad_crc = sat_u16(rx_.bad_crc);
        s.bad_frame = sat_u16(rx_.bad_cobs + rx_.truncated + rx_.oversized);
        s.refused = sat_u16(refused_);
        s.tx_dropped = sat_u16(tx_dropped_);
        s.overruns = sat_u16(overruns_);
        send(s);
    }

    template <typename Msg>
    void send(const Msg& m) {
        uint8_t frame[MAX_WIRE_FRAME];
        size_t len = encode_message(tx_seq_, m, frame, sizeof(frame));
        // The sequence number advances even for a dropped frame, so the host sees the gap.
        ++tx_seq_;
        if (len == 0 || !tx.push(frame, len)) ++tx_dropped_;
    }

    void clear_telemetry() {
        telemetry_.count = 0;
        decimation_count_ = 0;
    }

    void flush_telemetry() {
        if (telemetry_.count > 0) send(telemetry_);
        clear_telemetry();
    }

    void record_sample(uint16_t adc, uint8_t flags) {
        if (!session_ || cfg_.decimation == 0) return;
        if (decimation_count_ > 0) {
            --decimation_count_;
            return;
        }
        decimation_count_ = (uint16_t)(cfg_.decimation - 1);
        if (telemetry_.count == 0) {
            telemetry_.t0_us = now_us_;
            telemetry_.decimation = cfg_.decimation;
        }
        TelemetrySample& s = telemetry_.samples[telemetry_.count++];
        s.reference_cdeg = to_cdeg(reference_);
        s.command_cdeg = servo_on_ ? to_cdeg(command_) : CDEG_NONE;
        s.adc = adc;
        s.flags = (uint8_t)(flags | (mode_ & SAMPLE_MODE_MASK) | (faults_ ? SAMPLE_FAULT : 0) |
                            (servo_on_ ? SAMPLE_SERVO_ON : 0));
        if (telemetry_.count >= cfg_.batch) flush_telemetry();
    }

    StreamDecoder rx_;
    Telemetry telemetry_;
    DeviceConfig cfg_;
    real_t pid_state_[2];
    real_t setpoint_, reference_, command_;
    uint32_t device_id_;
    uint32_t last_rx_us_, now_us_, echo_;
    uint32_t refused_, tx_dropped_, overruns_;
    uint16_t decimation_count_, rail_ticks_;
    uint8_t tx_seq_, mode_, faults_, last_rx_seq_;
    bool session_, configured_, servo_on_, entry_pending_, have_setpoint_;
};

} // namespace gripper

#endif // GRIPPER_CORE_H
