// gripper_device.h - the device: protocol session, modes, PID, safety and telemetry, as one
// hardware-free state machine. The sketch (gripper.ino) feeds it received bytes and 1 kHz ticks
// with the ADC reading, applies its servo output and drains its transmit queue; the host harness
// (firmware/host/harness.cpp) does the same with a simulated clock, and the Python twin
// (gripper_env/hardware/firmware.py) mirrors it line for line.

#ifndef GRIPPER_DEVICE_H
#define GRIPPER_DEVICE_H

#include <stddef.h>
#include <stdint.h>

#include "gripper_pid.h"
#include "gripper_protocol.h"
#include "gripper_safety.h"

// The transmit queue is filled by the main loop and drained by the UART's interrupt on the board:
// the indices one side writes are read by the other with interrupts off (a 16-bit access is two
// instructions on the AVR). On the host there is one thread and nothing to guard.
#if defined(__AVR__)
#include <util/atomic.h>
#define GRIPPER_ATOMIC ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
#else
#define GRIPPER_ATOMIC
#endif

namespace gripper {

const uint8_t FIRMWARE_VERSION_MAJOR = 0;
const uint8_t FIRMWARE_VERSION_MINOR = 3;
const uint8_t FIRMWARE_VERSION_PATCH = 0;
const uint32_t TICK_PERIOD_US = 1000; // control period (1 kHz)
const uint16_t MAX_DECIMATION = 1000;


// Everything CONFIGURE sets, validated, in controller units.
struct DeviceConfig {
    PidGains<real_t> gains;
    real_t jaw_min, jaw_max;
    AdcCalibration adc;
    ServoCalibration servo;
    real_t adc_slope;           // deg per count, from adc (derived)
    real_t servo_base;          // 2 us_at_0 + 1/2 Timer1 ticks, from servo (derived)
    real_t servo_ticks_per_deg; // Timer1 ticks per deg, from servo (derived)
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
    c.gains.grasp = true; // a gripper's controller holds an object without stalling its servo
    c.gains.squeeze = 1;
    c.gains.push = 5;
    c.gains.shortfall = 0.5f;
    c.gains.still = 1;
    c.gains.dwell = 100;
    c.jaw_min = JAW_CLOSED_DEG;
    c.jaw_max = JAW_OPEN_DEG;
    c.adc.adc_at_lo = 119; // a 0-5 V pot over 0-180 deg; closed loop needs a CONFIGURE anyway
    c.adc.adc_at_hi = 523;
    c.servo.us_at_0 = SERVO_US_AT_0_DEFAULT;
    c.servo.us_at_180 = SERVO_US_AT_180_DEFAULT;
    c.decimation = 1;
    c.batch = 10;
    c.adc_slope = adc_slope<real_t>(c.adc);
    c.servo_base = servo_pulse_base<real_t>(c.servo);
    c.servo_ticks_per_deg = servo_ticks_per_deg<real_t>(c.servo);
    pid_prepare<real_t>(c.gains, real_t(TICK_PERIOD_US) / real_t(1000000));
    return c;
}

inline uint16_t abs_diff_u16(uint16_t a, uint16_t b) { return a > b ? a - b : b - a; }

// The grasp mode's settings: CONFIGURE's when it is on, else the defaults (unused, but never
// unchecked values).
inline void set_grasp(PidGains<real_t>& g, const Configure& m) {
    bool on = m.grasp != 0;
    g.squeeze = on ? m.grasp_squeeze_deg : 1.0f;
    g.push = on ? m.grasp_push_deg : 5.0f;
    g.shortfall = on ? m.grasp_short_deg : 0.5f;
    g.still = on ? m.grasp_still_deg : 1.0f;
    g.dwell = on ? m.grasp_dwell_ticks : 100;
}

// Report `field` as the first offending ConfigureField; always false (a rejection).
inline bool reject(uint16_t field, uint16_t* bad_field) {
    *bad_field = field;
    return false;
}

// True when a calibration (base, ticks_per_deg) gives the angle deg (in the hard jaw range) a
// pulse inside the hard window w.
inline bool pulse_inside(real_t deg, real_t base, real_t ticks_per_deg, PulseWindow w) {
    uint16_t ticks = servo_pulse_ticks_raw<real_t>(deg, base, ticks_per_deg);
    return ticks >= w.lo && ticks <= w.hi;
}

// Validate a CONFIGURE against the image's hard limits (the jaw range and the pulse window w). On
// success fill *out and return true; otherwise set *bad_field to the first offending
// ConfigureField. The effective PID limits are the intersection of the requested limits with
// the jaw range, so anti-windup acts on the real actuator limits.
inline bool validate_configure(const Configure& m, PulseWindow w, DeviceConfig* out,
                               uint16_t* bad_field) {
    if (!finite_f(m.p)) return reject(CF_P, bad_field);
    if (!finite_f(m.i)) return reject(CF_I, bad_field);
    if (!finite_f(m.d)) return reject(CF_D, bad_field);
    // Forward Euler filter pole 1 - N*dt must lie inside the unit circle: 0 < N*dt < 2.
    if (!finite_f(m.n) || !(m.n > 0.0f) || !(m.n * (TICK_PERIOD_US * 1e-6f) < 2.0f))
        return reject(CF_N, bad_field);
    if (m.u_min != m.u_min || m.u_min == __builtin_inff()) return reject(CF_U_MIN, bad_field);
    if (m.u_max != m.u_max || m.u_max == -__builtin_inff() || !(m.u_min < m.u_max))
        return reject(CF_U_MAX, bad_field);
    if (!finite_f(m.kb)) return reject(CF_KB, bad_field);
    if (!finite_f(m.jaw_min) || m.jaw_min < JAW_HARD_MIN_DEG || m.jaw_min > JAW_HARD_MAX_DEG)
        return reject(CF_JAW_MIN, bad_field);
    if (!finite_f(m.jaw_max) || m.jaw_max < JAW_HARD_MIN_DEG || m.jaw_max > JAW_HARD_MAX_DEG ||
        !(m.jaw_min < m.jaw_max))
        return reject(CF_JAW_MAX, bad_field);
    // The PID limits must overlap the jaw range.
    if (!(m.u_min < m.jaw_max)) return reject(CF_U_MIN, bad_field);
    if (!(m.u_max > m.jaw_min)) return reject(CF_U_MAX, bad_field);
    if (adc_at_rail(m.adc_at_lo)) return reject(CF_ADC_AT_LO, bad_field);
    if (adc_at_rail(m.adc_at_hi) || abs_diff_u16(m.adc_at_lo, m.adc_at_hi) < ADC_MIN_CAL_SPAN)
        return reject(CF_ADC_AT_HI, bad_field);
    if (m.servo_us_at_0 < SERVO_PULSE_MIN_US || m.servo_us_at_0 > SERVO_PULSE_MAX_US)
        return reject(CF_SERVO_US_AT_0, bad_field);
    if (m.servo_us_at_180 < SERVO_PULSE_MIN_US || m.servo_us_at_180 > SERVO_PULSE_MAX_US ||
        abs_diff_u16(m.servo_us_at_0, m.servo_us_at_180) < SERVO_MIN_CAL_SPAN_US)
        return reject(CF_SERVO_US_AT_180, bad_field);
    // The mapping must give both ends of the jaw range pulses inside the hard window (a reversed
    // or shifted mapping would move the jaw outside the hard range at a legal angle).
    ServoCalibration servo = {m.servo_us_at_0, m.servo_us_at_180};
    real_t tpd = servo_ticks_per_deg<real_t>(servo);
    real_t base = servo_pulse_base<real_t>(servo);
    if (!pulse_inside(real_t(m.jaw_min), base, tpd, w) ||
        !pulse_inside(real_t(m.jaw_max), base, tpd, w))
        return reject(CF_SERVO_US_AT_0, bad_field);
    if (m.decimation > MAX_DECIMATION) return reject(CF_DECIMATION, bad_field);
    if (m.anti_windup > AW_BACK_CALCULATION) return reject(CF_ANTI_WINDUP, bad_field);
    if (m.sign != 1 && m.sign != -1) return reject(CF_SIGN, bad_field);
    if (m.d_on_meas > 1) return reject(CF_D_ON_MEAS, bad_field);
    if (m.telemetry_batch < 1 || m.telemetry_batch > TELEMETRY_MAX_SAMPLES)
        return reject(CF_TELEMETRY_BATCH, bad_field);
    if (m.grasp > 1) return reject(CF_GRASP, bad_field);
    if (m.grasp) { // the grasp mode's settings, checked only when it is on
        if (!finite_f(m.grasp_squeeze_deg) || !(m.grasp_squeeze_deg > 0.0f))
            return reject(CF_GRASP_SQUEEZE_DEG, bad_field);
        if (!finite_f(m.grasp_push_deg) || !(m.grasp_push_deg > m.grasp_squeeze_deg))
            return reject(CF_GRASP_PUSH_DEG, bad_field);
        if (!finite_f(m.grasp_short_deg) || !(m.grasp_short_deg > 0.0f))
            return reject(CF_GRASP_SHORT_DEG, bad_field);
        if (!finite_f(m.grasp_still_deg) || !(m.grasp_still_deg > 0.0f))
            return reject(CF_GRASP_STILL_DEG, bad_field);
        if (m.grasp_dwell_ticks < 1) return reject(CF_GRASP_DWELL_TICKS, bad_field);
    }
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
    c.gains.grasp = m.grasp != 0;
    set_grasp(c.gains, m);
    c.jaw_min = m.jaw_min;
    c.jaw_max = m.jaw_max;
    c.adc.adc_at_lo = m.adc_at_lo;
    c.adc.adc_at_hi = m.adc_at_hi;
    c.servo = servo;
    c.decimation = m.decimation;
    c.batch = m.telemetry_batch;
    c.adc_slope = adc_slope<real_t>(c.adc);
    c.servo_base = base;
    c.servo_ticks_per_deg = tpd;
    pid_prepare<real_t>(c.gains, real_t(TICK_PERIOD_US) / real_t(1000000));
    *out = c;
    return true;
}

inline uint16_t sat_u16(uint32_t v) { return v > 0xFFFF ? 0xFFFF : (uint16_t)v; }

// Transmit queue: whole frames go in or are dropped. A single-producer, single-consumer ring:
// the device pushes (the main loop on the board), the UART's data-register-empty interrupt pops,
// so the control loop never blocks on serial output and a byte costs one short interrupt. Each
// side writes only its own index and reads the other's with interrupts off (GRIPPER_ATOMIC).
class TxQueue {
  public:
    enum { CAPACITY = 512, MASK = CAPACITY - 1 }; // a power of two: indices wrap with a mask
    TxQueue() : head_(0), tail_(0) {}
    size_t size() const {
        uint16_t h;
        GRIPPER_ATOMIC { h = head_; }
        return (uint16_t)(tail_ - h);
    }
    size_t free_space() const { return CAPACITY - size(); }
    // Queue n bytes (a whole wire frame), or nothing if they do not fit.
    bool push(const uint8_t* data, size_t n) {
        if (n > free_space()) return false;
        uint16_t t = tail_;
        size_t at = t & MASK;
        size_t first = n < CAPACITY - at ? n : CAPACITY - at;
        memcpy(buf_ + at, data, first);
        memcpy(buf_, data + first, n - first);
        publish((uint16_t)(t + n));
        return true;
    }
    // Queue the wire frame COBS(body | crc16 LE) + 0x00 of body = seq | type | payload (n bytes):
    // framed into a buffer on the stack (frame_body(), one pass for CRC and COBS), then copied.
    bool push_frame(const uint8_t* body, size_t n) {
        uint8_t wire[MAX_WIRE_FRAME];
        return push(wire, frame_body(body, (uint8_t)n, wire));
    }
    // The consumer: the next byte into *out, or false if the queue is empty. On the board only
    // the UART interrupt calls it (interrupts are off there).
    bool pop(uint8_t* out) {
        uint16_t h = head_;
        if (h == tail_) return false;
        *out = buf_[h & MASK];
        head_ = (uint16_t)(h + 1);
        return true;
    }

