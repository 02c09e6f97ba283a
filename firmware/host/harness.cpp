// harness.cpp - drive gripper_core.h from the host, for tests/hardware.
//
// Build:  g++ -std=c++17 -O2 -Wall -Wextra -Werror -ffp-contract=off -I firmware/gripper
//             firmware/host/harness.cpp -o harness
//         (add -DGRIPPER_REAL=float for the board's arithmetic)
// Protocol: one command per line on stdin, one answer line on stdout. Byte strings are hex ("-"
// for empty), reals are C99 hex floats ("%a", also accepts decimal, inf, nan), float32 wire fields
// are the 8 hex digits of their bits. Commands:
//
//   crc HEX                      -> 4 hex digits
//   cobs_enc HEX                 -> HEX
//   cobs_dec HEX                 -> HEX | ERR
//   reencode HEX                 -> OK seq type REFRAMED_HEX field... | ERR reason
//   encode TYPE SEQ field...     -> frame HEX | ERR reason
//   pid dt P I D N umin umax aw kb sign dmeas xi0 xf0 n r1 y1 ... rn yn
//   pid_grasp dt P I D N umin umax aw kb sign dmeas squeeze push short still dwell
//             xi0 xf0 held0 at0 count0 yf0 n r1 y1 ... rn yn
//                                -> u1 v1 ... un vn xi xf
//   clamp x lo hi safe           -> real            cdeg x -> int (to_cdeg of a real)
//   adc2deg adc lo hi            -> real            deg2adc deg lo hi -> int
//   pulse deg us0 us180          -> int ticks (clamped into the hard window)
//   window                       -> lo hi (the hard pulse window, ticks)
//   wd now last timeout          -> 0 | 1
//   dev_begin id now             -> OK   (the simulated clock is set to now)
//   dev_rx HEX                   -> bytes the device transmitted, HEX
//   dev_lost n                   -> OK   (n bytes lost before the next byte received)
//   dev_tick n adc               -> SUMMARY (n ticks, 1 ms apart, constant ADC reading)
//   dev_sim n tau_ms lo hi       -> SUMMARY y (first-order servo with time constant tau_ms whose
//                                   angle is read through the calibration lo/hi)
//   dev_counters                 -> frames_ok bad_cobs bad_crc truncated oversized damaged lost
//                                   discarded rx_overflow
//
// SUMMARY = mode faults servo_on_at_end ticks_on cmd_min cmd_max pulse_min pulse_max jaw_min
//           jaw_max TX_HEX, where cmd/pulse extremes are over the ticks with the servo on.

#include "gripper_core.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <algorithm>
#include <iostream>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

using namespace gripper;

namespace {

typedef std::vector<uint8_t> Bytes;

Bytes from_hex(const std::string& s) {
    Bytes out;
    if (s == "-") return out;
    for (size_t k = 0; k + 1 < s.size(); k += 2)
        out.push_back((uint8_t)std::strtoul(s.substr(k, 2).c_str(), nullptr, 16));
    return out;
}

std::string to_hex(const uint8_t* p, size_t n) {
    if (n == 0) return "-";
    static const char* digits = "0123456789abcdef";
    std::string s;
    for (size_t k = 0; k < n; ++k) {
        s += digits[p[k] >> 4];
        s += digits[p[k] & 15];
    }
    return s;
}

std::string real_str(double x) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%a", x);
    return buf;
}

std::string f32_str(float x) {
    uint32_t bits;
    std::memcpy(&bits, &x, 4);
    char buf[16];
    std::snprintf(buf, sizeof buf, "%08x", bits);
    return buf;
}

float f32_parse(const std::string& s) {
    uint32_t bits = (uint32_t)std::strtoul(s.c_str(), nullptr, 16);
    float x;
    std::memcpy(&x, &bits, 4);
    return x;
}

double real_parse(const std::string& s) { return std::strtod(s.c_str(), nullptr); }
long int_parse(const std::string& s) { return std::strtol(s.c_str(), nullptr, 10); }

// ---- field dumps, in the order of the Python dataclass fields ----

