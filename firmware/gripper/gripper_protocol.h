// gripper_protocol.h - frames of the serial protocol: the frame encoder and the byte-at-a-time
// stream decoder. The protocol unit is this file, gripper_wire.h (packing, CRC, COBS) and the
// generated gripper_messages.h (constants, enums, message codecs, from firmware/protocol.toml).
//
// The wire format is specified in firmware/PROTOCOL.md; the Python twin is
// gripper_env/hardware/protocol/ (framing.py for this file).

#ifndef GRIPPER_PROTOCOL_H
#define GRIPPER_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#include "gripper_messages.h"
#include "gripper_wire.h"

namespace gripper {

const size_t MAX_RAW_FRAME = MAX_PAYLOAD + 4;         // seq + type + payload + crc16
const size_t MAX_ENCODED_FRAME = MAX_RAW_FRAME + 2;   // COBS overhead for <= 254 bytes is 1 (+1)
const size_t MAX_WIRE_FRAME = MAX_ENCODED_FRAME + 1;  // plus the 0x00 delimiter

// x >> k for a shift counted at run time: whole bytes first. On the AVR a variable shift is a
// loop of one-bit shifts over every byte (~5 cycles a bit on 32 bits).
template <typename U>
inline U shift_right(U x, uint8_t k) {
    while (k >= 8) {
        x >>= 8;
        k = (uint8_t)(k - 8);
    }
    return x >> k;
}

// A centi-degree field from the IEEE-754 fields of an angle: sign, biased exponent e, significand
// m (hidden bit included), value = m * 2^(e - shift0). deg * 100 rounded half away from zero,
// exactly (no intermediate rounding), saturated to +-32767. m * 100 fits the unsigned type U of
// `width` bits (24-bit significands in 32 bits, 53-bit ones in 64).
template <typename U>
inline int16_t cdeg_from_fields(bool negative, int e, U m, int shift0, int width) {
    if (e == 0) return 0; // zero or subnormal: |deg| < 1e-37
    int k = shift0 - e;   // right shift that turns m * 100 into centi-degrees
    U c;
    if (k <= 0) {
        c = 32767; // huge (2^23 and more for a float) or infinite: saturated
    } else if (k > width) {
        c = 0; // m * 100 < 2^(width - 1): rounds to 0
    } else {
        // floor((x + 2^(k-1)) / 2^k) = (floor(x / 2^(k-1)) + 1) / 2: half away from zero
        c = (U)((shift_right<U>(m * 100, (uint8_t)(k - 1)) + 1) >> 1);
        if (c > 32767) c = 32767;
    }
    return negative ? (int16_t)-(int16_t)c : (int16_t)c;
}

// Saturating conversion of an angle (deg) to a centi-degree field: deg * 100 rounded half away
// from zero, exactly, saturated to +-32767; NaN becomes CDEG_NONE. Done on the float's bits: on
// the AVR the soft-float form (multiply, three comparisons, add, truncate) cost ~550 cycles a
// value, two values a telemetry sample (found under simavr). The Python twin rounds the same
// exact product (gripper_env/hardware/firmware.py).
inline int16_t to_cdeg(float deg) {
    uint32_t bits;
    memcpy(&bits, &deg, 4);
    uint8_t top = (uint8_t)(bits >> 24);
    uint8_t e = (uint8_t)((top << 1) | ((uint8_t)(bits >> 16) >> 7));
    uint32_t m = bits & 0x7FFFFFUL;
    if (e == 0xFF && m != 0) return CDEG_NONE;
    return cdeg_from_fields<uint32_t>((top & 0x80) != 0, e, m | 0x800000UL, 150, 32);
}

inline int16_t to_cdeg(double deg) {
    if (sizeof(double) == 4) return to_cdeg((float)deg); // avr-gcc: double is float
    uint64_t bits;
    memcpy(&bits, &deg, sizeof bits);
    int e = (int)((bits >> 52) & 0x7FF);
    uint64_t m = bits & 0xFFFFFFFFFFFFFULL;
    if (e == 0x7FF && m != 0) return CDEG_NONE;
    return cdeg_from_fields<uint64_t>((bits >> 63) != 0, e, m | 0x10000000000000ULL, 1075, 64);
}

// The wire frame COBS(body | crc16 LE) + 0x00 of body = seq | type | payload (n <= MAX_RAW_FRAME
// - 2 bytes) into out (MAX_WIRE_FRAME bytes): the CRC and the COBS blocks in one pass. The raw
// frame is under 254 bytes, so COBS adds exactly one byte; returns the length, n + 4.
inline uint8_t frame_body(const uint8_t* body, uint8_t n, uint8_t* out) {
    uint16_t crc = 0xFFFF;
    uint8_t o = 1, code_at = 0, code = 1;
    for (uint8_t i = 0; i < n + 2; ++i) {
        uint8_t b;
        if (i < n) {
            b = body[i];
            crc = crc16_update(crc, b);
        } else {
            b = i == n ? (uint8_t)(crc & 0xFF) : (uint8_t)(crc >> 8);
        }
        if (b != 0) {
            out[o++] = b;
            ++code;
        } else {
            out[code_at] = code;
            code = 1;
            code_at = o++;
        }
    }
    out[code_at] = code;
    out[o++] = 0;
    return o;
}

// Build the wire frame COBS(seq | type | payload | crc16 LE) + 0x00 into out (capacity cap).
// Returns its length, 0 if the payload is too long or out is too small.
inline size_t encode_frame(uint8_t seq, uint8_t type, const uint8_t* payload, size_t n,
                           uint8_t* out, size_t cap) {
    if (n > MAX_PAYLOAD || cap < n + 5) return 0;
    uint8_t body[MAX_RAW_FRAME - 2];
    body[0] = seq;
    body[1] = type;
    for (size_t k = 0; k < n; ++k) body[2 + k] = payload[k];
    return frame_body(body, (uint8_t)(n + 2), out);
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
//
// COBS decoding and the CRC run as the bytes arrive, so every push() costs about the same few
// dozen cycles, the delimiter included: the firmware's tick never waits behind the decoding of
// a long frame (found under simavr: decoding a 200-byte frame of line noise at its delimiter took
// ~9,000 cycles, and ticks started up to 480 us late during 4 KiB of random bytes). The verdict
// is exactly that of cobs_decode() then crc16() on the whole frame, checked in the same order.
class StreamDecoder {
  public:
    enum Result { NONE = 0, FRAME = 1, REJECTED = 2 };

    StreamDecoder() { reset(); }

    void reset() {
        have_seq_ = false;
        last_seq_ = 0;
        last_gap_ = 0;
        payload_len_ = 0;
        frames_ok = bad_cobs = bad_crc = truncated = oversized = damaged = lost = 0;
        discarded_bytes = 0;
        start_frame();
    }

    // Bytes were lost before this decoder (a full receive buffer, a UART overrun) right before the
    // next byte pushed: the frame they belonged to is dropped at its delimiter, whatever its CRC
    // says, and counted as damaged.
    void abort_frame() { damaged_ = true; }

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
                ++len_;
                decode_byte(b);
            } else {
                overflow_ = true;
                ++discarded_bytes;
            }
            return NONE;
        }
        // Delimiter: judge the frame collected so far.
        size_t n = len_;
        bool overflow = overflow_;
        bool damaged_frame = damaged_;
        bool incomplete = remaining_ != 0; // the last COBS block runs past the end
        size_t raw = out_;
        uint16_t computed = crc_;
        start_frame();
        if (damaged_frame) return reject(&damaged, n);
        if (overflow) return reject(&oversized, n);
        if (n == 0) return NONE; // consecutive delimiters are idle fill
        if (incomplete) return reject(&bad_cobs, n);
        if (raw < 4) return reject(&truncated, n);
        if (raw > MAX_RAW_FRAME) return reject(&oversized, n);
        if (computed != get_u16(buf_ + raw - 2)) return reject(&bad_crc, n);
        payload_len_ = raw - 4;
        uint8_t seq = buf_[0];
        last_gap_ = have_seq_ ? (uint8_t)(seq - (uint8_t)(last_seq_ + 1)) : 0;
        lost += last_gap_;
        have_seq_ = true;
        last_seq_ = seq;
        ++frames_ok;
        return FRAME;
    }

    // What a delimiter pushed now would make of the frame being received: whether it would be
    // accepted (exactly push()'s verdict), and its type. The sketch judges by them how long
    // handling the frame may take before it lets the delimiter in (a rejected one: nothing).
    bool pending_valid() const {
        return len_ > 0 && !overflow_ && !damaged_ && remaining_ == 0 && out_ >= 4 &&
               out_ <= MAX_RAW_FRAME && crc_ == get_u16(buf_ + out_ - 2);
    }
    uint8_t pending_type() const { return out_ >= 2 ? buf_[1] : 0; }

    uint8_t seq() const { return buf_[0]; }
    uint8_t type() const { return buf_[1]; }
    const uint8_t* payload() const { return buf_ + 2; }
    size_t payload_len() const { return payload_len_; }
    uint8_t last_gap() const { return last_gap_; } // frames missing before the last FRAME

    uint32_t frames_ok, bad_cobs, bad_crc, truncated, oversized, damaged, lost, discarded_bytes;

  private:
    void start_frame() {
        len_ = 0;
        out_ = 0;
        overflow_ = false;
        damaged_ = false;
        remaining_ = 0;
        code_ = 0xFF; // no block yet: no implicit zero before the first one
        crc_ = 0xFFFF;
    }

    // One decoded byte: store it; the CRC covers all but the last two (the CRC itself), so it
    // takes in the byte two places back.
    void emit(uint8_t x) {
        if (out_ >= 2) crc_ = crc16_update(crc_, buf_[out_ - 2]);
        buf_[out_++] = x;
    }

    // One non-zero encoded byte: a block's code, or data. A block of code c holds c - 1 data
    // bytes and, unless c == 0xFF, stands for a zero before the next block.
    void decode_byte(uint8_t b) {
        if (remaining_ == 0) {
            if (code_ != 0xFF) emit(0);
            code_ = b;
            remaining_ = (uint8_t)(b - 1);
        } else {
            emit(b);
            --remaining_;
        }
    }

    Result reject(uint32_t* counter, size_t n) {
        ++*counter;
        discarded_bytes += n;
        return REJECTED;
    }

    uint8_t buf_[MAX_ENCODED_FRAME];
    size_t len_;         // encoded bytes of this frame (at most MAX_ENCODED_FRAME kept)
    size_t out_;         // decoded bytes in buf_
    size_t payload_len_; // of the last FRAME
    uint16_t crc_;       // CRC of buf_[0 .. out_ - 2)
    uint8_t code_;       // code of the current COBS block
    uint8_t remaining_;  // data bytes still due in the current block
    bool overflow_;
    bool damaged_; // bytes of this frame were lost before the decoder
    bool have_seq_;
    uint8_t last_seq_;
    uint8_t last_gap_;
};