  private:
    void publish(uint16_t tail) {
        GRIPPER_ATOMIC { tail_ = tail; }
    }

    uint8_t buf_[CAPACITY];
    volatile uint16_t head_; // written by the consumer only
    volatile uint16_t tail_; // written by the producer only
};

// The device: protocol session, modes, PID, safety and telemetry. Hardware-free: the sketch feeds
// it received bytes (and tells it when bytes were lost before it), 1 kHz ticks with the ADC
// reading, applies servo_ticks() when servo_enabled(), and lets the UART drain tx. The host
// harness does the same with a simulated clock.
class Device {
  public:
    Device() { begin(0xFFFFFFFFUL, 0); }

    void begin(uint32_t device_id, uint32_t now_us) {
        device_id_ = device_id;
        window_ = hard_pulse_window<real_t>();
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
        for (uint8_t k = 0; k < PID_STATE_SIZE; ++k) pid_state_[k] = 0;
        last_rx_us_ = now_us;
        now_us_ = now_us;
        echo_ = 0;
        last_rx_seq_ = 0;
        refused_ = tx_dropped_ = overruns_ = rx_overflow_ = 0;
        rail_ticks_ = 0;
        sample_pending_ = false;
        clear_telemetry();
    }

    // Feed one received byte at device time now_us.
    void receive(uint8_t byte, uint32_t now_us) {
        if (rx_.push(byte) == StreamDecoder::FRAME) {
            now_us_ = now_us;
            handle_frame();
        }
    }