struct Fields {
    std::vector<std::string> v;
    size_t pos = 0;
    void i(long x) { v.push_back(std::to_string(x)); }
    void f(float x) { v.push_back(f32_str(x)); }
    long gi() { return int_parse(v.at(pos++)); }
    float gf() { return f32_parse(v.at(pos++)); }
    std::string str() const {
        std::string s;
        for (const std::string& t : v) s += " " + t;
        return s;
    }
};

void dump(const Hello& m, Fields& o) { o.i(m.protocol_version); }
void load(Hello& m, Fields& o) { m.protocol_version = (uint16_t)o.gi(); }

void dump(const Configure& m, Fields& o) {
    o.f(m.p), o.f(m.i), o.f(m.d), o.f(m.n), o.f(m.u_min), o.f(m.u_max), o.f(m.kb);
    o.f(m.jaw_min), o.f(m.jaw_max);
    o.i(m.adc_at_lo), o.i(m.adc_at_hi), o.i(m.servo_us_at_0), o.i(m.servo_us_at_180);
    o.i(m.decimation), o.i(m.anti_windup), o.i(m.sign), o.i(m.d_on_meas), o.i(m.telemetry_batch);
    o.i(m.grasp), o.f(m.grasp_squeeze_deg), o.f(m.grasp_push_deg), o.f(m.grasp_short_deg);
    o.f(m.grasp_still_deg), o.i(m.grasp_dwell_ticks);
}
void load(Configure& m, Fields& o) {
    m.p = o.gf(), m.i = o.gf(), m.d = o.gf(), m.n = o.gf(), m.u_min = o.gf(), m.u_max = o.gf();
    m.kb = o.gf(), m.jaw_min = o.gf(), m.jaw_max = o.gf();
    m.adc_at_lo = (uint16_t)o.gi(), m.adc_at_hi = (uint16_t)o.gi();
    m.servo_us_at_0 = (uint16_t)o.gi(), m.servo_us_at_180 = (uint16_t)o.gi();
    m.decimation = (uint16_t)o.gi(), m.anti_windup = (uint8_t)o.gi(), m.sign = (int8_t)o.gi();
    m.d_on_meas = (uint8_t)o.gi(), m.telemetry_batch = (uint8_t)o.gi();
    m.grasp = (uint8_t)o.gi(), m.grasp_squeeze_deg = o.gf(), m.grasp_push_deg = o.gf();
    m.grasp_short_deg = o.gf(), m.grasp_still_deg = o.gf();
    m.grasp_dwell_ticks = (uint16_t)o.gi();
}

void dump(const SetMode& m, Fields& o) { o.i(m.mode); }
void load(SetMode& m, Fields& o) { m.mode = (uint8_t)o.gi(); }

void dump(const Setpoint& m, Fields& o) { o.f(m.angle_deg); }
void load(Setpoint& m, Fields& o) { m.angle_deg = o.gf(); }

void dump(const ProfileChunk& m, Fields& o) {
    o.i(m.start_index), o.i(m.total_length), o.i(m.count);
    for (uint8_t k = 0; k < m.count; ++k) o.i(m.samples_cdeg[k]);
}
void load(ProfileChunk& m, Fields& o) {
    m.start_index = (uint16_t)o.gi(), m.total_length = (uint16_t)o.gi();
    m.count = (uint8_t)o.gi();
    for (uint8_t k = 0; k < m.count; ++k) m.samples_cdeg[k] = (int16_t)o.gi();
}

void dump(const Heartbeat& m, Fields& o) { o.i(m.token); }
void load(Heartbeat& m, Fields& o) { m.token = (uint32_t)o.gi(); }

void dump(const Estop&, Fields&) {}
void load(Estop&, Fields&) {}

