//! Number formats of the host benchmarks' Markdown tables.

/// `n` with thousands separators (`5,000,000`).
pub fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// `v` with three significant digits: plain from 0.01 to 1000 (`28.9`), else in exponent
/// form (`1.50e-7`).
pub fn number(v: f64) -> String {
    let a = v.abs();
    if !(0.01..1000.0).contains(&a) {
        return format!("{v:.2e}");
    }
    let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
    format!("{v:.decimals$}")
}