    // n host bytes were lost before the next byte fed to receive() (the receive buffer was full,
    // the UART overran): count them, and drop the frame they belonged to whatever its CRC says.
    void rx_lost(uint8_t n) {
        rx_overflow_ += n;
        rx_.abort_frame();
    }

    // One control period: control() then finish_tick(). now_us is the device time, adc the
    // potentiometer reading taken now, overrun true when this tick started late.
    void tick(uint32_t now_us, uint16_t adc, bool overrun) {
        control(now_us, adc, overrun);
        finish_tick();
    }

    // The time-critical half of a tick: safety checks, PID, servo command. The sketch applies the
    // servo output right after it, then calls finish_tick().
    void control(uint32_t now_us, uint16_t adc, bool overrun) {
        now_us_ = now_us;
        if (overrun) ++overruns_;
        uint8_t sample_flags = overrun ? (uint8_t)SAMPLE_OVERRUN : (uint8_t)0;
        if (mode_ != MODE_IDLE && watchdog_expired(now_us, last_rx_us_, WATCHDOG_TIMEOUT_US))
            safe_stop(FAULT_WATCHDOG);
        real_t y = adc_to_deg<real_t>(adc, cfg_.adc, cfg_.adc_slope);
        if (mode_ == MODE_CLOSED_LOOP) {
            rail_ticks_ = adc_at_rail(adc) ? rail_ticks_ + 1 : 0;
            if (rail_ticks_ >= SENSOR_FAULT_TICKS) safe_stop(FAULT_SENSOR);
        }
        if (entry_pending_) enter_mode(y);
        if (mode_ != MODE_IDLE) {
            reference_ = clamp_jaw<real_t>(setpoint_, cfg_.jaw_min, cfg_.jaw_max, safe_deg());
            if (have_setpoint_ && !same(reference_, setpoint_)) sample_flags |= SAMPLE_CLAMPED;
        }
        if (mode_ == MODE_OPEN_LOOP) {
            command_ = reference_;
        } else if (mode_ == MODE_CLOSED_LOOP) {
            real_t v = 0;
            real_t u = pid_update<real_t>(reference_, y, cfg_.gains,
                                          real_t(TICK_PERIOD_US) / real_t(1000000), pid_state_, &v);
            if (!is_finite(v) || !is_finite(pid_state_[PID_XI]) ||
                !is_finite(pid_state_[PID_XF]) || !is_finite(pid_state_[PID_YF])) {
                safe_stop(FAULT_NUMERIC);
            } else {
                if (!same(u, v)) sample_flags |= SAMPLE_SATURATED;
                if (pid_state_[PID_HELD] != real_t(0)) sample_flags |= SAMPLE_GRASP;
                command_ = clamp_jaw<real_t>(u, cfg_.jaw_min, cfg_.jaw_max, safe_deg());
            }
        }
        if (mode_ == MODE_IDLE) {
            reference_ = safe_deg();
            command_ = safe_deg();
        }
        take_sample(adc, sample_flags);
    }