void dump(const Info& m, Fields& o) {
    o.i(m.protocol_version), o.i(m.fw_major), o.i(m.fw_minor), o.i(m.fw_patch);
    o.i(m.device_id), o.i(m.tick_period_us), o.i(m.max_batch), o.i(m.max_payload);
    o.f(m.hard_jaw_min_deg), o.f(m.hard_jaw_max_deg), o.f(m.hard_pulse_min_us);
    o.f(m.hard_pulse_max_us);
}
void load(Info& m, Fields& o) {
    m.protocol_version = (uint16_t)o.gi(), m.fw_major = (uint8_t)o.gi();
    m.fw_minor = (uint8_t)o.gi(), m.fw_patch = (uint8_t)o.gi();
    m.device_id = (uint32_t)o.gi(), m.tick_period_us = (uint16_t)o.gi();
    m.max_batch = (uint8_t)o.gi(), m.max_payload = (uint8_t)o.gi();
    m.hard_jaw_min_deg = o.gf(), m.hard_jaw_max_deg = o.gf(), m.hard_pulse_min_us = o.gf();
    m.hard_pulse_max_us = o.gf();
}

void dump(const Telemetry& m, Fields& o) {
    o.i(m.t0_us), o.i(m.decimation), o.i(m.count);
    for (uint8_t k = 0; k < m.count; ++k) {
        const TelemetrySample& s = m.samples[k];
        o.i(s.reference_cdeg), o.i(s.command_cdeg), o.i(s.adc), o.i(s.flags);
    }
}
void load(Telemetry& m, Fields& o) {
    m.t0_us = (uint32_t)o.gi(), m.decimation = (uint16_t)o.gi(), m.count = (uint8_t)o.gi();
    for (uint8_t k = 0; k < m.count; ++k) {
        TelemetrySample& s = m.samples[k];
        s.reference_cdeg = (int16_t)o.gi(), s.command_cdeg = (int16_t)o.gi();
        s.adc = (uint16_t)o.gi(), s.flags = (uint8_t)o.gi();
    }
}

void dump(const Status& m, Fields& o) {
    o.i(m.device_time_us), o.i(m.echo), o.i(m.mode), o.i(m.faults), o.i(m.flags);
    o.i(m.last_rx_seq), o.i(m.frames_ok), o.i(m.frames_lost), o.i(m.bad_crc);
    o.i(m.bad_frame), o.i(m.refused), o.i(m.tx_dropped), o.i(m.overruns), o.i(m.rx_overflow);
    o.f(m.setpoint_deg);
}
void load(Status& m, Fields& o) {
    m.device_time_us = (uint32_t)o.gi(), m.echo = (uint32_t)o.gi(), m.mode = (uint8_t)o.gi();
    m.faults = (uint8_t)o.gi(), m.flags = (uint8_t)o.gi(), m.last_rx_seq = (uint8_t)o.gi();
    m.frames_ok = (uint32_t)o.gi(), m.frames_lost = (uint16_t)o.gi();
    m.bad_crc = (uint16_t)o.gi(), m.bad_frame = (uint16_t)o.gi(), m.refused = (uint16_t)o.gi();
    m.tx_dropped = (uint16_t)o.gi(), m.overruns = (uint16_t)o.gi();
    m.rx_overflow = (uint16_t)o.gi(), m.setpoint_deg = o.gf();
}

void dump(const Error& m, Fields& o) {
    o.i(m.code), o.i(m.msg_type), o.i(m.seq), o.i(m.detail);
}
void load(Error& m, Fields& o) {
    m.code = (uint8_t)o.gi(), m.msg_type = (uint8_t)o.gi(), m.seq = (uint8_t)o.gi();
    m.detail = (uint16_t)o.gi();
}

// Decode payload as Msg, re-encode it with seq; "OK seq type HEX fields" or "ERR bad_payload".
template <typename Msg>
std::string reencode_as(uint8_t seq, const uint8_t* p, size_t n) {
    static Msg m; // static: ProfileChunk and Telemetry are large
    if (!m.decode(p, n)) return "ERR bad_payload";
    uint8_t frame[MAX_WIRE_FRAME];
    size_t len = encode_message(seq, m, frame, sizeof frame);
    if (len == 0) return "ERR encode";
    Fields f;
    dump(m, f);
    return "OK " + std::to_string(seq) + " " + std::to_string(Msg::TYPE) + " " +
           to_hex(frame, len) + f.str();
}

template <typename Msg>
std::string encode_from(uint8_t seq, Fields& f) {
    static Msg m;
    load(m, f);
    uint8_t frame[MAX_WIRE_FRAME];
    size_t len = encode_message(seq, m, frame, sizeof frame);
    if (len == 0) return "ERR encode";
    return to_hex(frame, len);
}

