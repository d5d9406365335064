//! `odo_unit::decimal` against std: shortest digits and round trips over arbitrary bit
//! patterns, correctly rounded parsing of random and exactly-halfway decimal strings, the
//! accepted syntax, boundary tables, and no panic on any input.

use odo_unit::decimal::*;
use proptest::prelude::*;

/// The text std's `{}` gives: a plain decimal at every magnitude, never an exponent.
fn plain64(v: f64) -> String {
    format!("{v}")
}

fn plain32(v: f32) -> String {
    format!("{v}")
}

/// Plain decimal syntax: an optional `-`, digits, an optional `.` and digits.
fn is_plain(text: &str) -> bool {
    let t = text.strip_prefix('-').unwrap_or(text);
    let mut parts = t.splitn(2, '.');
    let int = parts.next().unwrap_or("");
    let frac = parts.next();
    !int.is_empty()
        && int.bytes().all(|b| b.is_ascii_digit())
        && frac.is_none_or(|f| !f.is_empty() && f.bytes().all(|b| b.is_ascii_digit()))
}

/// Digits and exponent of std's `{:e}` of a finite non-negative value.
fn std_digits(e_text: &str) -> (String, i32) {
    let (m, e) = e_text.split_once('e').unwrap();
    (m.replace('.', ""), e.parse().unwrap())
}

fn check_f64(v: f64) -> Result<(), TestCaseError> {
    let text = Shortest(v).to_string();
    prop_assert_eq!(&text, &plain64(v), "style of {:e}", v);
    if !v.is_finite() {
        prop_assert!(shortest_f64(v).is_none());
        return Ok(());
    }
    prop_assert!(is_plain(&text), "{}", text);
    let d = shortest_f64(v).unwrap();
    let (digits, exp) = std_digits(&format!("{:e}", v.abs()));
    prop_assert_eq!(std::str::from_utf8(d.digits()).unwrap(), digits.as_str());
    prop_assert_eq!(d.exponent(), exp);
    prop_assert_eq!(text.parse::<f64>().unwrap().to_bits(), v.to_bits());
    prop_assert_eq!(
        parse_f64(&text).map(f64::to_bits),
        Ok(v.to_bits()),
        "{}",
        text
    );
    Ok(())
}

fn check_f32(v: f32) -> Result<(), TestCaseError> {
    let text = Shortest(v).to_string();
    prop_assert_eq!(&text, &plain32(v), "style of {:e}", v);
    if !v.is_finite() {
        prop_assert!(shortest_f32(v).is_none());
        return Ok(());
    }
    prop_assert!(is_plain(&text), "{}", text);
    let d = shortest_f32(v).unwrap();
    let (digits, exp) = std_digits(&format!("{:e}", v.abs()));
    prop_assert_eq!(std::str::from_utf8(d.digits()).unwrap(), digits.as_str());
    prop_assert_eq!(d.exponent(), exp);
    prop_assert_eq!(text.parse::<f32>().unwrap().to_bits(), v.to_bits());
    prop_assert_eq!(
        parse_f32(&text).map(f32::to_bits),
        Ok(v.to_bits()),
        "{}",
        text
    );
    Ok(())
}

/// std's parse as this module reports it: a finite value, or the error it must give.
fn std64(text: &str) -> Result<u64, DecimalError> {
    match text.parse::<f64>() {
        Err(_) => Err(DecimalError::Invalid),
        Ok(v) if v.is_nan() || is_word(text) => Err(DecimalError::NotFinite),
        Ok(v) if v.is_infinite() => Err(DecimalError::Overflow),
        Ok(v) => Ok(v.to_bits()),
    }
}

fn std32(text: &str) -> Result<u32, DecimalError> {
    match text.parse::<f32>() {
        Err(_) => Err(DecimalError::Invalid),
        Ok(v) if v.is_nan() || is_word(text) => Err(DecimalError::NotFinite),
        Ok(v) if v.is_infinite() => Err(DecimalError::Overflow),
        Ok(v) => Ok(v.to_bits()),
    }
}

fn is_word(text: &str) -> bool {
    text.bytes()
        .any(|c| c.is_ascii_alphabetic() && !matches!(c, b'e' | b'E'))
}

