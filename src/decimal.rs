//! Compact, exact, allocation-free decimal text for `f64` and `f32`.
//!
//! The firmware cannot afford core's float text code (`core::num::dec2flt` and
//! `core::num::flt2dec`, about 41 KB of flash with their tables), so this module does the
//! same job with one small fixed-size bignum ([`LIMBS`] 32-bit limbs on the stack) and no
//! tables:
//!
//! * [`parse_f64`] / [`parse_f32`] read the decimal syntax of core's `str::parse` (optional
//!   sign, digits with an optional `.` fraction, optional `e`/`E` exponent with sign) and
//!   round correctly (round half to even). Inputs with at most [`MAX_DIGITS`] significant
//!   digits take Clinger's fast path when the digits and the power of ten are both exact in
//!   the type, otherwise an exact bignum quotient. `nan`/`inf`/`infinity` (any case) are
//!   refused as [`DecimalError::NotFinite`], and a finite literal beyond the type's range as
//!   [`DecimalError::Overflow`] (where core would return infinity). `f32` is parsed
//!   directly, never through `f64` (no double rounding).
//! * [`write_f64`] / [`write_f32`] (and the [`Shortest`] `Display` adaptor) write the
//!   shortest decimal that parses back to the identical value, as a plain decimal, the text
//!   of core's `{}` (the free-format Dragon4 / Burger–Dybvig algorithm, including core's
//!   choice of the closest and, on a tie, the larger digit string).
//!
//! # Exactness limit of the parser
//!
//! Up to [`MAX_DIGITS`] (40) significant digits are kept exactly (leading zeros do not
//! count); further digits only set a sticky bit ("more follows"). The result is therefore
//! the correctly rounded value for every input whose digits after the 40th significant one
//! are all zeros, at any exponent. For a longer input it is still correctly rounded unless
//! a halfway point between two adjacent floats lies strictly between the input truncated to
//! 40 digits and that truncation plus one unit in its 40th digit (halfway points have up to
//! 767 significant digits, so the input must agree with one in its first 40 digits and then
//! continue); even then the result is one of the two floats adjacent to the exact value.
//! No input panics; length and exponent are unbounded (exponents saturate far beyond the
//! range where the result is zero or overflows).
//!
//! # Output style
//!
//! Plain decimal at every magnitude, never an exponent (`0.2608`, `563`, `-0.00012`,
//! `0.000000039`, `0.00000000000039`, `1000000000`), exactly as core's `{}` prints the
//! value: digits, an optional `-` and an optional `.`; zero is `0` or `-0`, and non-finite
//! values `NaN`, `inf`, `-inf`. The longest text is that of the smallest subnormal `f64`
//! (`0.` and 323 zeros before `5`) or of `f64::MAX` (309 digits). Formatter flags (width,
//! precision) are ignored.

use core::cmp::Ordering;
use core::fmt;

/// An unsigned integer as a format argument, written in decimal (`{}` of a plain integer
/// links core's integer formatting: `Formatter::pad_integral` and a 200-byte digit table,
/// about 1 KiB of flash with the u32 and u64 routines). Formatter flags are ignored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dec(pub u64);

impl fmt::Display for Dec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        const DIGITS: &str = "0123456789";
        let mut digits = [0u8; 20];
        let mut n = self.0;
        let mut i = digits.len();
        loop {
            i -= 1;
            digits[i] = (n % 10) as u8;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        digits[i..].iter().try_for_each(|&d| {
            let d = usize::from(d);
            f.write_str(DIGITS.get(d..=d).ok_or(fmt::Error)?)
        })
    }
}

/// Significant digits the parser keeps exactly (see the module documentation).
pub const MAX_DIGITS: i64 = 40;

/// Limbs (32 bits each) of the internal bignum: 1280 bits. The largest intermediate is
/// about 1090 bits (printing the smallest subnormal `f64`); parsing needs at most about
/// 910 bits because inputs are limited to [`MAX_DIGITS`] digits and out-of-range exponents
/// are decided before any bignum arithmetic.
pub const LIMBS: usize = 40;

/// Why a decimal text was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecimalError {
    /// Not a decimal number (empty, stray characters, no digits, bad exponent).
    Invalid,
    /// `nan`, `inf` or `infinity` (any case, optional sign).
    NotFinite,
    /// A finite literal whose magnitude rounds beyond the type's largest finite value
    /// (core's parser returns infinity for it).
    Overflow,
}

