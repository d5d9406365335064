//! The board: every pin and peripheral choice of the firmware, in one place
//! (documented with a wiring table in `docs/HARDWARE.md`).
//!
//! | function                     | peripheral            | pin  | AF | notes |
//! |------------------------------|-----------------------|------|----|-------|
//! | left encoder A / B           | TIM2 CH1 / CH2, QEI x4 (32-bit) | PA15 / PB3 | 1 | boot as JTDI / JTDO: SWD only |
//! | right encoder A / B          | TIM3 CH1 / CH2, QEI x4 (16-bit) | PA6 / PA7  | 2 | |
//! | left index N                 | TIM2 CH3 input capture | PB10 | 1 | latches the left count in hardware |
//! | right index N                | TIM3 CH4 input capture | PB1  | 2 | latches the right count in hardware |
//! | left encoder fault           | GPIO in, pull-up      | PC2  | -  | active low |
//! | right encoder fault          | GPIO in, pull-up      | PC3  | -  | active low |
//! | GNSS 1-PPS                   | TIM5 CH1 input capture | PA0 | 2  | rising edge, pull-down, filtered; TIM5 also times the samples |
//! | GNSS NMEA (receiver TX)      | USART1 RX             | PA10 | 7  | [`GNSS_BAUD`] 8N1, RS-232 level shifter |
//! | host link TX / RX            | USART2 TX / RX        | PA2 / PA3 | 7 | Nucleo ST-LINK virtual COM port; QEMU `-serial` #2 |
//! | status LED                   | GPIO out              | PA5  | -  | on = PPS locked (Nucleo LD2) |
//!
//! Interrupt priorities (RTIC): TIM5 sample/PPS and TIM2/TIM3 index captures = 4;
//! USART1/USART2 = 3; the processing task (SPI2 vector) = 2; the command task (SPI3
//! vector) = 1. The index counts are latched by the timers themselves, so the capture
//! interrupts' latency does not matter (they must only run within one wheel turn).
//!
//! The `qemu` feature builds the same application for QEMU's `netduinoplus2`: HSI 16 MHz, the
//! timers count at 1 GHz of emulated time, the encoders, index pulses and fault lines come
//! from the deterministic [`sim`] drive, the PPS captures and NMEA bytes from the simulated
//! GNSS receiver [`sim_gnss`], the settings flash is RAM ([`flash`]).

#[cfg_attr(feature = "qemu", allow(dead_code))]
pub mod encoders;
pub mod flash;
pub mod sampler;
pub mod serial;
#[cfg(feature = "qemu")]
pub mod sim;
#[cfg(feature = "qemu")]
pub mod sim_gnss;
pub mod stack;

use odo_core::unit::{IndexCapture, RawCounts};
use stm32f4xx_hal::{pac, rcc::Config};

/// Unit of [`cycles`] in `status`.
#[cfg(not(feature = "qemu"))]
pub const CYCLES_UNIT: &str = "cycles";
/// Unit of [`cycles`] in `status`.
#[cfg(feature = "qemu")]
pub const CYCLES_UNIT: &str = "instructions (QEMU)";

/// Baud rate of the GNSS receiver's NMEA output (USART1).
pub const GNSS_BAUD: u32 = 38_400;

/// Where the USART1 interrupt takes NMEA bytes from: the UART on the board; in the `qemu`
/// build the simulated receiver's wire ([`sim_gnss::SimUart`]).
#[cfg(not(feature = "qemu"))]
pub type GnssRx = serial::GnssUart;
/// Where the USART1 interrupt takes NMEA bytes from: the UART on the board; in the `qemu`
/// build the simulated receiver's wire ([`sim_gnss::SimUart`]).
#[cfg(feature = "qemu")]
pub type GnssRx = sim_gnss::SimUart;

/// Watchdog timeout, milliseconds, at the LSI's nominal 32 kHz. The LSI runs anywhere
/// from 17 to 47 kHz (datasheet DS9716), so the real timeout lies between 2.7 s and 7.5 s:
/// the shortest is 3.4x the longest flash stall ([`flash::MAX_ERASE_MS`], 800 ms), before
/// which the flash driver feeds the watchdog.
pub const WATCHDOG_MS: u32 = 4_000;