// The wire frame of one TELEMETRY message, built as its samples are taken: each add() runs the
// CRC and COBS over the sample's 7 bytes, so finishing the frame costs a few hundred cycles
// instead of encoding, checksumming and COBS-encoding ~80 bytes in one tick (found under simavr:
// 4,900 cycles in the tick that completed a batch).
//
// The frame's sequence number is its first byte and is only known when the frame is queued (other
// frames may be sent while the batch fills), so the CRC runs from 0 over the payload alone and
// finish() adds the contribution of seq and type: crc(0xFFFF, seq type payload) =
// crc(0, payload) ^ (crc(0xFFFF, seq type) * x^(8 n) mod P), n the payload length (gripper_wire.h).
// Likewise COBS: the first block holds seq and type, so its code byte and the two header bytes
// are written last, into three bytes kept free at the front. The header's sample count is
// written as the batch size; a batch finished early gets the right count patched in (a non-zero
// byte either way, so the COBS blocks do not move) and its CRC corrected by the same rule.
// The bytes are exactly encode_frame()'s (tests/hardware checks them against the Python twin).
class TelemetryFrame {
  public:
    TelemetryFrame() {
        uint16_t x56 = 1; // x^56 mod P: the CRC register after 7 zero bytes from 1
        for (uint8_t k = 0; k < Telemetry::ENTRY_SIZE; ++k) x56 = crc16_update(x56, 0);
        x56n_[0] = 1;
        for (uint8_t k = 1; k <= TELEMETRY_MAX_SAMPLES + 1; ++k)
            x56n_[k] = crc16_mulmod(x56n_[k - 1], x56);
        count_ = 0;
    }