impl fmt::Display for DecimalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Invalid => "bad number",
            Self::NotFinite => "NaN/inf not allowed",
            Self::Overflow => "out of range",
        })
    }
}

/// Parses `text` as an `f64`, correctly rounded (see the module documentation).
pub fn parse_f64(text: &str) -> Result<f64, DecimalError> {
    let s = scan(text)?;
    let fast = s.exact_small(1 << 53, 22).map(|(m, e)| {
        let p = (0..e.unsigned_abs()).fold(1.0f64, |p, _| p * 10.0);
        if e < 0 {
            m as f64 / p
        } else {
            m as f64 * p
        }
    });
    let mag = match fast {
        Some(v) => v,
        None => f64::from_bits(convert(&s, &F64)?),
    };
    Ok(if s.neg { -mag } else { mag })
}

/// Parses `text` as an `f32`, correctly rounded and directly (not through `f64`).
pub fn parse_f32(text: &str) -> Result<f32, DecimalError> {
    let s = scan(text)?;
    let fast = s.exact_small(1 << 24, 10).map(|(m, e)| {
        let p = (0..e.unsigned_abs()).fold(1.0f32, |p, _| p * 10.0);
        if e < 0 {
            m as f32 / p
        } else {
            m as f32 * p
        }
    });
    let mag = match fast {
        Some(v) => v,
        // The bits of a finite f32 fit in 32 bits.
        None => f32::from_bits(convert(&s, &F32)? as u32),
    };
    Ok(if s.neg { -mag } else { mag })
}

/// Writes the shortest decimal that parses back to `v` (style: module documentation).
pub fn write_f64<W: fmt::Write + ?Sized>(v: f64, out: &mut W) -> fmt::Result {
    write_bits(v.to_bits(), &F64, &mut Dyn(out))
}

/// Writes the shortest decimal that parses back to `v` as an `f32` (style: module
/// documentation).
pub fn write_f32<W: fmt::Write + ?Sized>(v: f32, out: &mut W) -> fmt::Result {
    write_bits(v.to_bits() as u64, &F32, &mut Dyn(out))
}

/// `Display` adaptor: `write!(f, "{}", Shortest(v))` writes [`write_f64`] / [`write_f32`]
/// text (formatter width and precision are ignored).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shortest<T>(pub T);

impl fmt::Display for Shortest<f64> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_f64(self.0, f)
    }
}

impl fmt::Display for Shortest<f32> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_f32(self.0, f)
    }
}

/// The shortest round-trip decimal digits of a finite value: `d.ddd * 10^exponent`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Digits {
    buf: [u8; 18],
    len: usize,
    /// The value is `0.ddd * 10^k`.
    k: i32,
}

impl Digits {
    /// The ASCII digits, first one non-zero (just `0` for zero), as core's `{:e}` prints
    /// them.
    pub fn digits(&self) -> &[u8] {
        &self.buf[..self.len.min(self.buf.len())]
    }

    /// The decimal exponent of the first digit (what core's `{:e}` prints after `e`).
    pub fn exponent(&self) -> i32 {
        self.k - 1
    }
}

/// Shortest round-trip digits of `|v|`; `None` for NaN and infinities.
pub fn shortest_f64(v: f64) -> Option<Digits> {
    shortest_bits(v.to_bits() & !(1 << 63), &F64)
}

/// Shortest round-trip digits of `|v|` as an `f32`; `None` for NaN and infinities.
pub fn shortest_f32(v: f32) -> Option<Digits> {
    shortest_bits((v.to_bits() & !(1 << 31)) as u64, &F32)
}

// ---------------------------------------------------------------------------------------
// Binary formats.

/// An IEEE 754 binary format.
struct Format {
    /// Total bits (64 or 32).
    bits: u32,
    /// Significand precision including the hidden bit (53 or 24).
    p: u32,
    /// Exponent of the smallest normal value (-1022 or -126).
    emin: i32,
    /// A literal `d * 10^(t-1)` with `t - 1 >= max_dec` (so `>= 10^max_dec`) overflows.
    max_dec: i64,
    /// A literal below `10^min_dec` is less than half the smallest subnormal: zero.
    min_dec: i64,
}

impl Format {
    /// Bits of +infinity (the first magnitude that is not finite).
    fn inf(&self) -> u64 {
        ((1u64 << (self.bits - self.p)) - 1) << (self.p - 1)
    }
}

