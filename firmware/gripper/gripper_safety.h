// gripper_safety.h - what keeps the jaw safe whatever the host sends: the jaw clamp, the
// potentiometer calibration and its rails, the servo pulse's hard limits, the host watchdog,
// and the finiteness test behind the NUMERIC fault.

#ifndef GRIPPER_SAFETY_H
#define GRIPPER_SAFETY_H

#include <stdint.h>
#include <string.h>

#include "gripper_wire.h" // GRIPPER_ALWAYS_INLINE

namespace gripper {

const uint32_t WATCHDOG_TIMEOUT_US = 500000; // host silence that triggers the safe stop

// Servo and jaw geometry (deg). The jaw range is configurable, but only inside the hard range.
const float SERVO_MIN_DEG = 0.0f;
const float SERVO_MAX_DEG = 180.0f;
const float JAW_CLOSED_DEG = 21.0f; // default jaw_min: grip
const float JAW_OPEN_DEG = 92.0f;   // default jaw_max: un-grip, the safe position

// Hard limits compiled into the image: no CONFIGURE can move them. The jaw range must lie inside
// [JAW_HARD_MIN_DEG, JAW_HARD_MAX_DEG], and every servo pulse inside the pulses the servo mapping
// of the build (GRIPPER_SERVO_US_AT_0/180, the servo's true mapping) gives for those two angles:
// so a CONFIGURE with a widened jaw range or a wrong (say reversed) pulse mapping is refused, and
// the pulse is clamped into that window whatever the device computes. A rig whose jaw or servo
// differs is built with its own values, e.g. make CPPFLAGS+=-DGRIPPER_JAW_HARD_MAX_DEG=95.0f.
#ifndef GRIPPER_JAW_HARD_MIN_DEG
#define GRIPPER_JAW_HARD_MIN_DEG 21.0f
#endif
#ifndef GRIPPER_JAW_HARD_MAX_DEG
#define GRIPPER_JAW_HARD_MAX_DEG 92.0f
#endif
#ifndef GRIPPER_SERVO_US_AT_0
#define GRIPPER_SERVO_US_AT_0 544
#endif
#ifndef GRIPPER_SERVO_US_AT_180
#define GRIPPER_SERVO_US_AT_180 2400
#endif
const float JAW_HARD_MIN_DEG = GRIPPER_JAW_HARD_MIN_DEG;
const float JAW_HARD_MAX_DEG = GRIPPER_JAW_HARD_MAX_DEG;
// Two-point ADC calibration is taken at the jaw's mechanical ends.
const float CAL_ANGLE_LO_DEG = 21.0f;
const float CAL_ANGLE_HI_DEG = 92.0f;
const uint16_t ADC_MAX_COUNT = 1023;
const uint16_t ADC_RAIL_MARGIN = 4;     // readings this close to 0 or 1023 mean a broken wire
const uint16_t ADC_MIN_CAL_SPAN = 20;   // counts between the two calibration points
const uint16_t SENSOR_FAULT_TICKS = 20; // consecutive rail readings before a SENSOR fault
// Servo pulse (us): the build's mapping for 0 and 180 deg (the Servo library's 544/2400 by
// default), and the widest any calibration may name.
const uint16_t SERVO_US_AT_0_DEFAULT = GRIPPER_SERVO_US_AT_0;
const uint16_t SERVO_US_AT_180_DEFAULT = GRIPPER_SERVO_US_AT_180;
const uint16_t SERVO_PULSE_MIN_US = 400;
const uint16_t SERVO_PULSE_MAX_US = 2600;
const uint16_t SERVO_MIN_CAL_SPAN_US = 500;

template <typename Real>
inline bool is_finite(Real x) {
    // inf - inf and NaN - NaN are NaN, which compares unequal to everything.
    return (x - x) == (x - x);
}

// The same test on a float's exponent bits (all ones: infinity or NaN). On the AVR the generic form
// is two soft-float subtractions and a comparison, ~300 cycles; this is ~10.
inline bool is_finite(float x) {
    uint32_t bits;
    memcpy(&bits, &x, 4);
    return (bits & 0x7F800000UL) != 0x7F800000UL;
}

inline bool finite_f(float x) { return is_finite(x); }

// The order of floats on their bits: for non-NaN a and b, a < b exactly when
// order_key(a) < order_key(b), and a == b when the keys are equal (-0 and +0 share one). On the
// AVR a soft-float comparison is ~50 cycles, this ~10; the control path makes a dozen a tick.
inline uint32_t order_key(float x) {
    uint32_t bits;
    memcpy(&bits, &x, 4);
    if (bits & 0x80000000UL) return bits == 0x80000000UL ? bits : ~bits;
    return bits | 0x80000000UL;
}

inline bool is_nan(float x) {
    uint32_t bits;
    memcpy(&bits, &x, 4);
    return (bits & 0x7FFFFFFFUL) > 0x7F800000UL;
}

// a < b and a == b for non-NaN values (the float forms on the bits, the same answers).
template <typename Real>
inline bool less(Real a, Real b) {
    return a < b;
}
template <>
inline bool less<float>(float a, float b) {
    return order_key(a) < order_key(b);
}
template <typename Real>
inline bool same(Real a, Real b) {
    return a == b;
}
template <>
inline bool same<float>(float a, float b) {
    return order_key(a) == order_key(b);
}

// Clamp a servo command (deg) into [lo, hi] (neither NaN). NaN goes to `safe`, which must lie in
// [lo, hi].
template <typename Real>
inline Real clamp_jaw(Real x, Real lo, Real hi, Real safe) {
    if (x != x) return safe;
    if (less(x, lo)) return lo;
    if (less(hi, x)) return hi;
    return x;
}
template <>
GRIPPER_ALWAYS_INLINE float clamp_jaw<float>(float x, float lo, float hi, float safe) {
    uint32_t bx, bl, bh;
    memcpy(&bx, &x, 4);
    memcpy(&bl, &lo, 4);
    memcpy(&bh, &hi, 4);
    if (((bx | bl | bh) & 0x80000000UL) == 0) { // all three positive: the bits order like values
        if (bx > 0x7F800000UL) return safe;      // NaN
        if (bx < bl) return lo;
        if (bx > bh) return hi;
        return x;
    }
    if (is_nan(x)) return safe;
    if (less(x, lo)) return lo;
    if (less(hi, x)) return hi;
    return x;
}

struct AdcCalibration {
    uint16_t adc_at_lo; // counts at CAL_ANGLE_LO_DEG
    uint16_t adc_at_hi; // counts at CAL_ANGLE_HI_DEG
};

// Slope of the two-point calibration line (deg per count); the device computes it once per
// CONFIGURE, not at every tick (a soft-float division is ~500 cycles on the AVR).
template <typename Real>
inline Real adc_slope(const AdcCalibration& c) {
    // the difference of two counts is exact as an integer and as a float: one conversion
    return (Real(CAL_ANGLE_HI_DEG) - Real(CAL_ANGLE_LO_DEG)) /
           Real((int16_t)c.adc_at_hi - (int16_t)c.adc_at_lo);
}

// Measured jaw angle (deg) from ADC counts, by the two-point calibration line of slope `slope`.
// adc - adc_at_lo is exact in integers and in any float type, so this equals the float form.
template <typename Real>
inline Real adc_to_deg(uint16_t adc, const AdcCalibration& c, Real slope) {
    return Real(CAL_ANGLE_LO_DEG) + Real((int16_t)adc - (int16_t)c.adc_at_lo) * slope;
}

template <typename Real>
inline Real adc_to_deg(uint16_t adc, const AdcCalibration& c) {
    return adc_to_deg<Real>(adc, c, adc_slope<Real>(c));
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

// Timer1 ticks (0.5 us) per degree of the servo calibration; computed once per CONFIGURE.
template <typename Real>
inline Real servo_ticks_per_deg(const ServoCalibration& c) {
    // 2 (us_at_180 - us_at_0) is exact as an integer and as a float: one conversion
    return Real(2 * ((int32_t)c.us_at_180 - (int32_t)c.us_at_0)) /
           Real(SERVO_MAX_DEG - SERVO_MIN_DEG);
}

// The servo pulse (Timer1 ticks of 0.5 us) a calibration gives an angle (deg) in [0, 180],
// rounded to the nearest tick, before any limit: (2 us_at_0 + 1/2) + deg * ticks_per_deg,
// truncated (the first sum is exact, so the device computes it once per CONFIGURE).
template <typename Real>
inline Real servo_pulse_base(const ServoCalibration& c) {
    return Real(2 * (uint32_t)c.us_at_0) + Real(0.5);
}
template <typename Real>
inline uint16_t servo_pulse_ticks_raw(Real deg, Real base, Real ticks_per_deg) {
    return (uint16_t)(base + deg * ticks_per_deg);
}
template <typename Real>
inline uint16_t servo_pulse_ticks_raw(Real deg, const ServoCalibration& c, Real ticks_per_deg) {
    return servo_pulse_ticks_raw<Real>(deg, servo_pulse_base<Real>(c), ticks_per_deg);
}

// The hard pulse window (Timer1 ticks): the pulses of the hard jaw range under the build's mapping.
struct PulseWindow {
    uint16_t lo, hi;
};

template <typename Real>
inline PulseWindow hard_pulse_window() {
    ServoCalibration c = {SERVO_US_AT_0_DEFAULT, SERVO_US_AT_180_DEFAULT};
    Real tpd = servo_ticks_per_deg<Real>(c);
    uint16_t a = servo_pulse_ticks_raw<Real>(Real(JAW_HARD_MIN_DEG), c, tpd);
    uint16_t b = servo_pulse_ticks_raw<Real>(Real(JAW_HARD_MAX_DEG), c, tpd);
    PulseWindow w = {a < b ? a : b, a < b ? b : a};
    return w;
}

// Servo pulse width in Timer1 ticks of 0.5 us for an angle (deg): the angle clamped to the servo
// range, the pulse rounded to the nearest tick and clamped into the hard window `w` whatever the
// calibration.
template <typename Real>
inline uint16_t servo_pulse_ticks(Real deg, Real base, Real ticks_per_deg, PulseWindow w) {
    deg = clamp_jaw<Real>(deg, Real(SERVO_MIN_DEG), Real(SERVO_MAX_DEG), Real(JAW_OPEN_DEG));
    uint16_t ticks = servo_pulse_ticks_raw<Real>(deg, base, ticks_per_deg);
    if (ticks < w.lo) return w.lo;
    if (ticks > w.hi) return w.hi;
    return ticks;
}

template <typename Real>
inline uint16_t servo_pulse_ticks(Real deg, const ServoCalibration& c) {
    return servo_pulse_ticks<Real>(deg, servo_pulse_base<Real>(c), servo_ticks_per_deg<Real>(c),
                                   hard_pulse_window<Real>());
}

// True once `timeout_us` has passed since `last_us`; correct across the 71-minute micros() wrap.
inline bool watchdog_expired(uint32_t now_us, uint32_t last_us, uint32_t timeout_us) {
    return (uint32_t)(now_us - last_us) >= timeout_us;
}

} // namespace gripper

#endif // GRIPPER_SAFETY_H