fn check_parse(text: &str) -> Result<(), TestCaseError> {
    prop_assert_eq!(
        parse_f64(text).map(f64::to_bits),
        std64(text),
        "f64 {:?}",
        text
    );
    prop_assert_eq!(
        parse_f32(text).map(f32::to_bits),
        std32(text),
        "f32 {:?}",
        text
    );
    Ok(())
}

/// Bit patterns: uniform, plus the rarer classes (subnormal, powers of two, integers).
fn bits64() -> impl Strategy<Value = u64> {
    prop_oneof![
        6 => any::<u64>(),
        1 => (any::<bool>(), 0u64..1 << 52).prop_map(|(s, f)| (s as u64) << 63 | f),
        1 => (any::<bool>(), 0u64..2047).prop_map(|(s, e)| (s as u64) << 63 | e << 52),
        1 => any::<u64>().prop_map(|n| ((n >> (n % 64)) as f64).to_bits()),
    ]
}

fn bits32() -> impl Strategy<Value = u32> {
    prop_oneof![
        6 => any::<u32>(),
        1 => (any::<bool>(), 0u32..1 << 23).prop_map(|(s, f)| (s as u32) << 31 | f),
        1 => (any::<bool>(), 0u32..255).prop_map(|(s, e)| (s as u32) << 31 | e << 23),
        1 => any::<u32>().prop_map(|n| ((n >> (n % 32)) as f32).to_bits()),
    ]
}

/// A decimal literal with 1..=40 random significant digits (leading zeros, point placement,
/// exponent spelling all random) whose magnitude is about `10^mag`.
fn literal(mag: std::ops::RangeInclusive<i32>) -> impl Strategy<Value = String> {
    (
        0usize..3,
        prop::collection::vec(0u8..10, 1..=40),
        0usize..=40,
        0usize..3,
        mag,
        0usize..4,
    )
        .prop_map(|(sign, mut ds, point, zeros, mag, style)| {
            if ds[0] == 0 {
                ds[0] = 1 + ds.len() as u8 % 9;
            }
            let n = ds.len();
            let point = point.min(n);
            let mut s = String::from(["", "-", "+"][sign]);
            s.push_str(&"0".repeat(zeros));
            for (i, d) in ds.iter().enumerate() {
                if i == point && style != 3 {
                    s.push('.');
                }
                s.push((b'0' + d) as char);
            }
            // Value = 0.ds * 10^(point + zeros...) ~ 10^(point - n) * ds; pick the exponent
            // so that the magnitude is about 10^mag.
            let exp = mag - point as i32
                + if style == 3 {
                    point as i32 - n as i32
                } else {
                    0
                };
            match style {
                0 => s.push_str(&format!("e{exp}")),
                1 => s.push_str(&format!("E{}{exp}", if exp >= 0 { "+" } else { "" })),
                _ => s.push_str(&format!("e{exp:+}")),
            }
            s
        })
}