// Every message type, for dispatch on a type id (no macros: a type list and a generic lambda).
template <typename... Msgs>
struct MessageList {};
typedef MessageList<Hello, Configure, SetMode, Setpoint, ProfileChunk, Heartbeat, Estop, Info,
                    Telemetry, Status, Error>
    AllMessages;

// f(static_cast<Msg*>(nullptr)) for the message type whose TYPE is `type`, or `otherwise`.
template <typename F>
std::string dispatch(int, F, MessageList<>, const std::string& otherwise) {
    return otherwise;
}
template <typename F, typename Msg, typename... Rest>
std::string dispatch(int type, F f, MessageList<Msg, Rest...>, const std::string& otherwise) {
    if (type == Msg::TYPE) return f(static_cast<Msg*>(nullptr));
    return dispatch(type, f, MessageList<Rest...>(), otherwise);
}

std::string reencode(const Bytes& wire) {
    StreamDecoder dec;
    std::string answer = "ERR no_frame";
    int frames = 0;
    for (uint8_t b : wire) {
        StreamDecoder::Result r = dec.push(b);
        if (r == StreamDecoder::REJECTED) {
            if (dec.bad_crc) return "ERR bad_crc";
            if (dec.bad_cobs) return "ERR bad_cobs";
            if (dec.truncated) return "ERR truncated";
            return "ERR oversized";
        }
        if (r != StreamDecoder::FRAME) continue;
        if (++frames > 1) return "ERR two_frames";
        answer = dispatch(
            dec.type(),
            [&](auto* tag) {
                typedef typename std::remove_pointer<decltype(tag)>::type Msg;
                return reencode_as<Msg>(dec.seq(), dec.payload(), dec.payload_len());
            },
            AllMessages(), "ERR unknown_type");
    }
    return answer;
}

std::string encode(int type, uint8_t seq, Fields& f) {
    return dispatch(
        type,
        [&](auto* tag) {
            typedef typename std::remove_pointer<decltype(tag)>::type Msg;
            return encode_from<Msg>(seq, f);
        },
        AllMessages(), "ERR unknown_type");
}

std::string pid_run(std::istringstream& in) {
    std::string t;
    std::vector<double> a;
    while (in >> t) a.push_back(real_parse(t));
    if (a.size() < 14) return "ERR args";
    PidGains<real_t> g;
    real_t dt = (real_t)a[0];
    g.p = (real_t)a[1], g.i = (real_t)a[2], g.d = (real_t)a[3], g.n = (real_t)a[4];
    g.u_min = (real_t)a[5], g.u_max = (real_t)a[6], g.anti_windup = (uint8_t)a[7];
    g.kb = (real_t)a[8], g.sign = (real_t)a[9], g.d_on_meas = a[10] != 0;
    g.grasp = false;
    g.squeeze = g.push = g.shortfall = g.still = 0;
    g.dwell = 1;
    pid_prepare<real_t>(g, dt);
    real_t state[PID_STATE_SIZE] = {(real_t)a[11], (real_t)a[12], 0, 0, 0, 0};
    size_t n = (size_t)a[13];
    if (a.size() != 14 + 2 * n) return "ERR args";
    std::string out;
    for (size_t k = 0; k < n; ++k) {
        real_t v = 0;
        real_t u = pid_update<real_t>((real_t)a[14 + 2 * k], (real_t)a[15 + 2 * k], g, dt, state, &v);
        out += real_str(u) + " " + real_str(v) + " ";
    }
    return out + real_str(state[0]) + " " + real_str(state[1]);
}

