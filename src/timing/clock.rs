//! The sample clock on a free-running 32-bit timer: counter extension and catch-up after a
//! stall.
//!
//! The board's sample timer counts timer ticks freely over its 32 bits (84 MHz: it wraps
//! every 51.1 s). Each sample is an output-compare interrupt at the sample's tick, and the
//! PPS is input-captured on the same counter. Software works on one 64-bit timeline of
//! ticks (the one the [`Discipline`] and its [`Sample`]s use): [`TimerExtender`] maps
//! counter readings and capture values onto it.
//!
//! When the CPU stalls (a flash sector erase stops it for up to 2 s on the single-bank
//! STM32F401), the counter keeps running: the compare interrupt of the due sample is served
//! late, when one or many grid points have passed. [`catch_up`] then advances the grid
//! past the present and says which grid point the late snapshot stands for, how many were
//! merged into it, and which one to program next, so the schedule is back on the grid at
//! once and the second labels keep counting real (GNSS) seconds.
//!
//! # The interrupt, in order
//! 1. `now = extender.extend(CNT)` (first, at entry);
//! 2. if the capture flag is set: `edge = extender.capture(CCR1)` and
//!    `discipline.on_pps(edge)`: only the latest edge survives a long stall (the capture
//!    register holds the latest one and the over-capture flag says others were lost); the
//!    discipline takes it as the edge of the right second (it counts whole seconds from
//!    its last edge), or reacquires with it;
//! 3. `let c = catch_up(&mut discipline, due, now, guard)`: the encoder snapshot is
//!    labelled `c.sample`; program the compare register with `c.next.tick as u32`
//!    (the low 32 bits of the 64-bit tick) and keep `c.next` as the next `due`.
//!
//! Feeding the capture before `catch_up` lets the grid points still ahead be placed from
//! the fresh edge; the other order also works (the discipline then counts the stall's
//! seconds as missed and reacquires on the edge).

use super::pps::{Discipline, Sample};

/// Extends readings of a free-running 32-bit up-counter to a monotonic 64-bit tick count.
///
/// The 64-bit timeline starts at the value of the counter given to [`TimerExtender::new`]
/// (that reading is tick `cnt`), and adds 2^32 at each wrap. Every reading is interpreted
/// as the tick nearest to the last one, within -2^31..2^31 ticks of it, so
/// [`TimerExtender::extend`] must be called at least once every 2^31 ticks (25.5 s at
/// 84 MHz; the sample interrupt does so at every sample). Pure arithmetic, no hardware.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimerExtender {
    /// The latest extended reading, ticks.
    last: u64,
}

impl TimerExtender {
    /// An extender whose first reading `cnt` is tick `cnt` of the 64-bit timeline.
    pub const fn new(cnt: u32) -> Self {
        Self { last: cnt as u64 }
    }

    /// An extender whose latest reading is tick `tick` (its low 32 bits are the counter
    /// value then): to continue a timeline that does not start at the counter's value.
    pub const fn from_tick(tick: u64) -> Self {
        Self { last: tick }
    }

    /// The latest extended reading, ticks.
    pub const fn last(&self) -> u64 {
        self.last
    }

    /// The 64-bit tick of the counter reading `cnt`, taken at most 2^31 - 1 ticks after the
    /// latest extended reading (or at most 2^31 ticks before it: a reading taken before a
    /// preempting `extend` is given its earlier tick, and does not move the state back).
    /// The results of successive calls with fresh readings never decrease.
    pub fn extend(&mut self, cnt: u32) -> u64 {
        let tick = self.capture(cnt);
        if tick > self.last {
            self.last = tick;
        }
        tick
    }

    /// The 64-bit tick of a capture register value `ccr` latched within 2^31 ticks of the
    /// latest [`TimerExtender::extend`] reading: normally at or before it (up to 2^31 ticks
    /// earlier), or up to 2^31 - 1 ticks later (an edge latched between reading the counter
    /// and reading the capture register). Does not change the state.
    pub const fn capture(&self, ccr: u32) -> u64 {
        let delta = ccr.wrapping_sub(self.last as u32) as i32;
        // Before the start of the timeline (only in the first 2^31 ticks): clamp to 0.
        self.last.saturating_add_signed(delta as i64)
    }
}

/// What [`catch_up`] decided at one compare interrupt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CatchUp {
    /// The grid point the interrupt's encoder snapshot (taken at `now`) is labelled with:
    /// the latest committed grid point with `tick <= now`; `due` itself unless the
    /// interrupt was late by a sample period or more (a stall).
    pub sample: Sample,
    /// Grid points passed over and not reported separately: those before `sample`
    /// (their motion is in `sample`'s counts) and those in `(now, now + guard]`, too close
    /// to program (their motion is in the next sample's counts). 0 normally.
    pub merged: u32,
    /// The next grid point, to program into the compare register: `next.tick > now + guard`.
    pub next: Sample,
}

/// Advances the discipline's grid at a compare interrupt.
///
/// - `disc`: the discipline whose last committed sample is `due` (one sample committed
///   ahead, as with a compare register);
/// - `due`: the sample whose compare fired (`due.tick <= now`);
/// - `now`: the extended counter read at interrupt entry, ticks (64-bit timeline);
/// - `guard`: the least lead, ticks, with which a compare value can be programmed and
///   still fire (the time from reading the counter to writing the compare register, with
///   a margin).
///
/// Commits grid points ([`Discipline::next_sample`] with `now`) until one lies after
/// `now + guard`, which becomes [`CatchUp::next`]. Of the points committed meanwhile,
/// and `due`, the latest with `tick <= now` is [`CatchUp::sample`]; all the others are
/// counted in [`CatchUp::merged`]. So every grid point is either delivered as a `sample` or
/// merged, once, in order, and the second labels stay those of the grid however long the
/// stall. After a stall the delivered `sample`'s snapshot was taken up to one sample
/// period (plus the latency) after its tick; the next one is on time again.
///
/// If `due` is the first sample of a second, that second takes the rate configured now
/// ([`Discipline::begin_second`]), and so does the returned `sample`.
///
/// If `due.tick > now` (not a late interrupt, a spurious or early one), `due` is still
/// the `sample`. Allocation-free; the points of a long stall are skipped at once
/// ([`Discipline::skip_to`]: a few operations per second of stall), so the work does not
/// grow with the rate (a 0.8 s stall at 1 kHz is not 800 iterations).
pub fn catch_up(disc: &mut Discipline, due: Sample, now: u64, guard: u64) -> CatchUp {
    let limit = now.saturating_add(guard);
    // At the first sample of a second, the second takes the rate configured now.
    let mut sample = disc.begin_second(due);
    // Points of a long stall are skipped by arithmetic; an interrupt on time (within the
    // guard) has none to skip, and pays nothing for it.
    let mut merged: u32 = if now > due.tick.saturating_add(guard) {
        disc.skip_to(now)
    } else {
        0
    };
    loop {
        let next = disc.next_sample(now);
        if next.tick > limit {
            return CatchUp {
                sample,
                merged,
                next,
            };
        }
        merged = merged.saturating_add(1);
        if next.tick <= now {
            // `sample` is passed over: `next` is later and still in the past.
            sample = next;
        }
    }
}