/// Exact decimal text of a halfway point `odd * 2^e2` (optionally nudged by one unit in
/// its last digit) that has at most 40 significant digits.
fn halfway(odd: u128, e2: i32, nudge: i32) -> String {
    let (mut int, exp) = if e2 >= 0 {
        (odd << e2, 0)
    } else {
        (odd * 5u128.pow(e2.unsigned_abs()), e2)
    };
    int = (int as i128 + nudge as i128) as u128;
    format!("{int}e{exp}")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(100_000))]

    /// (a) digits and exponent equal std's `{:e}`; (b) the text is std's `{}`, a plain
    /// decimal,
    /// and parses back to the identical value with std and with `parse_f64`.
    #[test]
    fn f64_shortest_round_trip(bits in bits64()) {
        check_f64(f64::from_bits(bits))?;
    }

    /// As above for f32.
    #[test]
    fn f32_shortest_round_trip(bits in bits32()) {
        check_f32(f32::from_bits(bits))?;
    }

    /// (c) random literals across the whole f64 range, from below half the smallest
    /// subnormal to beyond the largest value: equal to std (overflow = std's infinity).
    #[test]
    fn parse_random_literals(text in literal(-345..=310)) {
        check_parse(&text)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(30_000))]

    /// Random literals across the f32 range and the subnormals.
    #[test]
    fn parse_random_f32_literals(text in literal(-50..=40)) {
        check_parse(&text)?;
    }

    /// Exact halfway points between adjacent f64 values (integers up to 2^127 and
    /// fractions `odd / 2^j` with up to 40 digits), and one unit either side: ties go to
    /// the even neighbour.
    #[test]
    fn parse_f64_halfway(m in (1u128 << 52)..(1u128 << 53), e2 in -30i32..=74, nudge in -1i32..=1) {
        let odd = 2 * m + 1;
        if e2 + 54 <= 128 {
            check_parse(&halfway(odd, e2, nudge))?;
        }
    }

    /// Exact halfway points between adjacent f32 values, and one unit either side.
    #[test]
    fn parse_f32_halfway(m in (1u128 << 23)..(1u128 << 24), e2 in -44i32..=100, nudge in -1i32..=1) {
        let odd = 2 * m + 1;
        if e2 + 25 <= 128 {
            check_parse(&halfway(odd, e2, nudge))?;
        }
    }

    /// Clinger's fast path and its edges: up to 19 digits, small exponents.
    #[test]
    fn parse_fast_path_region(m in any::<u64>(), shift in 0u32..64, e in -30i32..=30, frac in 0usize..4) {
        let digits = (m >> shift).to_string();
        let text = match frac.min(digits.len() - 1) {
            0 => format!("{digits}e{e}"),
            f => format!("{}.{}e{e}", &digits[..digits.len() - f], &digits[digits.len() - f..]),
        };
        check_parse(&text)?;
    }

    /// Strings over the number alphabet: the same accepted syntax and values as std.
    #[test]
    fn syntax_like_std(text in "[-+]?[0-9.eE+-]{0,40}|[-+]?(inf|nan|infinity|INF|NaN|Infinity)") {
        check_parse(&text)?;
    }

    /// Any string: never a panic; what is accepted, std accepts with the same value when
    /// it has at most 40 significant digits.
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,80}") {
        let a = parse_f64(&text);
        let b = parse_f32(&text);
        if text.len() <= 40 {
            check_parse(&text)?;
        } else {
            prop_assert!(a.is_err() || text.parse::<f64>().is_ok());
            prop_assert!(b.is_err() || text.parse::<f32>().is_ok());
        }
    }
}

#[test]
fn long_inputs_never_panic() {
    for text in [
        "1".repeat(100_000),
        format!("0.{}1", "0".repeat(100_000)),
        format!("{}e-100000", "9".repeat(100_000)),
        format!("1e{}", "9".repeat(1000)),
        format!("1e-{}", "9".repeat(1000)),
        format!("0e{}", "9".repeat(1000)),
        format!("{}.", "0".repeat(1000)),
    ] {
        let _ = parse_f64(&text);
        let _ = parse_f32(&text);
    }
    assert_eq!(
        parse_f64(&format!("1e{}", "9".repeat(1000))),
        Err(DecimalError::Overflow)
    );
    assert_eq!(parse_f64(&format!("-1e-{}", "9".repeat(1000))), Ok(-0.0));
    let ones = format!("{}e-99999", "1".repeat(100_000));
    assert_eq!(parse_f64(&ones), Ok(ones.parse::<f64>().unwrap()));
}

