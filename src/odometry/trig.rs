//! Trigonometry for the per-sample path, cheap on a Cortex-M4F (single-precision FPU, fast
//! 32x32->64 integer multiply) and bit-identical on the host.
//!
//! * [`sin_cos`]: sine and cosine of a binary angle (a `u64` fraction of a turn) as Q30
//!   fixed-point numbers, from Taylor polynomials on +-pi/4 evaluated in integer arithmetic
//!   after an exact quadrant reduction. Error against f64: below [`SIN_COS_MAX_ERROR`]
//!   (2e-9) over the whole circle; `libm::sinf` would cost about 1,250 instructions on the
//!   target (it computes in f64, which is software there) and is accurate only to f32.
//! * [`chord_defect`] and [`sinc_derivative`]: the chord factor of eq (9) as
//!   `sin(x)/x = 1 - chord_defect(x)` and its derivative, as even/odd power series in f32,
//!   so the `dalpha -> 0` limit of eq (10) is reached smoothly with no branch.
//! * [`sqrt`]: a square root accurate to a few f32 ulps without `libm` (whose `sqrtf` is a
//!   software routine on this target).
//! * [`exp_neg`]: `exp(-x)` for `x >= 0`, the decay of a Gauss-Markov state over one sample:
//!   a short power series where `x` is small (every sample of a real drive), an exact
//!   power-of-two reduction beyond.

/// One full turn in binary-angle units is 2^64; this is pi/2^63, radians per unit.
pub const RAD_PER_BINARY: f64 = core::f64::consts::PI / 9_223_372_036_854_775_808.0;

/// Q30 fixed-point one.
pub const Q30_ONE: i32 = 1 << 30;

/// Largest absolute error of [`sin_cos`] against the exact values, in units of one
/// (documented bound, checked over the whole circle by the host tests).
pub const SIN_COS_MAX_ERROR: f64 = 2.0e-9;

/// pi in Q29.
const PI_Q29: i64 = 1_686_629_713;

/// `(a * b) >> 31`, rounded to nearest, for Q31 operands.
#[inline(always)]
fn mul_q31(a: i32, b: i32) -> i32 {
    ((i64::from(a) * i64::from(b) + (1 << 30)) >> 31) as i32
}

// Taylor coefficients of sin(x)/x and cos(x) in powers of x^2, Q30.
const SIN_C: [i32; 6] = [
    1_073_741_824, // 1
    -178_956_971,  // -1/6
    8_947_849,     // 1/120
    -213_044,      // -1/5040
    2_959,         // 1/362880
    -27,           // -1/39916800
];
const COS_C: [i32; 6] = [
    1_073_741_824, // 1
    -536_870_912,  // -1/2
    44_739_243,    // 1/24
    -1_491_308,    // -1/720
    26_631,        // 1/40320
    -296,          // -1/3628800
];

