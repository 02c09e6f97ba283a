// gripper_safety.h - what keeps the jaw safe whatever the host sends: the jaw clamp, the
// potentiometer calibration and its rails, the servo pulse's hard limits, the host watchdog,
// and the finiteness test behind the NUMERIC fault.

#ifndef GRIPPER_SAFETY_H
#define GRIPPER_SAFETY_H

#include <stdint.h>
#include <string.h>

namespace gripper {

const uint32_t WATCHDOG_TIMEOUT_US = 500000; // host silence that triggers the safe stop

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

// Slope of the two-point calibration line (deg per count); the device computes it once per
// CONFIGURE, not at every tick (a soft-float division is ~500 cycles on the AVR).
template <typename Real>
inline Real adc_slope(const AdcCalibration& c) {
    return (Real(CAL_ANGLE_HI_DEG) - Real(CAL_ANGLE_LO_DEG)) /
           (Real(c.adc_at_hi) - Real(c.adc_at_lo));
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
    return Real(2) * (Real(c.us_at_180) - Real(c.us_at_0)) / Real(SERVO_MAX_DEG - SERVO_MIN_DEG);
}

// Servo pulse width in Timer1 ticks of 0.5 us for an angle (deg), clamped to the servo range
// and to the hard pulse limits whatever the calibration; rounded to the nearest tick.
template <typename Real>
inline uint16_t servo_pulse_ticks(Real deg, const ServoCalibration& c, Real ticks_per_deg) {
    deg = clamp_jaw(deg, Real(SERVO_MIN_DEG), Real(SERVO_MAX_DEG), Real(JAW_OPEN_DEG));
    Real ticks = Real(2 * (uint32_t)c.us_at_0) + deg * ticks_per_deg + Real(0.5);
    if (ticks < Real(2 * SERVO_PULSE_MIN_US)) return 2 * SERVO_PULSE_MIN_US;
    if (ticks > Real(2 * SERVO_PULSE_MAX_US)) return 2 * SERVO_PULSE_MAX_US;
    return (uint16_t)ticks;
}

template <typename Real>
inline uint16_t servo_pulse_ticks(Real deg, const ServoCalibration& c) {
    return servo_pulse_ticks<Real>(deg, c, servo_ticks_per_deg<Real>(c));
}

// True once `timeout_us` has passed since `last_us`; correct across the 71-minute micros() wrap.
inline bool watchdog_expired(uint32_t now_us, uint32_t last_us, uint32_t timeout_us) {
    return (uint32_t)(now_us - last_us) >= timeout_us;
}

} // namespace gripper

#endif // GRIPPER_SAFETY_H