#[test]
fn boundary_table() {
    let zeros = |n: usize| "0".repeat(n);
    let f64s: &[(f64, String)] = &[
        (0.0, "0".into()),
        (-0.0, "-0".into()),
        (5e-324, format!("0.{}5", zeros(323))),
        (-5e-324, format!("-0.{}5", zeros(323))),
        (
            f64::MIN_POSITIVE,
            format!("0.{}22250738585072014", zeros(307)),
        ),
        (
            2.225073858507201e-308,
            format!("0.{}2225073858507201", zeros(307)),
        ),
        (f64::MAX, format!("17976931348623157{}", zeros(292))),
        (f64::MIN, format!("-17976931348623157{}", zeros(292))),
        (9007199254740992.0, "9007199254740992".into()),
        (9007199254740993.0, "9007199254740992".into()),
        (9007199254740994.0, "9007199254740994".into()),
        (9007199254740991.0, "9007199254740991".into()),
        (0.2608, "0.2608".into()),
        (0.26, "0.26".into()),
        (0.563, "0.563".into()),
        (3.9e-8, "0.000000039".into()),
        (20000.0, "20000".into()),
        (1e-7, "0.0000001".into()),
        (563.0, "563".into()),
        (-0.00012, "-0.00012".into()),
        (1e-9, "0.000000001".into()),
        (9.99999999e-10, "0.000000000999999999".into()),
        (1e-10, "0.0000000001".into()),
        (1e-12, "0.000000000001".into()),
        (999999999.0, "999999999".into()),
        (1e9, "1000000000".into()),
        (1.5e300, format!("15{}", zeros(299))),
        (0.1 + 0.2, "0.30000000000000004".into()),
        (0.03, "0.03".into()),
        (f64::INFINITY, "inf".into()),
        (f64::NEG_INFINITY, "-inf".into()),
        (f64::NAN, "NaN".into()),
        (1125899906842624.0 + 0.25, "1125899906842624.3".into()),
        (1125899906842624.0 + 0.75, "1125899906842624.8".into()),
    ];
    for (v, text) in f64s {
        let (v, text) = (*v, text.as_str());
        assert_eq!(Shortest(v).to_string(), text, "{v:e}");
        check_f64(v).unwrap();
        if v.is_finite() {
            assert_eq!(parse_f64(text).map(f64::to_bits), Ok(v.to_bits()), "{text}");
        }
    }
    let f32s: &[(f32, String)] = &[
        (0.0, "0".into()),
        (-0.0, "-0".into()),
        (1e-45, format!("0.{}1", zeros(44))),
        (f32::MIN_POSITIVE, format!("0.{}11754944", zeros(37))),
        (f32::MAX, format!("34028235{}", zeros(31))),
        (16777216.0, "16777216".into()),
        (16777217.0, "16777216".into()),
        (3.9e-8, "0.000000039".into()),
        (1e-7, "0.0000001".into()),
        (0.05, "0.05".into()),
        (-0.05, "-0.05".into()),
        (0.001, "0.001".into()),
        (0.01, "0.01".into()),
        (0.06, "0.06".into()),
        (1.234567e-9, "0.000000001234567".into()),
        (3.123e-8, "0.00000003123".into()),
        (1e-12, "0.000000000001".into()),
        (-3.9e-10, "-0.00000000039".into()),
    ];
    for (v, text) in f32s {
        let (v, text) = (*v, text.as_str());
        assert_eq!(Shortest(v).to_string(), text, "{v:e}");
        check_f32(v).unwrap();
        assert_eq!(parse_f32(text).map(f32::to_bits), Ok(v.to_bits()), "{text}");
    }
    // Ties to even and the f32 / f64 difference (no double rounding).
    assert_eq!(parse_f64("9007199254740993"), Ok(9007199254740992.0));
    assert_eq!(parse_f64("9007199254740995"), Ok(9007199254740996.0));
    assert_eq!(
        parse_f64("9007199254740993.0000000000000000000001"),
        Ok(9007199254740994.0)
    );
    assert_eq!(parse_f32("16777217"), Ok(16777216.0));
    assert_eq!(parse_f32("16777219"), Ok(16777220.0));
    // 1 + 2^-24 + 1e-28: rounds up as f32; through f64 it would become 1 + 2^-24, a tie
    // that rounds down to 1.
    let t = "1.0000000596046447753906250001";
    assert_eq!(parse_f32(t), Ok(1.0000001));
    assert_eq!(parse_f32(t).unwrap(), t.parse::<f32>().unwrap());
    // Range edges.
    assert_eq!(parse_f64("1.7976931348623158e308"), Ok(f64::MAX));
    assert_eq!(
        parse_f64("1.7976931348623159e308"),
        Err(DecimalError::Overflow)
    );
    assert_eq!(parse_f64("1e309"), Err(DecimalError::Overflow));
    assert_eq!(parse_f64("2.4703282292062328e-324"), Ok(5e-324));
    assert_eq!(parse_f64("2.4703282292062327e-324"), Ok(0.0));
    assert_eq!(
        parse_f64("-1e-400").map(f64::to_bits),
        Ok((-0.0f64).to_bits())
    );
    assert_eq!(parse_f32("3.4028235e38"), Ok(f32::MAX));
    assert_eq!(parse_f32("3.40282356e38"), Ok(f32::MAX));
    assert_eq!(parse_f32("3.4028236e38"), Err(DecimalError::Overflow));
    assert_eq!(parse_f32("3.40282357e38"), Err(DecimalError::Overflow));
    assert_eq!(parse_f32("1e39"), Err(DecimalError::Overflow));
    assert_eq!(parse_f32("7.006492321624085e-46"), Ok(0.0));
    assert_eq!(parse_f32("7.006492321624086e-46"), Ok(1e-45));
    for t in [
        "1.7976931348623158e308",
        "1.7976931348623159e308",
        "2.4703282292062328e-324",
        "2.4703282292062327e-324",
        "3.40282356e38",
        "3.4028236e38",
        "7.006492321624085e-46",
        "7.006492321624086e-46",
    ] {
        check_parse(t).unwrap();
    }
}