/// Sine and cosine of the binary angle `angle` (fraction of a turn, 2^64 = one turn, zero
/// along +y, clockwise), both in Q30 (`1 << 30` = 1.0). Error below [`SIN_COS_MAX_ERROR`].
///
/// The angle is rounded to 2^-32 turn (1.5e-9 rad), reduced exactly to `r` in
/// [-1/8, 1/8) turn and a quadrant, and the Taylor series of sin and cos to x^11 and x^10
/// are evaluated on `r` by Horner's rule in Q30/Q31 integers (truncation error < 1e-10).
pub fn sin_cos(angle: u64) -> (i32, i32) {
    let a32 = (angle.wrapping_add(1 << 31) >> 32) as u32;
    let quadrant = a32.wrapping_add(1 << 29) >> 30;
    // r in [-2^29, 2^29): units of 2^-32 turn.
    let r = a32.wrapping_sub(quadrant << 30) as i32;
    // x = r * 2 pi / 2^32 rad, in Q31: r * pi (exact product, rounded shift).
    let x = ((i64::from(r) * PI_Q29 + (1 << 28)) >> 29) as i32;
    let x2 = mul_q31(x, x);
    let mut ps = SIN_C[5];
    let mut pc = COS_C[5];
    for k in (0..5).rev() {
        ps = SIN_C[k] + mul_q31(ps, x2);
        pc = COS_C[k] + mul_q31(pc, x2);
    }
    // sin = x * ps: Q31 * Q30 >> 31 -> Q30.
    let s = mul_q31(x, ps);
    let c = pc;
    match quadrant & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Converts a Q30 number to f32.
#[inline(always)]
pub fn q30_to_f32(v: i32) -> f32 {
    v as f32 * (1.0 / Q30_ONE as f32)
}

/// `1 - sin(x)/x` for |x| <= pi/2 (x in radians): the relative shortening of the chord of an
/// arc against the arc (eq 9 with x = dalpha/2). Power series to x^10: absolute error below
/// 1e-7 at |x| = pi/2, at f32 rounding for |x| < 0.5; exactly 0 at x = 0.
#[inline(always)]
pub fn chord_defect(x: f32) -> f32 {
    let u = x * x;
    u * (1.0 / 6.0
        - u * (1.0 / 120.0 - u * (1.0 / 5040.0 - u * (1.0 / 362_880.0 - u * (1.0 / 39_916_800.0)))))
}

/// Derivative of `sin(x)/x` with respect to x for |x| <= pi/2, as a power series to x^11
/// (absolute error below 1e-7).
#[inline(always)]
pub fn sinc_derivative(x: f32) -> f32 {
    let u = x * x;
    -x * (1.0 / 3.0
        - u * (1.0 / 30.0
            - u * (1.0 / 840.0
                - u * (1.0 / 45_360.0 - u * (1.0 / 3_991_680.0 - u * (1.0 / 518_918_400.0))))))
}

/// Square root of a non-negative finite f32 (returns 0 for x <= 0), relative error below
/// 3e-7; bit-identical on every IEEE-754 machine (no libm, no FMA).
#[inline]
pub fn sqrt(x: f32) -> f32 {
    // Also catches NaN: only a positive x gets past.
    if x.partial_cmp(&0.0) != Some(core::cmp::Ordering::Greater) {
        return 0.0;
    }
    // Reciprocal square root: the classic initial estimate (3.4 % error), two Newton steps
    // (error 5e-6).
    let mut y = f32::from_bits(0x5f37_5a86 - (x.to_bits() >> 1));
    let half = 0.5 * x;
    y *= 1.5 - half * y * y;
    y *= 1.5 - half * y * y;
    // One Newton step on the square root itself squares that error away.
    let r = x * y;
    r + 0.5 * y * (x - r * r)
}

/// `exp(-x)` for `x >= 0` (0 for larger than 87, NaN or infinite `x`; 1 for `x <= 0`),
/// relative error below 3e-7.
///
/// The covariance model decays its opposite-phase slip state by `exp(-|ds_1 - ds_2| / L)`
/// per sample, and a sample's wheel-distance difference is far below the correlation length
/// (at 50 Hz, 4 cm of difference in a spin at 1 m/s, against `L` of 0.05..20 m in the
/// calibration's grid): for `x < 1/16` the series to `x^4` is exact to f32 rounding (its
/// remainder `x^5 / 120` is below 1e-8) and costs four multiply-adds. Larger `x` splits
/// `x = n ln 2 + r`, `|r| <= ln 2 / 2`, and takes `2^-n exp(-r)` (the series to `r^7`,
/// remainder below 1.3e-7), so that any setting gives a decay in `[0, 1]`.
#[inline]
pub fn exp_neg(x: f32) -> f32 {
    const SMALL: f32 = 1.0 / 16.0;
    if x < SMALL {
        // Also x <= 0.
        if x.partial_cmp(&0.0) != Some(core::cmp::Ordering::Greater) {
            return 1.0;
        }
        return 1.0 - x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0))));
    }
    // Also catches NaN and infinity.
    if x.partial_cmp(&87.0) != Some(core::cmp::Ordering::Less) {
        return 0.0;
    }
    // ln 2 split into a part whose product with n < 128 is exact in f32 (0.693359375, nine
    // significant bits) and the rest (Cody-Waite).
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let n = (x * core::f32::consts::LOG2_E + 0.5) as i32;
    let r = (x - n as f32 * LN2_HI) - n as f32 * LN2_LO;
    let e = 1.0
        - r * (1.0
            - r * (0.5
                - r * (1.0 / 6.0
                    - r * (1.0 / 24.0 - r * (1.0 / 120.0 - r * (1.0 / 720.0 - r / 5040.0))))));
    // 2^-n, n in 0..=126: a normal f32.
    e * f32::from_bits(((127 - n) as u32) << 23)
}

/// `sqrt(a^2 + b^2)`, for the small magnitudes of per-sample uncertainties.
#[inline]
pub fn hypot(a: f32, b: f32) -> f32 {
    sqrt(a * a + b * b)
}

/// `v` truncated toward zero to an integer, for finite `|v| < 2^63`, like `v as i64` but
/// in a few integer instructions: the Cortex-M4F has no f32-to-i64 conversion, and the
/// compiler's `__aeabi_f2lz` routine costs several times more. Saturates beyond the range.
#[inline]
pub fn f32_to_i64(v: f32) -> i64 {
    let bits = v.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    if exponent < 0 {
        return 0;
    }
    let magnitude = if exponent > 62 {
        i64::MAX
    } else {
        let mantissa = i64::from((bits & 0x007f_ffff) | 0x0080_0000);
        if exponent >= 23 {
            mantissa << (exponent - 23)
        } else {
            mantissa >> (23 - exponent)
        }
    };
    if bits >> 31 != 0 {
        -magnitude
    } else {
        magnitude
    }
}
