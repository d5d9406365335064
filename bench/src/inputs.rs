//! The varied input set of the benchmarks: per-sample increments of a drive with straights,
//! arcs of both senses, pivots, stops, reversing and large steps, generated deterministically.

use odo_testkit::Rng;

/// Number of samples in the set.
#[cfg_attr(not(target_os = "none"), allow(dead_code))] // the target benchmark's input
pub const SAMPLES: usize = 512;

/// Per-sample increments `(dGamma_1, dGamma_2)` of the benchmark drive.
#[cfg_attr(not(target_os = "none"), allow(dead_code))] // the target benchmark's input
pub fn increments() -> [[i32; 2]; SAMPLES] {
    let mut rng = Rng::new(0x0D0_5EED);
    let mut out = [[0i32; 2]; SAMPLES];
    for (k, d) in out.iter_mut().enumerate() {
        let v = (rng.next_u64() % 1200) as i32;
        *d = match (k / 32) % 8 {
            0 => [v, v],                // straight
            1 => [v, v * 3 / 4],        // arc, clockwise
            2 => [v / 2, v],            // arc, counter-clockwise
            3 => [v / 3, -v / 3],       // pivot
            4 => [0, 0],                // standing still
            5 => [-v, -(v * 7 / 8)],    // reversing on an arc
            6 => [v * 20, v * 20 - 37], // fast (1 kHz-equivalent large steps)
            _ => [
                (rng.next_u64() % 9) as i32 - 4,
                (rng.next_u64() % 9) as i32 - 4,
            ], // crawl, jitter
        };
    }
    out
}