    // The rest of a tick: encode this tick's telemetry sample into the frame being built, and
    // queue the frame once the batch is complete. Done after the servo update, it delays no
    // output.
    void finish_tick() {
        if (sample_pending_) record_sample();
    }

    // Outputs for the sketch.
    bool servo_enabled() const { return servo_on_; }
    real_t servo_command_deg() const { return command_; }
    uint16_t servo_ticks() const {
        return servo_pulse_ticks<real_t>(command_, cfg_.servo_base, cfg_.servo_ticks_per_deg,
                                         window_);
    }

    // State, for STATUS and tests.
    uint8_t mode() const { return mode_; }
    uint8_t faults() const { return faults_; }
    bool session() const { return session_; }
    real_t jaw_min() const { return cfg_.jaw_min; }
    real_t jaw_max() const { return cfg_.jaw_max; }
    PulseWindow pulse_window() const { return window_; }
    uint32_t rx_overflow() const { return rx_overflow_; }
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
        // Host frames missing before this one (a HELLO starts a new sequence): say so at once,
        // so the host can resend a command it is waiting on instead of timing out.
        if (session_ && type != MSG_HELLO && rx_.last_gap()) report_lost();
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
            if (!validate_configure(m, window_, &c, &field)) return refuse(ERR_BAD_VALUE, field);
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
        info.hard_jaw_min_deg = JAW_HARD_MIN_DEG;
        info.hard_jaw_max_deg = JAW_HARD_MAX_DEG;
        info.hard_pulse_min_us = window_.lo * 0.5f;
        info.hard_pulse_max_us = window_.hi * 0.5f;
        send(info);
    }