const F64: Format = Format {
    bits: 64,
    p: 53,
    emin: -1022,
    max_dec: 309,
    min_dec: -324,
};

const F32: Format = Format {
    bits: 32,
    p: 24,
    emin: -126,
    max_dec: 39,
    min_dec: -46,
};

// ---------------------------------------------------------------------------------------
// Fixed-size bignum, little-endian 32-bit limbs. Every operation stays within `LIMBS`;
// the callers' magnitudes are bounded (see `LIMBS`), which debug builds assert.

#[derive(Clone, Copy)]
struct Big([u32; LIMBS]);

// The basic operations stay out of line: inlined into every caller they cost more flash
// than the calls.

impl Big {
    fn from_u64(v: u64) -> Self {
        let mut b = Big([0; LIMBS]);
        b.0[0] = v as u32;
        b.0[1] = (v >> 32) as u32;
        b
    }

    fn is_zero(&self) -> bool {
        self.0.iter().all(|&x| x == 0)
    }

    fn bit_len(&self) -> i32 {
        match self.0.iter().rposition(|&x| x != 0) {
            Some(i) => (i as i32 + 1) * 32 - self.0[i].leading_zeros() as i32,
            None => 0,
        }
    }

    #[inline(never)]
    fn cmp(&self, o: &Big) -> Ordering {
        self.0.iter().rev().cmp(o.0.iter().rev())
    }

    /// `self = self * m + a`.
    #[inline(never)]
    fn mul_add(&mut self, m: u32, a: u32) {
        let mut carry = a as u64;
        for x in self.0.iter_mut() {
            let t = *x as u64 * m as u64 + carry;
            *x = t as u32;
            carry = t >> 32;
        }
        debug_assert_eq!(carry, 0, "bignum overflow");
    }

    /// `self *= base^n` in steps of `base^chunk` (the largest power below 2^32).
    fn mul_pow(&mut self, base: u32, chunk: u32, mut n: u32) {
        while n > 0 {
            let t = n.min(chunk);
            self.mul_add(base.pow(t), 0);
            n -= t;
        }
    }

    fn mul_pow5(&mut self, n: u32) {
        self.mul_pow(5, 13, n);
    }

    fn mul_pow10(&mut self, n: u32) {
        self.mul_pow(10, 9, n);
    }

    #[inline(never)]
    fn add(&mut self, o: &Big) {
        let mut carry = false;
        for (x, &y) in self.0.iter_mut().zip(o.0.iter()) {
            let (s1, c1) = x.overflowing_add(y);
            let (s2, c2) = s1.overflowing_add(carry as u32);
            *x = s2;
            carry = c1 | c2;
        }
        debug_assert!(!carry, "bignum overflow");
    }

    /// `self -= o`; requires `self >= o`.
    #[inline(never)]
    fn sub(&mut self, o: &Big) {
        let mut borrow = false;
        for (x, &y) in self.0.iter_mut().zip(o.0.iter()) {
            let (d1, b1) = x.overflowing_sub(y);
            let (d2, b2) = d1.overflowing_sub(borrow as u32);
            *x = d2;
            borrow = b1 | b2;
        }
        debug_assert!(!borrow, "bignum underflow");
    }

    /// `self <<= n` bits.
    fn shl(&mut self, n: u32) {
        debug_assert!(self.bit_len() as u64 + n as u64 <= (LIMBS * 32) as u64 || self.is_zero());
        let words = (n / 32) as usize;
        let bits = n % 32;
        let src = self.0;
        for (i, x) in self.0.iter_mut().enumerate().rev() {
            let at = |j: Option<usize>| j.and_then(|j| src.get(j)).copied().unwrap_or(0);
            let hi = at(i.checked_sub(words)) << bits;
            let lo = if bits == 0 {
                0
            } else {
                at(i.checked_sub(words + 1)) >> (32 - bits)
            };
            *x = hi | lo;
        }
    }
}

// ---------------------------------------------------------------------------------------
// Parsing.

/// A scanned decimal literal: `(digits + tail) * 10^exp` with `0 <= tail < 1`, `tail > 0`
/// exactly when `sticky`.
struct Scan {
    neg: bool,
    /// The first (up to) [`MAX_DIGITS`] significant digits as an integer.
    digits: Big,
    /// The same while it has at most 19 digits (exact in u64).
    small: u64,
    /// Number of significant digits kept (0 for zero).
    n: i64,
    exp: i64,
    sticky: bool,
}

