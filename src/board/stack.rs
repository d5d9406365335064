//! Stack high-water mark. At start-up the free stack is painted with a pattern; the lowest
//! word that no longer holds it shows the most stack the firmware has ever used, all
//! interrupt priorities nested included (reported by `status`).
//!
//! flip-link places the stack at the bottom of RAM: it grows down from `_stack_start` (just
//! below `.data`) towards `_stack_end` (the RAM origin), where an overflow faults.

/// The paint: a word the program is unlikely to leave on its stack.
const PATTERN: u32 = 0x5AFE_C0DE;
/// Bytes below the stack pointer left unpainted for the painting function's own calls.
const MARGIN: usize = 256;

extern "C" {
    /// Top of the stack (its first push lands just below), from the linker script.
    static _stack_start: u32;
    /// Bottom of the stack region, from the linker script (flip-link: the RAM origin).
    static _stack_end: u32;
}

/// `(top, bottom)` addresses of the stack region.
fn region() -> (usize, usize) {
    // Only the addresses of the linker-defined symbols are taken (safe since Rust 1.82);
    // they are never read as values.
    (
        core::ptr::addr_of!(_stack_start) as usize,
        core::ptr::addr_of!(_stack_end) as usize,
    )
}

/// Paints the free stack, from the bottom of the region to just below the current stack
/// pointer. Call once, early in `init`, with interrupts disabled.
pub fn paint() {
    let (_, bottom) = region();
    let sp = cortex_m::register::msp::read() as usize;
    let end = sp.saturating_sub(MARGIN) & !3;
    let mut p = bottom;
    while p < end {
        // Note(unsafe): `p` lies between the bottom of the stack region and MARGIN bytes
        // below the stack pointer: free stack, which nothing else uses while interrupts are
        // disabled in `init`; the address is word-aligned.
        unsafe { core::ptr::write_volatile(p as *mut u32, PATTERN) };
        p += 4;
    }
}

/// `(used, size)`: the most stack ever used since [`paint`], and the region's size, bytes.
pub fn high_water() -> (usize, usize) {
    let (top, bottom) = region();
    let mut p = bottom;
    // Note(unsafe): reads of word-aligned addresses inside the stack region; words below the
    // deepest stack use hold the paint and are never written concurrently.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PATTERN {
        p += 4;
    }
    (top - p, top - bottom)
}