/// Shortest watchdog timeout over the LSI's range (47 kHz), milliseconds.
pub const WATCHDOG_MIN_MS: u32 = WATCHDOG_MS * 32 / 47;

const _: () = assert!(WATCHDOG_MIN_MS > 3 * flash::MAX_ERASE_MS);

/// Reloads the independent watchdog from anywhere (the flash driver, just before an erase).
#[cfg_attr(feature = "qemu", allow(dead_code))]
pub fn watchdog_feed() {
    // Note(unsafe): a write of the reload key 0xAAAA to IWDG_KR, a write-only register whose
    // only effect is the reload; atomic, and harmless before the watchdog is started.
    unsafe { (*pac::IWDG::ptr()).kr().write(|w| w.bits(0xAAAA)) };
}

pub use odo_core::timing::ClockSource;

/// How long start-up waits for the HSE to become ready, milliseconds (a crystal takes about
/// 2 ms; an external clock is ready at once).
#[cfg_attr(any(feature = "qemu", not(feature = "hse")), allow(dead_code))]
pub const HSE_STARTUP_MS: u32 = 100;

/// Set by the clock security system's NMI when the HSE failed after start-up.
static HSE_FAILED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The clock source now: [`ClockSource::HsiFallback`] once the clock security system has
/// switched away from a failed HSE.
pub fn clock_source(at_start: ClockSource) -> ClockSource {
    if HSE_FAILED.load(core::sync::atomic::Ordering::Relaxed) {
        ClockSource::HsiFallback
    } else {
        at_start
    }
}

/// Starts the clocks ([`clock_config`]) without ever hanging: with the `hse` feature, the
/// HSE is started first and waited for at most [`HSE_STARTUP_MS`] (at the reset clock, the
/// 16 MHz HSI); if it is not ready the PLL runs from the HSI instead and the result says
/// so. With the HSE running, the clock security system is enabled: an HSE failure then
/// raises the NMI, which restarts the PLL from the HSI at the same 84 MHz.
pub fn start_clocks(rcc: pac::RCC) -> (stm32f4xx_hal::rcc::Rcc, ClockSource) {
    use stm32f4xx_hal::rcc::RccExt;
    #[cfg(all(not(feature = "qemu"), feature = "hse"))]
    {
        rcc.cr().modify(|_, w| {
            #[cfg(feature = "hse-bypass")]
            w.hsebyp().set_bit();
            w.hseon().set_bit()
        });
        // About 10 cycles per poll at 16 MHz.
        let polls = HSE_STARTUP_MS * (16_000_000 / 1000 / 10);
        let mut ready = false;
        for _ in 0..polls {
            if rcc.cr().read().hserdy().bit_is_set() {
                ready = true;
                break;
            }
        }
        if ready {
            let rcc = rcc.freeze(clock_config());
            // Note(unsafe): RCC_CR CSSON (bit 19): the clock security system watches the
            // HSE from now on; a failure raises the NMI (handler below).
            unsafe {
                (*pac::RCC::ptr())
                    .cr()
                    .modify(|r, w| w.bits(r.bits() | 1 << 19))
            };
            return (rcc, ClockSource::Hse);
        }
        rcc.cr()
            .modify(|_, w| w.hseon().clear_bit().hsebyp().clear_bit());
        (rcc.freeze(hsi_config()), ClockSource::HsiFallback)
    }
    #[cfg(any(feature = "qemu", not(feature = "hse")))]
    {
        (rcc.freeze(clock_config()), ClockSource::Hsi)
    }
}