// pid_grasp dt P I D N umin umax aw kb sign dmeas squeeze push short still dwell
//           xi0 xf0 held0 at0 count0 yf0 n r1 y1 ... rn yn
// -> "u v held" per sample, then the 6 state values
std::string pid_grasp_run(std::istringstream& in) {
    std::string t;
    std::vector<double> a;
    while (in >> t) a.push_back(real_parse(t));
    const size_t head = 23;
    if (a.size() < head) return "ERR args";
    PidGains<real_t> g;
    real_t dt = (real_t)a[0];
    g.p = (real_t)a[1], g.i = (real_t)a[2], g.d = (real_t)a[3], g.n = (real_t)a[4];
    g.u_min = (real_t)a[5], g.u_max = (real_t)a[6], g.anti_windup = (uint8_t)a[7];
    g.kb = (real_t)a[8], g.sign = (real_t)a[9], g.d_on_meas = a[10] != 0;
    g.grasp = true;
    g.squeeze = (real_t)a[11], g.push = (real_t)a[12], g.shortfall = (real_t)a[13];
    g.still = (real_t)a[14], g.dwell = (uint16_t)a[15];
    pid_prepare<real_t>(g, dt);
    real_t state[PID_STATE_SIZE];
    for (int k = 0; k < PID_STATE_SIZE; ++k) state[k] = (real_t)a[16 + k];
    size_t n = (size_t)a[22];
    if (a.size() != head + 2 * n) return "ERR args";
    std::string out;
    for (size_t k = 0; k < n; ++k) {
        real_t v = 0;
        real_t u = pid_update<real_t>((real_t)a[head + 2 * k], (real_t)a[head + 1 + 2 * k], g, dt,
                                      state, &v);
        out += real_str(u) + " " + real_str(v) + " " + real_str(state[PID_HELD]) + " ";
    }
    for (int k = 0; k < PID_STATE_SIZE; ++k) out += real_str(state[k]) + (k + 1 < PID_STATE_SIZE ? " " : "");
    return out;
}

// ---- the simulated device ----

Device device;
uint32_t now_us = 0;
double sim_y = JAW_OPEN_DEG; // angle of the simulated servo (deg), reset by dev_begin

std::string drain_tx() {
    Bytes b;
    uint8_t byte;
    while (device.tx.pop(&byte)) b.push_back(byte);
    return to_hex(b.data(), b.size());
}

struct TickSummary {
    size_t on = 0;
    double cmd_min = INFINITY, cmd_max = -INFINITY;
    long pulse_min = 1L << 30, pulse_max = -1;
    void add() {
        if (!device.servo_enabled()) return;
        ++on;
        double c = (double)device.servo_command_deg();
        long p = device.servo_ticks();
        cmd_min = std::fmin(cmd_min, c), cmd_max = std::fmax(cmd_max, c);
        // A NaN command must not hide: fmin/fmax skip NaN, so record it explicitly.
        if (c != c) cmd_min = cmd_max = NAN;
        pulse_min = std::min(pulse_min, p), pulse_max = std::max(pulse_max, p);
    }
    std::string str() {
        std::ostringstream o;
        o << (int)device.mode() << " " << (int)device.faults() << " "
          << (device.servo_enabled() ? 1 : 0) << " " << on << " " << real_str(cmd_min) << " "
          << real_str(cmd_max) << " " << pulse_min << " " << pulse_max << " "
          << real_str((double)device.jaw_min()) << " " << real_str((double)device.jaw_max())
          << " " << drain_tx();
        return o.str();
    }
};