    void apply_config(const DeviceConfig& c) {
        bool structure_changed = c.gains.sign != cfg_.gains.sign ||
                                 c.gains.d_on_meas != cfg_.gains.d_on_meas ||
                                 c.gains.grasp != cfg_.gains.grasp;
        bool telemetry_changed = c.decimation != cfg_.decimation || c.batch != cfg_.batch;
        if (telemetry_changed) {
            flush_telemetry();
            clear_telemetry();
        }
        cfg_ = c;
        configured_ = true;
        // A new sign or derivative input changes what xf means, and the grasp mode switched on
        // or off what the state holds: re-enter bumplessly.
        if (structure_changed && mode_ == MODE_CLOSED_LOOP) entry_pending_ = true;
    }

    void refuse(uint8_t code, uint16_t detail) {
        ++refused_;
        send_error(code, rx_.type(), rx_.seq(), detail);
    }

    // FRAMES_LOST: last_gap() host frames are missing before this one (not a refusal).
    void report_lost() {
        uint8_t gap = rx_.last_gap();
        send_error(ERR_FRAMES_LOST, 0, (uint8_t)(rx_.seq() - gap), gap);
    }

    void send_error(uint8_t code, uint8_t type, uint8_t seq, uint16_t detail) {
        Error e;
        e.code = code;
        e.msg_type = type;
        e.seq = seq;
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
        s.bad_frame = sat_u16(rx_.bad_cobs + rx_.truncated + rx_.oversized + rx_.damaged);
        s.refused = sat_u16(refused_);
        s.tx_dropped = sat_u16(tx_dropped_);
        s.overruns = sat_u16(overruns_);
        s.rx_overflow = sat_u16(rx_overflow_);
        s.setpoint_deg = have_setpoint_ ? (float)setpoint_ : __builtin_nanf("");
        send(s);
    }