impl Scan {
    /// `(digits, exp)` when the digits are below `max_m` and `|exp| <= max_e`, so that one
    /// correctly rounded multiplication or division gives the result (Clinger).
    fn exact_small(&self, max_m: u64, max_e: i64) -> Option<(u64, i32)> {
        (!self.sticky && self.n <= 19 && self.small <= max_m && self.exp.abs() <= max_e)
            .then_some((self.small, self.exp as i32))
    }
}

fn scan(text: &str) -> Result<Scan, DecimalError> {
    let b = text.as_bytes();
    let (neg, b) = match b.split_first() {
        Some((b'-', rest)) => (true, rest),
        Some((b'+', rest)) => (false, rest),
        _ => (false, b),
    };
    if [&b"inf"[..], b"infinity", b"nan"]
        .iter()
        .any(|w| b.eq_ignore_ascii_case(w))
    {
        return Err(DecimalError::NotFinite);
    }
    let mut s = Scan {
        neg,
        digits: Big::from_u64(0),
        small: 0,
        n: 0,
        exp: 0,
        sticky: false,
    };
    let mut any = false;
    let mut point = false;
    let mut rest: &[u8] = &[];
    for (i, &c) in b.iter().enumerate() {
        match c {
            b'0'..=b'9' => {
                any = true;
                let d = (c - b'0') as u32;
                if s.n < MAX_DIGITS {
                    if s.n == 0 && d == 0 {
                        // A leading zero: only its position matters.
                    } else {
                        s.digits.mul_add(10, d);
                        s.small = s.small.wrapping_mul(10).wrapping_add(d as u64);
                        s.n += 1;
                    }
                    s.exp -= point as i64;
                } else {
                    s.sticky |= d != 0;
                    s.exp += !point as i64;
                }
            }
            b'.' if !point => point = true,
            b'e' | b'E' => {
                rest = b.get(i + 1..).unwrap_or(&[]);
                if rest.is_empty() {
                    return Err(DecimalError::Invalid);
                }
                break;
            }
            _ => return Err(DecimalError::Invalid),
        }
    }
    if !any {
        return Err(DecimalError::Invalid);
    }
    if !rest.is_empty() {
        let (eneg, digits) = match rest.split_first() {
            Some((b'-', r)) => (true, r),
            Some((b'+', r)) => (false, r),
            _ => (false, rest),
        };
        if digits.is_empty() {
            return Err(DecimalError::Invalid);
        }
        let mut e: i64 = 0;
        for &c in digits {
            if !c.is_ascii_digit() {
                return Err(DecimalError::Invalid);
            }
            // Saturate far beyond any exponent that can matter (inputs are < 2^40 bytes).
            if e < 1 << 40 {
                e = e * 10 + (c - b'0') as i64;
            }
        }
        s.exp += if eneg { -e } else { e };
    }
    Ok(s)
}

/// The magnitude bits of the correctly rounded value of `s` in format `f`.
fn convert(s: &Scan, f: &Format) -> Result<u64, DecimalError> {
    if s.n == 0 {
        return Ok(0);
    }
    // The value lies in [10^(top-1), 10^top).
    let top = s.n + s.exp;
    if top > f.max_dec {
        return Err(DecimalError::Overflow);
    }
    if top <= f.min_dec {
        return Ok(0);
    }
    // Now |exp| <= 364 for f64: value = num / den * 2^exp.
    let e = s.exp as i32;
    let mut num = s.digits;
    let mut den = Big::from_u64(1);
    if e >= 0 {
        num.mul_pow5(e as u32);
    } else {
        den.mul_pow5(e.unsigned_abs());
    }
    // Scale so that the quotient has p+2 or p+3 bits: 2^(p+1) <= num / den < 2^(p+3).
    let p = f.p as i32;
    let shift = p + 2 - num.bit_len() + den.bit_len();
    if shift >= 0 {
        num.shl(shift as u32);
    } else {
        den.shl(shift.unsigned_abs());
    }
    // Restoring division, one bit per step: den is scaled so that num / den < 2.
    den.shl(f.p + 2);
    let mut q: u64 = 0;
    for _ in 0..f.p + 3 {
        q <<= 1;
        if num.cmp(&den) != Ordering::Less {
            num.sub(&den);
            q |= 1;
        }
        num.shl(1);
    }
    round(q, e - shift, s.sticky || !num.is_zero(), f)
}