#[test]
fn syntax_table() {
    let ok: &[(&str, f64)] = &[
        ("1", 1.0),
        ("+1", 1.0),
        ("-1", -1.0),
        ("1.", 1.0),
        (".5", 0.5),
        ("+.5", 0.5),
        ("-.5e-3", -0.0005),
        ("1.e2", 100.0),
        ("2.6e-1", 0.26),
        ("1E+2", 100.0),
        ("007", 7.0),
        ("0.000", 0.0),
        ("0e999999999999999999999", 0.0),
        ("1e-999999999999999999999", 0.0),
    ];
    for &(text, v) in ok {
        assert_eq!(parse_f64(text), Ok(v), "{text}");
        check_parse(text).unwrap();
    }
    let bad: &[(&str, DecimalError)] = &[
        ("", DecimalError::Invalid),
        ("+", DecimalError::Invalid),
        ("-", DecimalError::Invalid),
        (".", DecimalError::Invalid),
        ("e5", DecimalError::Invalid),
        (".e5", DecimalError::Invalid),
        ("1e", DecimalError::Invalid),
        ("1e+", DecimalError::Invalid),
        ("1e+-5", DecimalError::Invalid),
        ("1..2", DecimalError::Invalid),
        ("1e5.0", DecimalError::Invalid),
        (" 1", DecimalError::Invalid),
        ("1 ", DecimalError::Invalid),
        ("1_0", DecimalError::Invalid),
        ("0x10", DecimalError::Invalid),
        ("+-1", DecimalError::Invalid),
        ("--1", DecimalError::Invalid),
        ("0.26m", DecimalError::Invalid),
        ("infin", DecimalError::Invalid),
        ("+-inf", DecimalError::Invalid),
        ("\u{661}", DecimalError::Invalid),
        ("inf", DecimalError::NotFinite),
        ("-Infinity", DecimalError::NotFinite),
        ("+INF", DecimalError::NotFinite),
        ("NaN", DecimalError::NotFinite),
        ("-nan", DecimalError::NotFinite),
        ("1e999", DecimalError::Overflow),
        ("-1e999", DecimalError::Overflow),
    ];
    for &(text, e) in bad {
        assert_eq!(parse_f64(text), Err(e), "{text:?}");
        check_parse(text).unwrap();
    }
    assert_eq!(DecimalError::NotFinite.to_string(), "NaN/inf not allowed");
}

#[test]
fn writes_into_any_writer() {
    let mut s = heapless::String::<32>::new();
    write_f64(-1.5e-10, &mut s).unwrap();
    write_f32(0.1, &mut s).unwrap();
    assert_eq!(s.as_str(), "-0.000000000150.1");
    // A writer that is too small reports the error.
    let mut tiny = heapless::String::<3>::new();
    assert!(write_f64(0.2608, &mut tiny).is_err());
    assert_eq!(format!("[{}]", Shortest(2.5f32)), "[2.5]");
}

/// `Dec` writes an integer as `{}` does, at the boundaries and across the range.
#[test]
fn dec_is_core_integer_display() {
    use odo_unit::decimal::Dec;
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let mut cases = vec![
        0,
        1,
        9,
        10,
        99,
        100,
        u64::from(u32::MAX),
        u64::MAX,
        u64::MAX - 1,
    ];
    for k in 0..20 {
        cases.push(10u64.pow(k));
        cases.push(10u64.pow(k) - 1);
    }
    for _ in 0..10_000 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        cases.push(x >> (x % 64));
    }
    for v in cases {
        assert_eq!(Dec(v).to_string(), v.to_string());
    }
}