    uint8_t count() const { return count_; }

    // Drop the samples of the frame being built.
    void clear() { count_ = 0; }

    // Begin a batch of `batch` samples (1..TELEMETRY_MAX_SAMPLES), the first taken at t0_us.
    void start(uint32_t t0_us, uint16_t decimation, uint8_t batch) {
        o_ = HEADER_BYTES;
        code_at_ = FIRST_BLOCK;
        run_ = 0;
        crc0_ = 0;
        count_ = 0;
        batch_ = batch;
        uint8_t h[Telemetry::HEADER];
        put_u32(h, t0_us);
        put_u16(h + 4, decimation);
        put(h, 6);
        count_at_ = o_; // batch is never 0: a data byte, never a block boundary
        put(&batch, 1);
    }

    // Append one sample (at most `batch` per frame).
    void add(const TelemetrySample& s) {
        uint8_t e[Telemetry::ENTRY_SIZE];
        put_i16(e, s.reference_cdeg);
        put_i16(e + 2, s.command_cdeg);
        put_u16(e + 4, s.adc);
        e[6] = s.flags;
        put(e, sizeof e);
        ++count_;
    }

    // Finish the frame (count_ >= 1 samples) with sequence number seq; returns the wire frame's
    // length (COBS bytes and the 0x00 delimiter), in data(). The next batch needs start().
    size_t finish(uint8_t seq) {
        if (count_ != batch_) { // fewer samples than the header says: patch count and CRC
            buf_[count_at_] = count_;
            crc0_ ^= crc16_mulmod(crc16_update(0, (uint8_t)(count_ ^ batch_)), x56n_[count_]);
        }
        uint16_t prefix = crc16_update(crc16_update(0xFFFF, seq), (uint8_t)Telemetry::TYPE);
        uint16_t crc = crc0_ ^ crc16_mulmod(prefix, x56n_[count_ + 1]);
        uint8_t c[2] = {(uint8_t)(crc & 0xFF), (uint8_t)(crc >> 8)};
        encode(c, 2);
        close_block();
        buf_[o_++] = 0; // delimiter
        // The first block: seq, type and the first run_ payload bytes (a zero seq ends a block
        // of its own). Both forms take the three bytes kept free.
        if (seq != 0) {
            buf_[0] = (uint8_t)(3 + first_run_);
            buf_[1] = seq;
        } else {
            buf_[0] = 1;
            buf_[1] = (uint8_t)(2 + first_run_);
        }
        buf_[2] = (uint8_t)Telemetry::TYPE;
        count_ = 0;
        return o_;
    }

