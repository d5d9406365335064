//! Instruction counts on the Cortex-M4F, under QEMU `-icount shift=0,sleep=off`, printed as
//! Markdown tables (`bench/run` puts them into docs/RESULTS.md).

use core::hint::black_box;
use core::sync::atomic::{compiler_fence, Ordering};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use odo_unit::odometry::uncertainty::{
    CovarianceUncertainty, PaperUncertainty, StepGeometry, StepJacobian, UncertaintyCoefficients,
};
use odo_unit::odometry::{
    ChassisParams, IndexRefs, Integrator, Pose, UncertaintyModel, WheelCounts,
};

use crate::inputs::{increments, SAMPLES};
use crate::naive::NaiveIntegrator;
use stm32f4xx_hal as _;

/// TIM2 control register 1.
const TIM2_CR1: *mut u32 = 0x4000_0000 as *mut u32;
/// TIM2 counter.
const TIM2_CNT: *const u32 = 0x4000_0024 as *const u32;

#[inline(always)]
fn now() -> u32 {
    compiler_fence(Ordering::SeqCst);
    // Note(unsafe): a volatile read of TIM2's counter register, which exists on the
    // STM32F4 and on QEMU's netduinoplus2; reading it has no side effects.
    let t = unsafe { core::ptr::read_volatile(TIM2_CNT) };
    compiler_fence(Ordering::SeqCst);
    t
}

/// Instructions spent in `f`, less the cost of the two counter reads.
#[inline(always)]
pub fn count(overhead: u32, f: impl FnOnce()) -> u32 {
    let a = now();
    f();
    let b = now();
    b.wrapping_sub(a).saturating_sub(overhead)
}

/// Median and maximum of a set of counts (sorts it).
fn stats(v: &mut [u32]) -> (u32, u32) {
    v.sort_unstable();
    (v[v.len() / 2], v[v.len() - 1])
}

/// A count with thousands separators (`7,394`).
pub struct Thousands(pub u32);

impl core::fmt::Display for Thousands {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (high, low) = (self.0 / 1000, self.0 % 1000);
        if high > 0 {
            write!(f, "{},{:03}", Thousands(high), low)
        } else {
            write!(f, "{low}")
        }
    }
}

/// Prints the table row of `name`: median and worst of `v` (sorted); returns the median.
pub fn report(name: &str, v: &mut [u32]) -> u32 {
    let (median, worst) = stats(v);
    hprintln!(
        "| {} | {} | {} |",
        name,
        Thousands(median),
        Thousands(worst)
    );
    median
}

/// Runs the integrator over the input set, counting each step.
/// With `with_sigma`, each count includes taking the sigmas for a record (`sigma()`), which
/// is where the covariance model takes its square roots.
fn integrator_steps(
    params: &ChassisParams,
    index: bool,
    with_sigma: bool,
    overhead: u32,
    out: &mut [u32; SAMPLES],
) {
    let mut integ = match Integrator::new(params, WheelCounts::default(), Pose::default()) {
        Ok(i) => i,
        Err(_) => return,
    };
    let refs = if index {
        IndexRefs {
            left: Some(1234),
            right: Some(-777),
        }
    } else {
        IndexRefs::default()
    };
    let mut g = [0i64; 2];
    for (k, d) in increments().iter().enumerate() {
        g = [g[0] + i64::from(d[0]), g[1] + i64::from(d[1])];
        let counts = WheelCounts {
            left: g[0],
            right: g[1],
        };
        out[k] = count(overhead, || {
            black_box(integ.step(black_box(counts), black_box(refs)));
            if with_sigma {
                black_box(integ.sigma());
            }
        });
    }
    black_box(integ.pose());
}

