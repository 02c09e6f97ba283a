// gripper_wire.h - wire-level helpers of the serial protocol: little-endian packing, CRC-16 and
// COBS. Part of the protocol unit (with gripper_messages.h and gripper_protocol.h).
//
// Plain C++11 for avr-gcc 5.4 and the host compiler: no Arduino headers, no standard library,
// no heap. Fields are packed byte by byte, never by struct memcpy, so the layout does not depend
// on the compiler's padding or the CPU's byte order.

#ifndef GRIPPER_WIRE_H
#define GRIPPER_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

namespace gripper {

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

} // namespace gripper

#endif // GRIPPER_WIRE_H