std::string handle(const std::string& line) {
    std::istringstream in(line);
    std::string cmd;
    in >> cmd;
    std::string a, b, c, d;
    if (cmd == "crc") {
        in >> a;
        Bytes x = from_hex(a);
        char buf[8];
        std::snprintf(buf, sizeof buf, "%04x", crc16(x.data(), x.size()));
        return buf;
    }
    if (cmd == "cobs_enc") {
        in >> a;
        Bytes x = from_hex(a);
        Bytes out(x.size() + x.size() / 254 + 2);
        size_t n = cobs_encode(x.data(), x.size(), out.data(), out.size());
        return n ? to_hex(out.data(), n) : "ERR";
    }
    if (cmd == "cobs_dec") {
        in >> a;
        Bytes x = from_hex(a);
        Bytes out(x.size() + 1);
        long n = cobs_decode(x.data(), x.size(), out.data(), out.size());
        return n < 0 ? "ERR" : to_hex(out.data(), (size_t)n);
    }
    if (cmd == "reencode") {
        in >> a;
        return reencode(from_hex(a));
    }
    if (cmd == "encode") {
        long type = 0, seq = 0;
        in >> type >> seq;
        Fields f;
        while (in >> a) f.v.push_back(a);
        return encode((int)type, (uint8_t)seq, f);
    }
    if (cmd == "pid") return pid_run(in);
    if (cmd == "pid_grasp") return pid_grasp_run(in);
    if (cmd == "clamp") {
        in >> a >> b >> c >> d;
        return real_str((double)clamp_jaw<real_t>((real_t)real_parse(a), (real_t)real_parse(b),
                                                  (real_t)real_parse(c), (real_t)real_parse(d)));
    }
    if (cmd == "cdeg") {
        in >> a;
        return std::to_string(to_cdeg((real_t)real_parse(a)));
    }
    if (cmd == "adc2deg" || cmd == "deg2adc") {
        in >> a >> b >> c;
        AdcCalibration cal = {(uint16_t)int_parse(b), (uint16_t)int_parse(c)};
        if (cmd == "adc2deg") return real_str((double)adc_to_deg<real_t>((uint16_t)int_parse(a), cal));
        return std::to_string(deg_to_adc<real_t>((real_t)real_parse(a), cal));
    }
    if (cmd == "pulse") {
        in >> a >> b >> c;
        ServoCalibration cal = {(uint16_t)int_parse(b), (uint16_t)int_parse(c)};
        return std::to_string(servo_pulse_ticks<real_t>((real_t)real_parse(a), cal));
    }
    if (cmd == "window") {
        PulseWindow w = hard_pulse_window<real_t>();
        return std::to_string(w.lo) + " " + std::to_string(w.hi);
    }
    if (cmd == "wd") {
        in >> a >> b >> c;
        return watchdog_expired((uint32_t)std::strtoul(a.c_str(), nullptr, 10),
                                (uint32_t)std::strtoul(b.c_str(), nullptr, 10),
                                (uint32_t)std::strtoul(c.c_str(), nullptr, 10))
                   ? "1"
                   : "0";
    }
    if (cmd == "dev_begin") {
        in >> a >> b;
        now_us = (uint32_t)std::strtoul(b.c_str(), nullptr, 10);
        device.begin((uint32_t)std::strtoul(a.c_str(), nullptr, 10), now_us);
        sim_y = JAW_OPEN_DEG;
        return "OK";
    }
    if (cmd == "dev_rx") {
        in >> a;
        for (uint8_t byte : from_hex(a)) device.receive(byte, now_us);
        return drain_tx();
    }
    if (cmd == "dev_lost") {
        in >> a;
        device.rx_lost((uint8_t)int_parse(a));
        return "OK";
    }
    if (cmd == "dev_tick") {
        long n = 0, adc = 0;
        in >> n >> adc;
        TickSummary s;
        for (long k = 0; k < n; ++k) {
            device.tick(now_us, (uint16_t)adc, false);
            s.add();
            now_us += TICK_PERIOD_US;
        }
        return s.str();
    }
    if (cmd == "dev_sim") {
        long n = 0, lo = 0, hi = 0;
        double tau_ms = 0;
        in >> n >> tau_ms >> lo >> hi;
        AdcCalibration cal = {(uint16_t)lo, (uint16_t)hi};
        double& y = sim_y;
        TickSummary s;
        for (long k = 0; k < n; ++k) {
            device.tick(now_us, deg_to_adc<double>(y, cal), false);
            s.add();
            if (device.servo_enabled())
                y += (1.0 / tau_ms) * ((double)device.servo_command_deg() - y);
            now_us += TICK_PERIOD_US;
        }
        return s.str() + " " + real_str(y);
    }
    if (cmd == "dev_counters") {
        const StreamDecoder& r = device.decoder();
        std::ostringstream o;
        o << r.frames_ok << " " << r.bad_cobs << " " << r.bad_crc << " " << r.truncated << " "
          << r.oversized << " " << r.damaged << " " << r.lost << " " << r.discarded_bytes << " "
          << device.rx_overflow();
        return o.str();
    }
    return "ERR unknown_command";
}

} // namespace

int main() {
    std::ios::sync_with_stdio(false);
    std::string line;
    while (std::getline(std::cin, line)) {
        if (line.empty()) continue;
        std::cout << handle(line) << "\n" << std::flush;
    }
    return 0;
}