    // Frame and queue a message: seq | type | payload built in place, then CRC-checked and
    // COBS-encoded into the transmit queue (the bytes of encode_message()).
    template <typename Msg>
    void send(const Msg& m) {
        uint8_t body[MAX_RAW_FRAME - 2];
        body[0] = tx_seq_;
        body[1] = (uint8_t)Msg::TYPE;
        size_t n = m.encode(body + 2);
        // The sequence number advances even for a dropped frame, so the host sees the gap.
        ++tx_seq_;
        if (!tx.push_frame(body, n + 2)) ++tx_dropped_;
    }

    // Start a new telemetry batch and decimation count (telemetry settings changed, or boot).
    void clear_telemetry() {
        sample_pending_ = false;
        decimation_count_ = 0;
        telemetry_.clear();
    }

    // Queue the telemetry frame with the samples taken so far (the batch is complete, or the
    // telemetry settings change).
    void flush_telemetry() {
        if (sample_pending_) record_sample(); // control() without finish_tick(): keep its sample
        if (telemetry_.count() == 0) return;
        size_t n = telemetry_.finish(tx_seq_);
        ++tx_seq_; // as in send(): a dropped frame still takes its sequence number
        if (!tx.push(telemetry_.data(), n)) ++tx_dropped_;
    }

    // In control(): whether this tick is sampled (decimation), and its sample's state; the
    // encoding waits for finish_tick().
    void take_sample(uint16_t adc, uint8_t flags) {
        if (!session_ || cfg_.decimation == 0) return;
        if (decimation_count_ > 0) {
            --decimation_count_;
            return;
        }
        decimation_count_ = (uint16_t)(cfg_.decimation - 1);
        if (sample_pending_) record_sample(); // control() twice without finish_tick()
        pending_.t_us = now_us_;
        pending_.reference = reference_;
        pending_.command = command_;
        pending_.adc = adc;
        pending_.servo_on = servo_on_;
        pending_.flags = (uint8_t)(flags | (mode_ & SAMPLE_MODE_MASK) |
                                   (faults_ ? SAMPLE_FAULT : 0) | (servo_on_ ? SAMPLE_SERVO_ON : 0));
        sample_pending_ = true;
    }

    // Add the pending sample to the frame being built; queue the frame when the batch is full.
    void record_sample() {
        sample_pending_ = false;
        if (telemetry_.count() == 0) telemetry_.start(pending_.t_us, cfg_.decimation, cfg_.batch);
        TelemetrySample s;
        s.reference_cdeg = to_cdeg(pending_.reference);
        s.command_cdeg = pending_.servo_on ? to_cdeg(pending_.command) : CDEG_NONE;
        s.adc = pending_.adc;
        s.flags = pending_.flags;
        telemetry_.add(s);
        if (telemetry_.count() >= cfg_.batch) flush_telemetry();
    }

    // A tick's telemetry sample between control() and finish_tick().
    struct PendingSample {
        uint32_t t_us;
        real_t reference, command;
        uint16_t adc;
        uint8_t flags;
        bool servo_on;
    };

    StreamDecoder rx_;
    TelemetryFrame telemetry_;
    PendingSample pending_;
    DeviceConfig cfg_;
    PulseWindow window_;
    real_t pid_state_[PID_STATE_SIZE];
    real_t setpoint_, reference_, command_;
    uint32_t device_id_;
    uint32_t last_rx_us_, now_us_, echo_;
    uint32_t refused_, tx_dropped_, overruns_, rx_overflow_;
    uint16_t decimation_count_, rail_ticks_;
    uint8_t tx_seq_, mode_, faults_, last_rx_seq_;
    bool session_, configured_, servo_on_, entry_pending_, have_setpoint_, sample_pending_;
};

} // namespace gripper

#endif // GRIPPER_DEVICE_H