/// A plausible geometry for the uncertainty-only measurement of sample `d`.
fn geometry(d: [i32; 2], heading: f32) -> StepGeometry {
    let c = 4.084e-5f32;
    let s = [c * d[0] as f32, c * d[1] as f32];
    let ds = 0.5 * (s[0] + s[1]);
    let dalpha = (s[0] - s[1]) / 0.563;
    let theta = heading + 0.5 * dalpha;
    StepGeometry {
        abs_counts: [d[0].unsigned_abs() as f32, d[1].unsigned_abs() as f32],
        abs_count_difference: (d[0] - d[1]).unsigned_abs() as f32,
        wheel_distance: s,
        ds,
        dalpha,
        chord: ds,
        sin: libm::sinf(theta),
        cos: libm::cosf(theta),
        inv_track: 1.0 / 0.563,
    }
}

#[entry]
fn main() -> ! {
    // Note(unsafe): enables TIM2's counter (CEN); TIM2 is used by nothing else in this
    // program. Under QEMU the counter then advances one per executed instruction.
    unsafe { core::ptr::write_volatile(TIM2_CR1, 1) };
    let mut empty = [0u32; 16];
    for e in empty.iter_mut() {
        *e = count(0, || {});
    }
    let (overhead, _) = stats(&mut empty);

    hprintln!("| operation | median | worst |");
    hprintln!("| --- | ---: | ---: |");
    let medians = integrator_rows(overhead);
    let protocol = crate::target_protocol::run(overhead);
    // Stack used by one step: paint the stack below the current frame, step, find the
    // deepest overwritten word.
    let step_stack = stack_of_step(&ChassisParams::DESIGNED);

    let step = medians.step.max(1);
    hprintln!();
    hprintln!("| figure | value |");
    hprintln!("| --- | ---: |");
    hprintln!(
        "| odometry part of the paper-model step (median difference) | {} instructions |",
        Thousands(medians.step.saturating_sub(medians.uncertainty))
    );
    hprintln!(
        "| naive step / fixed-point step (medians) | {}.{:02}x |",
        medians.naive / step,
        (medians.naive % step) * 100 / step
    );
    hprintln!(
        "| counter overhead (subtracted from every count) | {} instruction{} |",
        overhead,
        if overhead == 1 { "" } else { "s" }
    );
    hprintln!(
        "| pose frame on the wire | {} bytes |",
        protocol.frame_bytes
    );
    hprintln!(
        "| stack of one integrator step (painted, incl. a 64-byte margin) | {} bytes |",
        step_stack
    );
    hprintln!(
        "| stack of frame encoding incl. its output buffer (painted) | {} bytes |",
        protocol.encode_stack
    );

    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::nop();
    }
}

/// Medians of the integrator rows that the figures table derives from.
struct Medians {
    /// The paper-model step.
    step: u32,
    /// The paper model's uncertainty alone.
    uncertainty: u32,
    /// The naive f32 step.
    naive: u32,
}