    const uint8_t* data() const { return buf_; }

  private:
    enum { HEADER_BYTES = 3, FIRST_BLOCK = 0 };

    // CRC and COBS of n payload bytes, in one pass on locals (the members' loads and stores per
    // byte doubled its cost on the AVR).
    void put(const uint8_t* p, uint8_t n) {
        uint16_t crc = crc0_;
        uint8_t o = o_;
        uint8_t run = run_;
        for (uint8_t k = 0; k < n; ++k) {
            uint8_t b = p[k];
            crc = crc16_update(crc, b);
            if (b != 0) {
                buf_[o++] = b;
                ++run;
            } else {
                run_ = run;
                close_block();
                code_at_ = o++;
                run = 0;
            }
        }
        crc0_ = crc;
        o_ = o;
        run_ = run;
    }

    // COBS: a zero ends the current block (its code byte is written then) and opens the next.
    // A raw telemetry frame is under 254 bytes, so no block reaches the 254-byte limit.
    void encode(const uint8_t* p, uint8_t n) {
        for (uint8_t k = 0; k < n; ++k) {
            uint8_t b = p[k];
            if (b != 0) {
                buf_[o_++] = b;
                ++run_;
            } else {
                close_block();
                code_at_ = o_++;
                run_ = 0;
            }
        }
    }

    void close_block() {
        if (code_at_ == FIRST_BLOCK)
            first_run_ = run_;
        else
            buf_[code_at_] = (uint8_t)(run_ + 1);
    }

    uint8_t buf_[MAX_WIRE_FRAME];
    uint16_t x56n_[TELEMETRY_MAX_SAMPLES + 2]; // x^(56 k) mod P: 7 k bytes of payload
    uint16_t crc0_;                            // CRC from 0 of the payload so far
    uint8_t o_, code_at_, run_, first_run_, count_at_, count_, batch_;
};

static_assert(4 + Telemetry::HEADER + Telemetry::ENTRY_SIZE * TELEMETRY_MAX_SAMPLES < 254,
              "a raw telemetry frame must fit one COBS block");
static_assert(MAX_WIRE_FRAME <= 255, "TelemetryFrame indexes its buffer with a u8");

} // namespace gripper

#endif // GRIPPER_PROTOCOL_H
