//! The documented bandwidth tables of the host link (docs/PROTOCOL.md, docs/MAVLINK.md)
//! checked against a settings check.

/// A documented row: `(baud, most records per second at divider 1, least divider at rate
/// 50 Hz, least divider at rate 1000 Hz)`.
pub type BudgetRow = (u32, u32, u32, u32);

/// Asserts that `fits(baud, rate, divider)` draws its boundaries where `row` says: `most`
/// fits at divider 1 and one more does not, and the dividers are the least that fit.
pub fn assert_budget_row(fits: impl Fn(u32, u32, u32) -> bool, row: BudgetRow) {
    let (baud, most, at50, at1000) = row;
    assert!(fits(baud, most, 1) && !fits(baud, most + 1, 1), "{baud}");
    assert!(fits(baud, 50, at50), "{baud}");
    assert!(at50 == 1 || !fits(baud, 50, at50 - 1), "{baud}");
    assert!(
        fits(baud, 1000, at1000) && !fits(baud, 1000, at1000 - 1),
        "{baud}"
    );
}