/// The clock security system's NMI: the HSE failed, the hardware switched the system clock
/// to the HSI and stopped the PLL. Restarts the PLL from the HSI at the same 84 MHz (so the
/// timers, UARTs and flash wait states stay right) and flags the fallback.
#[cfg(all(not(feature = "qemu"), feature = "hse"))]
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    // Note(unsafe): raw RCC registers, RM0368 sec. 6.3: CIR CSSC (bit 23) clears the CSS
    // flag; PLLCFGR = HSI source, M = 16, N = 336, P = /4, Q = 7 (1 MHz VCO input, 336 MHz
    // VCO, 84 MHz SYSCLK, 48 MHz Q); PLLON (bit 24) and wait for PLLRDY (bit 25, the HSI
    // always runs); CFGR SW = PLL (0b10) and wait for SWS. Nothing else touches RCC after
    // start-up, and the NMI preempts everything, so these read-modify-writes are not raced.
    unsafe {
        let rcc = &*pac::RCC::ptr();
        rcc.cir().modify(|r, w| w.bits(r.bits() | 1 << 23));
        rcc.pllcfgr()
            .write(|w| w.bits(16 | 336 << 6 | 0b01 << 16 | 7 << 24));
        rcc.cr().modify(|r, w| w.bits(r.bits() | 1 << 24));
        while rcc.cr().read().bits() & 1 << 25 == 0 {}
        rcc.cfgr().modify(|r, w| w.bits((r.bits() & !0b11) | 0b10));
        while rcc.cfgr().read().bits() >> 2 & 0b11 != 0b10 {}
    }
    HSE_FAILED.store(true, core::sync::atomic::Ordering::Relaxed);
}

/// The HSI variant of [`clock_config`]: the same 84 MHz from the 16 MHz HSI.
#[cfg_attr(feature = "qemu", allow(dead_code))]
pub fn hsi_config() -> Config {
    use stm32f4xx_hal::prelude::*;
    Config::hsi().sysclk(84.MHz()).pclk1(42.MHz())
}

/// Clock configuration.
///
/// Board: 84 MHz from the PLL. The default build (feature `hse-bypass`) takes an 8 MHz
/// external clock on OSC_IN in bypass mode, as a Nucleo-64's ST-LINK provides; a board with
/// an 8 MHz crystal builds with `--no-default-features --features hse`; without either, the
/// PLL runs from the 16 MHz HSI, +-1 % at 25 C and +-4 % over temperature: the PPS
/// discipline still locks (its tolerance follows the clock, [`ClockSource::tolerance_ppm`]), but
/// free-running (indoor) timing is only that good and the UART baud rates may leave the
/// receivers' tolerance (docs/HARDWARE.md). APB1 = 42 MHz, so TIM2-5 count at 84 MHz;
/// APB2 = 84 MHz.
///
/// QEMU: the HSI at 16 MHz without PLL (QEMU's RCC never reports the PLL locked).
pub fn clock_config() -> Config {
    #[cfg(feature = "qemu")]
    {
        Config::hsi()
    }
    #[cfg(all(not(feature = "qemu"), feature = "hse"))]
    {
        use stm32f4xx_hal::prelude::*;
        let config = Config::hse(HSE_HZ.Hz()).sysclk(84.MHz()).pclk1(42.MHz());
        // A Nucleo-64 has no crystal: its ST-LINK feeds an 8 MHz clock (MCO) into OSC_IN,
        // which the HSE must take in bypass mode.
        #[cfg(feature = "hse-bypass")]
        let config = config.bypass_hse_oscillator();
        config
    }
    #[cfg(all(not(feature = "qemu"), not(feature = "hse")))]
    {
        hsi_config()
    }
}

/// Frequency of the HSE crystal with the `hse` feature, Hz.
#[cfg_attr(any(feature = "qemu", not(feature = "hse")), allow(dead_code))]
pub const HSE_HZ: u32 = 8_000_000;

/// Frequency of the TIM5 sample timer's ticks, Hz: TIM2-5 in QEMU count at 1 GHz of emulated
/// time whatever the clock tree says; on the board the APB1 timer clock.
pub fn timer_hz(clocks: &stm32f4xx_hal::rcc::Clocks) -> u32 {
    if cfg!(feature = "qemu") {
        1_000_000_000
    } else {
        clocks.timclk1().raw()
    }
}

