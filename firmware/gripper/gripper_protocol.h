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

// Saturating conversion of an angle (deg) to a centi-degree field; NaN becomes CDEG_NONE.
template <typename Real>
inline int16_t to_cdeg(Real deg) {
    if (deg != deg) return CDEG_NONE;
    Real c = deg * Real(100);
    if (c >= Real(32767)) return 32767;
    if (c <= Real(-32767)) return -32767;
    return (int16_t)(c < Real(0) ? c - Real(0.5) : c + Real(0.5));
}

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
        frames_ok = bad_cobs = bad_crc = truncated = oversized = lost = discarded_bytes = 0;
        start_frame();
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
        bool incomplete = remaining_ != 0; // the last COBS block runs past the end
        size_t raw = out_;
        uint16_t computed = crc_;
        start_frame();
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

    uint8_t seq() const { return buf_[0]; }
    uint8_t type() const { return buf_[1]; }
    const uint8_t* payload() const { return buf_ + 2; }
    size_t payload_len() const { return payload_len_; }
    uint8_t last_gap() const { return last_gap_; } // frames missing before the last FRAME

    uint32_t frames_ok, bad_cobs, bad_crc, truncated, oversized, lost, discarded_bytes;

  private:
    void start_frame() {
        len_ = 0;
        out_ = 0;
        overflow_ = false;
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
    bool have_seq_;
    uint8_t last_seq_;
    uint8_t last_gap_;
};

} // namespace gripper

#endif // GRIPPER_PROTOCOL_H
