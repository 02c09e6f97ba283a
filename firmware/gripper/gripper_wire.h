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

#if defined(__AVR__)
#include <avr/pgmspace.h>
#define GRIPPER_FLASH PROGMEM
#define GRIPPER_FLASH_WORD(p) pgm_read_word(p)
#else
#define GRIPPER_FLASH
#define GRIPPER_FLASH_WORD(p) (*(p))
#endif

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

// CRC-16/CCITT-FALSE (poly 0x1021, not reflected) one byte at a time from a 256-entry table, in
// flash on the AVR (512 bytes), the same code on the host. Measured under simavr: the bitwise form
// compiled to ~55 cycles a byte on the AVR (16-bit shifts are loops there), the table to ~26, so
// a telemetry frame's CRC costs ~2,000 cycles instead of ~4,400.
const uint16_t CRC16_TABLE[256] GRIPPER_FLASH = {
    0x0000, 0x1021, 0x2042, 0x3063, 0x4084, 0x50A5, 0x60C6, 0x70E7,
    0x8108, 0x9129, 0xA14A, 0xB16B, 0xC18C, 0xD1AD, 0xE1CE, 0xF1EF,
    0x1231, 0x0210, 0x3273, 0x2252, 0x52B5, 0x4294, 0x72F7, 0x62D6,
    0x9339, 0x8318, 0xB37B, 0xA35A, 0xD3BD, 0xC39C, 0xF3FF, 0xE3DE,
    0x2462, 0x3443, 0x0420, 0x1401, 0x64E6, 0x74C7, 0x44A4, 0x5485,
    0xA56A, 0xB54B, 0x8528, 0x9509, 0xE5EE, 0xF5CF, 0xC5AC, 0xD58D,
    0x3653, 0x2672, 0x1611, 0x0630, 0x76D7, 0x66F6, 0x5695, 0x46B4,
    0xB75B, 0xA77A, 0x9719, 0x8738, 0xF7DF, 0xE7FE, 0xD79D, 0xC7BC,
    0x48C4, 0x58E5, 0x6886, 0x78A7, 0x0840, 0x1861, 0x2802, 0x3823,
    0xC9CC, 0xD9ED, 0xE98E, 0xF9AF, 0x8948, 0x9969, 0xA90A, 0xB92B,
    0x5AF5, 0x4AD4, 0x7AB7, 0x6A96, 0x1A71, 0x0A50, 0x3A33, 0x2A12,
    0xDBFD, 0xCBDC, 0xFBBF, 0xEB9E, 0x9B79, 0x8B58, 0xBB3B, 0xAB1A,
    0x6CA6, 0x7C87, 0x4CE4, 0x5CC5, 0x2C22, 0x3C03, 0x0C60, 0x1C41,
    0xEDAE, 0xFD8F, 0xCDEC, 0xDDCD, 0xAD2A, 0xBD0B, 0x8D68, 0x9D49,
    0x7E97, 0x6EB6, 0x5ED5, 0x4EF4, 0x3E13, 0x2E32, 0x1E51, 0x0E70,
    0xFF9F, 0xEFBE, 0xDFDD, 0xCFFC, 0xBF1B, 0xAF3A, 0x9F59, 0x8F78,
    0x9188, 0x81A9, 0xB1CA, 0xA1EB, 0xD10C, 0xC12D, 0xF14E, 0xE16F,
    0x1080, 0x00A1, 0x30C2, 0x20E3, 0x5004, 0x4025, 0x7046, 0x6067,
    0x83B9, 0x9398, 0xA3FB, 0xB3DA, 0xC33D, 0xD31C, 0xE37F, 0xF35E,
    0x02B1, 0x1290, 0x22F3, 0x32D2, 0x4235, 0x5214, 0x6277, 0x7256,
    0xB5EA, 0xA5CB, 0x95A8, 0x8589, 0xF56E, 0xE54F, 0xD52C, 0xC50D,
    0x34E2, 0x24C3, 0x14A0, 0x0481, 0x7466, 0x6447, 0x5424, 0x4405,
    0xA7DB, 0xB7FA, 0x8799, 0x97B8, 0xE75F, 0xF77E, 0xC71D, 0xD73C,
    0x26D3, 0x36F2, 0x0691, 0x16B0, 0x6657, 0x7676, 0x4615, 0x5634,
    0xD94C, 0xC96D, 0xF90E, 0xE92F, 0x99C8, 0x89E9, 0xB98A, 0xA9AB,
    0x5844, 0x4865, 0x7806, 0x6827, 0x18C0, 0x08E1, 0x3882, 0x28A3,
    0xCB7D, 0xDB5C, 0xEB3F, 0xFB1E, 0x8BF9, 0x9BD8, 0xABBB, 0xBB9A,
    0x4A75, 0x5A54, 0x6A37, 0x7A16, 0x0AF1, 0x1AD0, 0x2AB3, 0x3A92,
    0xFD2E, 0xED0F, 0xDD6C, 0xCD4D, 0xBDAA, 0xAD8B, 0x9DE8, 0x8DC9,
    0x7C26, 0x6C07, 0x5C64, 0x4C45, 0x3CA2, 0x2C83, 0x1CE0, 0x0CC1,
    0xEF1F, 0xFF3E, 0xCF5D, 0xDF7C, 0xAF9B, 0xBFBA, 0x8FD9, 0x9FF8,
    0x6E17, 0x7E36, 0x4E55, 0x5E74, 0x2E93, 0x3EB2, 0x0ED1, 0x1EF0,
};

// Always inlined: on the AVR the call alone costs as much as the table step.
#if defined(__GNUC__)
#define GRIPPER_ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define GRIPPER_ALWAYS_INLINE inline
#endif

GRIPPER_ALWAYS_INLINE uint16_t crc16_update(uint16_t crc, uint8_t data) {
    return (uint16_t)((crc << 8) ^ GRIPPER_FLASH_WORD(&CRC16_TABLE[(uint8_t)(crc >> 8) ^ data]));
}

// CRC-16/CCITT-FALSE: init 0xFFFF, xorout 0; check("123456789") == 0x29B1.
inline uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFF) {
    for (size_t i = 0; i < n; ++i) crc = crc16_update(crc, data[i]);
    return crc;
}

// The CRC register is linear in its initial value: the CRC of a message from init I is the CRC
// from init 0 XOR (I * x^(8 n) mod P), n the message's length in bytes. crc16_mulmod multiplies
// two 16-bit polynomials modulo P = x^16 + x^12 + x^5 + 1; crc16_update(1, 0) repeated n times,
// or a power of x^8 by mulmod, gives x^(8 n) mod P. The telemetry encoder uses it to finish a
// frame's CRC once its sequence number, the first byte, is known (TelemetryFrame).
inline uint16_t crc16_mulmod(uint16_t a, uint16_t b) {
    uint16_t r = 0;
    for (uint8_t k = 0; k < 16; ++k) { // a's bits from the top: r = r * x + bit * b
        bool carry = (r & 0x8000) != 0;
        r = (uint16_t)(r << 1);
        if (carry) r ^= 0x1021;
        if (a & 0x8000) r ^= b;
        a = (uint16_t)(a << 1);
    }
    return r;
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
