//! QEMU's `netduinoplus2`: HSI 16 MHz, the timers count at 1 GHz of emulated time, the
//! encoders, index pulses and fault lines come from the deterministic simulated drive
//! (`drive`), the PPS captures and NMEA bytes from the simulated GNSS receiver (`gnss`), the
//! settings flash is RAM (`flash`), the sample compare is TIM5's update event (`sampler`),
//! logging goes over semihosting.

pub mod drive;
pub mod flash;
pub mod gnss;
pub mod sampler;

use super::serial::GnssUart;
use super::BusClocks;
use super::FaultLines;
use defmt_semihosting as _;
use odo_unit::timing::ClockSource;
use odo_unit::unit::watchdog::IwdgSetting;
use odo_unit::unit::{IndexCapture, RawCounts};
use stm32f4xx_hal::{pac, rcc::Config};

/// Widths of the raw counters (left, right), bits: the simulated drive's, as the board's
/// TIM2 and TIM3.
pub const COUNTER_BITS: [u32; 2] = [32, 16];

/// Unit of [`cycles`] in `status`.
pub const CYCLES_UNIT: &str = "instructions (QEMU)";

/// Where the USART1 interrupt takes NMEA bytes from: the simulated receiver's wire.
pub type GnssRx = gnss::SimUart;

/// What the sampler needs besides TIM5: the simulated receiver (PPS captures and NMEA).
pub type SamplerExtra = gnss::SimGnss;

/// The simulated receiver, wired to the GNSS UART's interrupt, sending at `baud`.
pub fn attach_gnss(uart: GnssUart, baud: u32) -> (GnssRx, SamplerExtra) {
    gnss::attach(uart, baud)
}

/// Starts the independent watchdog: nothing to do, QEMU's `netduinoplus2` models no IWDG
/// (its registers are unimplemented and the board's sequence would wait on nothing).
pub fn start_iwdg(iwdg: &pac::iwdg::RegisterBlock, setting: IwdgSetting) -> bool {
    let _ = (iwdg, setting);
    true
}

/// Starts the clocks: the HSI at 16 MHz without PLL (QEMU's RCC never reports the PLL
/// locked).
pub fn start_clocks(rcc: pac::RCC) -> (stm32f4xx_hal::rcc::Rcc, ClockSource, BusClocks) {
    use stm32f4xx_hal::rcc::RccExt;
    let rcc = rcc.freeze(Config::hsi());
    let clocks = BusClocks {
        pclk1: rcc.clocks.pclk1().raw(),
        pclk2: rcc.clocks.pclk2().raw(),
        // TIM2-5 in QEMU count at 1 GHz of emulated time whatever the clock tree says.
        timer: 1_000_000_000,
    };
    (rcc, ClockSource::Hsi, clocks)
}

/// Frequency of the TIM5 sample timer's ticks, Hz: TIM2-5 in QEMU count at 1 GHz of emulated
/// time whatever the clock tree says.
pub fn timer_hz(clocks: &BusClocks) -> u32 {
    clocks.timer
}

/// The unit's 96-bit unique ID: zeros (QEMU does not map that system memory).
pub fn unique_id() -> [u8; 12] {
    [0u8; 12]
}

/// Where the counts, index pulses and fault lines come from: the simulated drive.
pub struct Acquisition {
    sim: drive::SimDrive,
}

impl Acquisition {
    /// The simulated drive (the timers and fault lines are not used: TIM2 is the cycle
    /// counter, [`cycles`]).
    pub fn new(
        _tim2: pac::TIM2,
        _tim3: pac::TIM3,
        _faults: FaultLines,
        _rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> Self {
        Self {
            sim: drive::SimDrive::new(),
        }
    }

    /// `None`: the drive is sampled at the sample's tick ([`Self::snapshot`]).
    #[inline(always)]
    pub fn snapshot_now(&self) -> Option<RawCounts> {
        None
    }

    /// Both counters at the sample instant `tick`.
    #[inline(always)]
    pub fn snapshot(&mut self, tick: u64) -> RawCounts {
        self.sim.snapshot(tick)
    }

    /// Never a latched pulse: the drive reports its pulses with the samples
    /// ([`Self::sample_index`]).
    pub fn take_index(&self, wheel: usize) -> Option<IndexCapture> {
        let _ = wheel;
        None
    }

    /// Index pulses of the simulated drive since the last snapshot.
    pub fn sample_index(&mut self) -> [Option<u32>; 2] {
        let mut out = [None, None];
        for pulse in self.sim.take_index() {
            out[pulse.wheel] = Some(pulse.raw);
        }
        out
    }

    /// The fault lines (left, right) at `tick`.
    pub fn faults(&self, tick: u64) -> (bool, bool) {
        self.sim.faults(tick)
    }
}

/// A free-running count for measuring code: TIM2's counter, which the qemu build leaves
/// untouched and which under `-icount shift=0` counts executed instructions.
#[inline(always)]
pub fn cycles() -> u32 {
    // Note(unsafe): a read of TIM2 CNT, a register no other code of the qemu build uses
    // (the encoders are simulated); reads have no side effect.
    unsafe { (*pac::TIM2::ptr()).cnt().read().bits() }
}

/// The low 32 bits of the sample timeline's tick now: the last sample instant plus the
/// counter ticks since its interrupt read TIM5 (`sampler::base`). QEMU's TIM5 counter keeps
/// counting across its update events and runs ahead of the software's tick timeline (on which
/// the drive, the receiver and the records are defined) by the interrupt latency of each
/// sample, so only its advance since the last sample is used.
pub fn tick_now() -> u32 {
    loop {
        let (base, cnt_then) = sampler::base();
        let cnt = sampler::counter();
        // The sample interrupt (higher priority) may have moved the base between the reads.
        if sampler::base() == (base, cnt_then) {
            return base.wrapping_add(cnt.wrapping_sub(cnt_then));
        }
    }
}

/// Starts what [`cycles`] reads.
pub fn start_cycle_counter(core: &mut cortex_m::Peripherals) {
    let _ = core;
    // Note(unsafe): TIM2 CR1 = CEN; QEMU's TIM2 then counts at 1 GHz of emulated time.
    unsafe { (*pac::TIM2::ptr()).cr1().write(|w| w.bits(1)) };
}