/// Prints the integrator's rows of the instruction table.
fn integrator_rows(overhead: u32) -> Medians {
    let mut full = [0u32; SAMPLES];
    let designed = ChassisParams::DESIGNED;
    integrator_steps(&designed, false, false, overhead, &mut full);
    let step = report(
        "integrator step, paper model (odometry + uncertainty)",
        &mut full,
    );

    // Uncertainty alone: Jacobian plus the paper's propagation.
    let coefficients = UncertaintyCoefficients {
        delta: [3.9e-8; 2],
        delta_diff: 0.0,
        kappa: [1e-7; 2],
        kappa_diff: 1e-6,
        turn_decay: 0.0,
        turn_rate_variance: 0.0,
        geometry: [1e-8, 1e-8, 1e-6, 5e-9, 1e-9, -1e-9],
    };
    let mut paper = PaperUncertainty::default();
    let mut unc = [0u32; SAMPLES];
    for (k, d) in increments().iter().enumerate() {
        let g = geometry(*d, k as f32 * 0.01);
        unc[k] = count(overhead, || {
            let j = StepJacobian::of(black_box(&g));
            paper.step(&coefficients, &g, &j);
            black_box(&paper);
        });
    }
    let uncertainty = report(
        "of which the uncertainty (Jacobian + eqs 23-28), paper model",
        &mut unc,
    );

    let mut cov = CovarianceUncertainty::default();
    for (k, d) in increments().iter().enumerate() {
        let g = geometry(*d, k as f32 * 0.01);
        unc[k] = count(overhead, || {
            let j = StepJacobian::of(black_box(&g));
            cov.step(&coefficients, &g, &j);
            black_box(&cov);
        });
    }
    report("uncertainty alone, covariance model", &mut unc);

    let covariance = ChassisParams {
        uncertainty_model: UncertaintyModel::Covariance,
        ..designed
    };
    integrator_steps(&covariance, false, false, overhead, &mut full);
    report("integrator step, covariance model", &mut full);
    integrator_steps(&designed, false, true, overhead, &mut full);
    report("step + `sigma()` for a record, paper model", &mut full);
    integrator_steps(&covariance, false, true, overhead, &mut full);
    report("step + `sigma()`, covariance model", &mut full);
    // Opposite-phase slip as a Gauss-Markov state (`kappa_diff_corr`).
    let turning = ChassisParams {
        kappa_diff: 4.0e-4,
        kappa_diff_corr: 2.0,
        ..covariance
    };
    integrator_steps(&turning, false, true, overhead, &mut full);
    report(
        "step + `sigma()`, covariance model with `kappa_diff_corr` set",
        &mut full,
    );

    let with_diff = ChassisParams {
        delta_diff: 2.0e-8,
        ..designed
    };
    integrator_steps(&with_diff, false, false, overhead, &mut full);
    report("integrator step, paper model with `delta_diff`", &mut full);

    let wobbly = odo_testkit::wobbly_wheels();
    integrator_steps(&wobbly, true, false, overhead, &mut full);
    report(
        "integrator step, per-angle wheel functions referenced by the index",
        &mut full,
    );

    let mut naive = NaiveIntegrator::new([0.26, 0.26], 0.563, 20_000, 3.9e-8);
    for (k, d) in increments().iter().enumerate() {
        full[k] = count(overhead, || {
            naive.step(black_box(*d));
            black_box(&naive);
        });
    }
    let naive = report(
        "the same step written naively (f32, `libm` `sinf`/`cosf`/`sqrtf`)",
        &mut full,
    );
    Medians {
        step,
        uncertainty,
        naive,
    }
}

/// Bytes of stack below the caller's frame used by `f`: the stack below the current frame is
/// painted, `f` runs, and the deepest overwritten word is found.
#[inline(never)]
pub fn stack_used(f: impl FnOnce()) -> usize {
    const PAINT: usize = 2048;
    const MARGIN: usize = 64;
    const PATTERN: u32 = 0xC0FF_EE11;
    let sp = cortex_m::register::msp::read() as usize;
    let base = (sp - MARGIN - PAINT * 4) & !3;
    for k in 0..PAINT {
        // Note(unsafe): writes the pattern into free stack below the current frame (MARGIN
        // bytes kept for this function's own calls); nothing lives there.
        unsafe { core::ptr::write_volatile((base + k * 4) as *mut u32, PATTERN) };
    }
    f();
    let mut deepest = PAINT;
    for k in 0..PAINT {
        // Note(unsafe): reads back the painted region written above.
        if unsafe { core::ptr::read_volatile((base + k * 4) as *const u32) } != PATTERN {
            deepest = k;
            break;
        }
    }
    (PAINT - deepest) * 4 + MARGIN
}

/// Bytes of stack used by integrator steps over varied inputs.
fn stack_of_step(params: &ChassisParams) -> usize {
    let mut integ = match Integrator::new(params, WheelCounts::default(), Pose::default()) {
        Ok(i) => i,
        Err(_) => return 0,
    };
    stack_used(|| {
        // Inputs generated on the fly: an input array would itself sit in the painted region.
        let mut rng = odo_testkit::Rng::new(99);
        let mut g = [0i64; 2];
        for _ in 0..SAMPLES {
            g[0] += (rng.next_u64() % 2000) as i64 - 500;
            g[1] += (rng.next_u64() % 2000) as i64 - 500;
            black_box(integ.step(
                WheelCounts {
                    left: g[0],
                    right: g[1],
                },
                IndexRefs {
                    left: Some(5),
                    right: Some(9),
                },
            ));
        }
    })
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("bench panicked: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::nop();
    }
}