/// Rounds `(q + t) * 2^e2` to format `f` (half to even), where `0 <= t < 1` and `t > 0`
/// exactly when `sticky`; `q` has at least `p + 2` bits. Returns the magnitude bits.
fn round(q: u64, e2: i32, sticky: bool, f: &Format) -> Result<u64, DecimalError> {
    let p = f.p as i32;
    let top = e2 + 63 - q.leading_zeros() as i32;
    // Exponent of the result's last bit (fixed for subnormals).
    let lsb = top.max(f.emin) - (p - 1);
    let shift = (lsb - e2) as u32;
    if shift > 62 {
        // Below half the smallest subnormal.
        return Ok(0);
    }
    let half = 1u64 << (shift - 1);
    let rest = q & ((half << 1) - 1);
    let mut m = q >> shift;
    if rest > half || (rest == half && (sticky || m & 1 == 1)) {
        m += 1;
    }
    // A carry out of the significand (or out of the subnormal range) moves into the
    // exponent field by itself.
    let bits = (((lsb - (f.emin - (p - 1))) as u64) << (p - 1)) + m;
    if bits >= f.inf() {
        return Err(DecimalError::Overflow);
    }
    Ok(bits)
}

// ---------------------------------------------------------------------------------------
// Printing.

/// `&mut dyn Write` for any writer, so that the printing code is compiled once.
struct Dyn<'a, W: fmt::Write + ?Sized>(&'a mut W);

impl<W: fmt::Write + ?Sized> fmt::Write for Dyn<'_, W> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.0.write_str(s)
    }
}

fn write_bits(bits: u64, f: &Format, out: &mut dyn fmt::Write) -> fmt::Result {
    let sign = 1u64 << (f.bits - 1);
    let mag = bits & (sign - 1);
    if mag > f.inf() {
        return out.write_str("NaN");
    }
    if bits & sign != 0 {
        out.write_str("-")?;
    }
    let d = match shortest_bits(mag, f) {
        Some(d) => d,
        None => return out.write_str("inf"),
    };
    let digits = d.digits();
    let len = digits.len() as i32;
    let k = d.k;
    // The digits are ASCII '0'..='9': each written as its slice of a constant str, so that
    // no UTF-8 validation (core's, with its 256-byte table) is linked for them.
    const DIGITS: &str = "0123456789";
    let put = |out: &mut dyn fmt::Write, ds: &[u8]| -> fmt::Result {
        ds.iter().try_for_each(|&b| {
            let i = usize::from(b.wrapping_sub(b'0'));
            out.write_str(DIGITS.get(i..=i).ok_or(fmt::Error)?)
        })
    };
    let zeros = |out: &mut dyn fmt::Write, n: i32| -> fmt::Result {
        (0..n).try_for_each(|_| out.write_str("0"))
    };
    // Plain decimal at any magnitude (|k| <= 324 zeros at most).
    if mag == 0 {
        out.write_str("0")
    } else if k <= 0 {
        out.write_str("0.")?;
        zeros(out, -k)?;
        put(out, digits)
    } else if k < len {
        let (int, frac) = digits.split_at(k as usize);
        put(out, int)?;
        out.write_str(".")?;
        put(out, frac)
    } else {
        put(out, digits)?;
        zeros(out, k - len)
    }
}

/// `a < b`, or `a <= b` when `inclusive`.
fn below(a: &Big, b: &Big, inclusive: bool) -> bool {
    match a.cmp(b) {
        Ordering::Less => true,
        Ordering::Equal => inclusive,
        Ordering::Greater => false,
    }
}