/// The unit's 96-bit unique ID (zeros in QEMU, which does not map that system memory).
pub fn unique_id() -> [u8; 12] {
    #[cfg(not(feature = "qemu"))]
    {
        let mut id = [0u8; 12];
        let uid = stm32f4xx_hal::signature::Uid::get();
        id[0..2].copy_from_slice(&uid.x().to_le_bytes());
        id[2..4].copy_from_slice(&uid.y().to_le_bytes());
        id[4] = uid.waf_num();
        let lot = uid.lot_num().as_bytes();
        let n = lot.len().min(7);
        id[5..5 + n].copy_from_slice(&lot[..n]);
        id
    }
    #[cfg(feature = "qemu")]
    {
        [0u8; 12]
    }
}

/// Pins kept after configuration: the ones the firmware reads or drives.
pub struct Pins {
    /// Status LED.
    pub led: Led,
    /// Encoder fault lines.
    pub faults: FaultLines,
}

/// Configures the pins of the table above (alternate functions, pulls). Pins
/// that only carry a peripheral function are dropped: their configuration stays in the
/// GPIO registers.
pub fn pins(
    gpioa: pac::GPIOA,
    gpiob: pac::GPIOB,
    gpioc: pac::GPIOC,
    rcc: &mut stm32f4xx_hal::rcc::Rcc,
) -> Pins {
    use stm32f4xx_hal::gpio::GpioExt;
    let a = gpioa.split(rcc);
    let b = gpiob.split(rcc);
    let c = gpioc.split(rcc);
    // Left encoder on TIM2 (AF1); PA15/PB3 leave their JTAG function (SWD stays usable).
    let _ = a.pa15.into_input().into_alternate::<1>();
    let _ = b.pb3.into_input().into_alternate::<1>();
    // Right encoder on TIM3 (AF2).
    let _ = a.pa6.into_alternate::<2>();
    let _ = a.pa7.into_alternate::<2>();
    // PPS on TIM5 CH1 (AF2), pulled down so that an unplugged receiver reads as no edges.
    let _ = a.pa0.into_alternate::<2>().internal_pull_down(true);
    // Index lines on TIM2 CH3 (PB10, AF1) and TIM3 CH4 (PB1, AF2), pulled up (open-collector
    // or line-driver outputs both work).
    let _ = b.pb10.into_alternate::<1>().internal_pull_up(true);
    let _ = b.pb1.into_alternate::<2>().internal_pull_up(true);
    // USART1 RX (GNSS), USART2 TX/RX (host), AF7.
    let _ = a.pa10.into_alternate::<7>();
    let _ = a.pa2.into_alternate::<7>();
    let _ = a.pa3.into_alternate::<7>();
    Pins {
        led: Led(a.pa5.into_push_pull_output()),
        faults: FaultLines {
            left: c.pc2.into_pull_up_input(),
            right: c.pc3.into_pull_up_input(),
        },
    }
}

/// The status LED (PA5): on while the samples are locked to the PPS.
pub struct Led(stm32f4xx_hal::gpio::PA5<stm32f4xx_hal::gpio::Output>);

impl Led {
    /// Shows the lock state.
    pub fn set(&mut self, on: bool) {
        if on {
            self.0.set_high();
        } else {
            self.0.set_low();
        }
    }
}

/// The two encoder fault lines (active low, pulled up).
#[cfg_attr(feature = "qemu", allow(dead_code))]
pub struct FaultLines {
    left: stm32f4xx_hal::gpio::PC2<stm32f4xx_hal::gpio::Input>,
    right: stm32f4xx_hal::gpio::PC3<stm32f4xx_hal::gpio::Input>,
}

#[cfg_attr(feature = "qemu", allow(dead_code))]
impl FaultLines {
    /// (left, right): true when the encoder reports a fault.
    pub fn read(&self) -> (bool, bool) {
        (self.left.is_low(), self.right.is_low())
    }
}

/// Where the counts, index pulses and fault lines come from: the timers and GPIOs on the
/// board, the simulated drive in the `qemu` build.
pub struct Acquisition {
    #[cfg(not(feature = "qemu"))]
    encoders: encoders::Encoders,
    #[cfg(not(feature = "qemu"))]
    faults: FaultLines,
    #[cfg(feature = "qemu")]
    sim: sim::SimDrive,
}