/// Shortest digits of the non-negative magnitude `bits`: core's `flt2dec` decoding and
/// Dragon4 shortest mode (`strategy::dragon::format_shortest`), on [`Big`].
fn shortest_bits(bits: u64, f: &Format) -> Option<Digits> {
    let mut out = Digits {
        buf: [b'0'; 18],
        len: 1,
        k: 1,
    };
    if bits >= f.inf() {
        return None;
    }
    if bits == 0 {
        return Some(out);
    }
    // Decode like core: v = mant * 2^exp, neighbours at (mant - minus) and (mant + plus)
    // (halfway points), inclusive when the integer significand is even.
    let frac_bits = f.p - 1;
    let biased = (bits >> frac_bits) as i32;
    let frac = bits & ((1 << frac_bits) - 1);
    let exp = biased + f.emin - 1 - frac_bits as i32;
    let (mant, minus, plus, exp, inclusive) = if biased == 0 {
        (frac << 1, 1, 1, exp, true)
    } else if frac == 0 {
        // A power of two: the neighbour below is twice as close.
        (1 << (frac_bits + 2), 1, 2, exp - 2, true)
    } else {
        let m = frac | 1 << frac_bits;
        (m << 1, 1, 1, exp - 1, m & 1 == 0)
    };
    // Estimate k with 10^(k-1) < high <= 10^(k+1) (core's estimator).
    let high = mant + plus;
    let nbits = 64 - (high - 1).leading_zeros() as i64;
    let mut k = (((nbits + exp as i64) * 1_292_913_986) >> 32) as i32;

    // v = mant / scale, low = (mant - minus) / scale, high = (mant + plus) / scale.
    let mut mant = Big::from_u64(mant);
    let mut minus = Big::from_u64(minus);
    let mut plus = Big::from_u64(plus);
    let mut scale = Big::from_u64(1);
    if exp < 0 {
        scale.shl(exp.unsigned_abs());
    } else {
        for b in [&mut mant, &mut minus, &mut plus] {
            b.shl(exp as u32);
        }
    }
    if k >= 0 {
        scale.mul_pow10(k as u32);
    } else {
        for b in [&mut mant, &mut minus, &mut plus] {
            b.mul_pow10(k.unsigned_abs());
        }
    }
    let mut sum = mant;
    sum.add(&plus);
    if below(&scale, &sum, inclusive) {
        k += 1;
    } else {
        for b in [&mut mant, &mut minus, &mut plus] {
            b.mul_add(10, 0);
        }
    }

    let mut i = 0;
    let (down, up) = loop {
        let mut d = b'0';
        while mant.cmp(&scale) != Ordering::Less {
            mant.sub(&scale);
            d += 1;
        }
        if let Some(slot) = out.buf.get_mut(i) {
            *slot = d;
        }
        i += 1;
        let down = below(&mant, &minus, inclusive);
        let mut sum = mant;
        sum.add(&plus);
        let up = below(&scale, &sum, inclusive);
        // 17 digits always suffice for f64; the bound only guards the buffer.
        if down || up || i >= 17 {
            break (down, up);
        }
        for b in [&mut mant, &mut minus, &mut plus] {
            b.mul_add(10, 0);
        }
    };
    out.len = i;
    if up
        && (!down || {
            mant.shl(1);
            mant.cmp(&scale) != Ordering::Less
        })
    {
        // Round the digits up (ties go up, like core).
        let ds = &mut out.buf[..i];
        match ds.iter().rposition(|&c| c != b'9') {
            Some(j) => {
                ds[j] += 1;
                ds[j + 1..].fill(b'0');
            }
            None => {
                ds.fill(b'0');
                if let Some(first) = ds.first_mut() {
                    *first = b'1';
                }
                // 999 -> 1000: core appends a zero digit and raises k.
                out.buf[i] = b'0';
                out.len = i + 1;
                k += 1;
            }
        }
    }
    out.k = k;
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::string::String;

    fn text64(v: f64) -> String {
        let mut s = String::new();
        write_f64(v, &mut s).unwrap();
        s
    }

    #[test]
    fn extremes_fit_the_bignum() {
        // Debug assertions in `Big` check every operation for overflow.
        for v in [
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
            f64::from_bits((1 << 52) - 1),
            1.0,
        ] {
            assert_eq!(text64(v).parse::<f64>().unwrap(), v);
            assert_eq!(parse_f64(&text64(v)), Ok(v));
        }
        let long = "9".repeat(40);
        for e in [-400, -364, -363, -324, -323, 0, 268, 269, 270, 308, 309] {
            let t = std::format!("{long}e{e}");
            assert_eq!(
                parse_f64(&t).ok(),
                t.parse::<f64>().ok().filter(|v| v.is_finite())
            );
            let t = std::format!("1e{e}");
            assert_eq!(
                parse_f64(&t).ok(),
                t.parse::<f64>().ok().filter(|v| v.is_finite())
            );
        }
    }
}