impl Acquisition {
    /// From the encoder timers and the fault lines.
    #[cfg(not(feature = "qemu"))]
    pub fn new(encoders: encoders::Encoders, faults: FaultLines) -> Self {
        Self { encoders, faults }
    }

    /// From the simulated drive (the timers and fault lines are not used in QEMU).
    #[cfg(feature = "qemu")]
    pub fn new(_faults: FaultLines) -> Self {
        Self {
            sim: sim::SimDrive::new(),
        }
    }

    /// Both counters now, read first thing in the sample interrupt (the board's timers);
    /// `None` in QEMU, whose drive is sampled at the sample's tick ([`Self::snapshot`]).
    #[inline(always)]
    pub fn snapshot_now(&self) -> Option<RawCounts> {
        #[cfg(not(feature = "qemu"))]
        {
            Some(self.encoders.snapshot())
        }
        #[cfg(feature = "qemu")]
        {
            None
        }
    }

    /// Both counters at the sample instant `tick`.
    #[inline(always)]
    pub fn snapshot(&mut self, tick: u64) -> RawCounts {
        #[cfg(not(feature = "qemu"))]
        {
            let _ = tick;
            self.encoders.snapshot()
        }
        #[cfg(feature = "qemu")]
        {
            self.sim.snapshot(tick)
        }
    }

    /// The index pulse of `wheel` (0 left, 1 right) latched by its timer since the last
    /// call (the timer's capture interrupt); never one in QEMU, whose drive reports its
    /// pulses with the samples ([`Self::simulated_index`]).
    pub fn take_index(&self, wheel: usize) -> Option<IndexCapture> {
        #[cfg(not(feature = "qemu"))]
        {
            if wheel == 0 {
                self.encoders.take_index_left()
            } else {
                self.encoders.take_index_right()
            }
        }
        #[cfg(feature = "qemu")]
        {
            let _ = wheel;
            None
        }
    }

    /// Index pulses of the simulated drive since the last snapshot (none on the board,
    /// where the timers latch them).
    pub fn simulated_index(&mut self) -> [Option<u32>; 2] {
        #[allow(unused_mut)]
        let mut out = [None, None];
        #[cfg(feature = "qemu")]
        for pulse in self.sim.take_index() {
            out[pulse.wheel] = Some(pulse.raw);
        }
        out
    }

    /// The fault lines (left, right) at `tick`.
    pub fn faults(&self, tick: u64) -> (bool, bool) {
        #[cfg(not(feature = "qemu"))]
        {
            let _ = tick;
            self.faults.read()
        }
        #[cfg(feature = "qemu")]
        {
            self.sim.faults(tick)
        }
    }
}

/// A free-running cycle count for measuring code: the DWT cycle counter on the board (CPU
/// cycles at 84 MHz); in QEMU, TIM2's counter, which the `qemu` build leaves untouched and
/// which under `-icount shift=0` counts executed instructions.
#[inline(always)]
pub fn cycles() -> u32 {
    #[cfg(not(feature = "qemu"))]
    {
        cortex_m::peripheral::DWT::cycle_count()
    }
    #[cfg(feature = "qemu")]
    {
        // Note(unsafe): a read of TIM2 CNT, a register no other code of the qemu build uses
        // (the encoders are simulated); reads have no side effect.
        unsafe { (*pac::TIM2::ptr()).cnt().read().bits() }
    }
}

/// Starts what [`cycles`] reads.
pub fn start_cycle_counter(core: &mut cortex_m::Peripherals) {
    #[cfg(not(feature = "qemu"))]
    {
        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
    }
    #[cfg(feature = "qemu")]
    {
        let _ = core;
        // Note(unsafe): TIM2 CR1 = CEN; QEMU's TIM2 then counts at 1 GHz of emulated time.
        unsafe { (*pac::TIM2::ptr()).cr1().write(|w| w.bits(1)) };
    }
}
