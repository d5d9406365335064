//! The STM32F401 board: the encoder timers, the settings sectors of the MCU's flash, TIM5's
//! output compare and PPS capture, the HSE clock with the clock security system, the DWT
//! cycle counter, logging over RTT.

pub mod encoders;
pub mod flash;
pub mod sampler;

use super::serial::GnssUart;
use super::BusClocks;
use super::FaultLines;
use defmt_rtt as _;
use odo_core::timing::ClockSource;
use odo_core::unit::{IndexCapture, RawCounts};
use stm32f4xx_hal::pac;

/// Widths of the raw counters (left, right), bits.
pub const COUNTER_BITS: [u32; 2] = [encoders::LEFT_BITS, encoders::RIGHT_BITS];

/// Unit of [`cycles`] in `status`.
pub const CYCLES_UNIT: &str = "cycles";

/// Where the USART1 interrupt takes NMEA bytes from: the UART.
pub type GnssRx = GnssUart;

/// What the sampler needs besides TIM5: nothing on the board (the PPS is captured by TIM5).
pub type SamplerExtra = ();

/// The GNSS receiver's UART as the USART1 interrupt reads it.
pub fn attach_gnss(uart: GnssUart) -> (GnssRx, SamplerExtra) {
    (uart, ())
}

/// Reloads the independent watchdog from anywhere (the flash driver, just before an erase).
pub fn watchdog_feed() {
    // Note(unsafe): a write of the reload key 0xAAAA to IWDG_KR, a write-only register whose
    // only effect is the reload; atomic, and harmless before the watchdog is started.
    unsafe { (*pac::IWDG::ptr()).kr().write(|w| w.bits(0xAAAA)) };
}

/// How long start-up waits for the HSE to become ready, milliseconds (a crystal takes about
/// 2 ms; an external clock is ready at once).
#[cfg_attr(not(feature = "hse"), allow(dead_code))]
pub const HSE_STARTUP_MS: u32 = 100;

/// Starts the clocks (84 MHz from the PLL, [`BUS_CLOCKS`]) without ever hanging: with the
/// `hse` feature, the HSE is started first and waited for at most [`HSE_STARTUP_MS`] (at the
/// reset clock, the 16 MHz HSI); if it is not ready the PLL runs from the HSI instead and the
/// result says so. With the HSE running, the clock security system is enabled: an HSE
/// failure then raises the NMI, which restarts the PLL from the HSI at the same 84 MHz.
///
/// Board: the default build (feature `hse-bypass`) takes an 8 MHz external clock on OSC_IN
/// in bypass mode, as a Nucleo-64's ST-LINK provides; a board with an 8 MHz crystal builds
/// with `--no-default-features --features hse`; without either, the PLL runs from the 16 MHz
/// HSI, +-1 % at 25 C and +-4 % over temperature: the PPS discipline still locks (its
/// tolerance follows the clock, [`ClockSource::tolerance_ppm`]), but free-running (indoor)
/// timing is only that good and the UART baud rates may leave the receivers' tolerance
/// (docs/HARDWARE.md). APB1 = 42 MHz, so TIM2-5 count at 84 MHz; APB2 = 84 MHz.
pub fn start_clocks(rcc: pac::RCC) -> (stm32f4xx_hal::rcc::Rcc, ClockSource, BusClocks) {
    use stm32f4xx_hal::rcc::RccExt;
    #[cfg(feature = "hse")]
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
            start_pll(&rcc, true);
            // Note(unsafe): RCC_CR CSSON (bit 19): the clock security system watches the
            // HSE from now on; a failure raises the NMI (handler below).
            rcc.cr()
                .modify(|r, w| unsafe { w.bits(r.bits() | 1 << 19) });
            return (rcc.constrain(), ClockSource::Hse, BUS_CLOCKS);
        }
        rcc.cr()
            .modify(|_, w| w.hseon().clear_bit().hsebyp().clear_bit());
        start_pll(&rcc, false);
        (rcc.constrain(), ClockSource::HsiFallback, BUS_CLOCKS)
    }
    #[cfg(not(feature = "hse"))]
    {
        start_pll(&rcc, false);
        (rcc.constrain(), ClockSource::Hsi, BUS_CLOCKS)
    }
}

/// The bus clocks [`start_clocks`] sets up: APB1 42 MHz (its timers 84 MHz), APB2 84 MHz.
pub const BUS_CLOCKS: BusClocks = BusClocks {
    pclk1: 42_000_000,
    pclk2: 84_000_000,
    timer: 84_000_000,
};

/// PLLCFGR for 84 MHz SYSCLK from an 8 MHz HSE (`hse`) or the 16 MHz HSI: M = 4 or 8
/// (2 MHz VCO input), N = 168 (336 MHz VCO), P = /4 (0b01: 84 MHz), Q = 7 (48 MHz), PLLSRC
/// (bit 22) = HSE or HSI; reserved bit 29 kept at its reset value, 1 (RM0368 sec. 6.3.2).
/// The same values the HAL's clock solver finds for these clocks.
const fn pllcfgr(hse: bool) -> u32 {
    let m = if hse { HSE_HZ / 2_000_000 } else { 8 };
    m | 168 << 6 | 0b01 << 16 | (hse as u32) << 22 | 7 << 24 | 1 << 29
}

const _: () = assert!(pllcfgr(false) == 0x2701_2A08 && pllcfgr(true) == 0x2741_2A04);

/// Runs SYSCLK at 84 MHz from the PLL fed by the HSE (`hse`, already running) or the HSI:
/// flash wait states and caches first (2 WS up to 90 MHz at 2.7-3.6 V, prefetch, I- and
/// D-cache: RM0368 sec. 3.4), the PLL, AHB /1, APB1 /2, APB2 /1, then the switch. Also the
/// clock security system's NMI, after the hardware stopped the PLL and switched to the HSI.
fn start_pll(rcc: &pac::rcc::RegisterBlock, hse: bool) {
    // Note(unsafe): raw register values from RM0368: FLASH_ACR LATENCY = 2 (bits 0-3),
    // PRFTEN (8), ICEN (9), DCEN (10); RCC_PLLCFGR ([`pllcfgr`]); RCC_CR PLLON (24), wait for
    // PLLRDY (25); RCC_CFGR HPRE = 0 (bits 4-7), PPRE1 = 0b100 (/2, bits 10-12), PPRE2 = 0
    // (bits 13-15), then SW = 0b10 (PLL) and wait for SWS (bits 2-3). Only start-up and the
    // NMI (which preempts everything) touch these, so the read-modify-writes are not raced.
    unsafe {
        let flash = &*pac::FLASH::ptr();
        flash
            .acr()
            .modify(|r, w| w.bits((r.bits() & !0xF) | 2 | 0b111 << 8));
        rcc.pllcfgr().write(|w| w.bits(pllcfgr(hse)));
        rcc.cr().modify(|r, w| w.bits(r.bits() | 1 << 24));
        while rcc.cr().read().bits() & 1 << 25 == 0 {}
        rcc.cfgr()
            .modify(|r, w| w.bits((r.bits() & !0xFCF0) | 0b100 << 10));
        cortex_m::asm::delay(16);
        rcc.cfgr().modify(|r, w| w.bits((r.bits() & !0b11) | 0b10));
        while rcc.cfgr().read().bits() >> 2 & 0b11 != 0b10 {}
    }
}

/// The clock security system's NMI: the HSE failed, the hardware switched the system clock
/// to the HSI and stopped the PLL. Restarts the PLL from the HSI at the same 84 MHz (so the
/// timers, UARTs and flash wait states stay right) and flags the fallback.
#[cfg(feature = "hse")]
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    // Note(unsafe): raw RCC registers, RM0368 sec. 6.3: CIR CSSC (bit 23) clears the CSS
    // flag; then the PLL from the HSI ([`start_pll`]; the HSI always runs).
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.cir()
        .modify(|r, w| unsafe { w.bits(r.bits() | 1 << 23) });
    start_pll(rcc, false);
    super::HSE_FAILED.store(true, core::sync::atomic::Ordering::Relaxed);
}

/// Frequency of the HSE crystal with the `hse` feature, Hz.
pub const HSE_HZ: u32 = 8_000_000;

/// Frequency of the TIM5 sample timer's ticks, Hz: the APB1 timer clock.
pub fn timer_hz(clocks: &BusClocks) -> u32 {
    clocks.timer
}

/// The unit's 96-bit unique ID.
pub fn unique_id() -> [u8; 12] {
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

/// Where the counts, index pulses and fault lines come from: the encoder timers and the
/// fault GPIOs.
pub struct Acquisition {
    encoders: encoders::Encoders,
    faults: FaultLines,
}

impl Acquisition {
    /// Starts the encoder timers TIM2 (left) and TIM3 (right); reads `faults`.
    pub fn new(
        tim2: pac::TIM2,
        tim3: pac::TIM3,
        faults: FaultLines,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> Self {
        Self {
            encoders: encoders::Encoders::new(tim2, tim3, rcc),
            faults,
        }
    }

    /// Both counters now, read first thing in the sample interrupt.
    #[inline(always)]
    pub fn snapshot_now(&self) -> Option<RawCounts> {
        Some(self.encoders.snapshot())
    }

    /// Both counters at the sample instant `tick` (read now: the timers count by themselves).
    #[inline(always)]
    pub fn snapshot(&mut self, tick: u64) -> RawCounts {
        let _ = tick;
        self.encoders.snapshot()
    }

    /// The index pulse of `wheel` (0 left, 1 right) latched by its timer since the last
    /// call (the timer's capture interrupt).
    pub fn take_index(&self, wheel: usize) -> Option<IndexCapture> {
        if wheel == 0 {
            self.encoders.take_index_left()
        } else {
            self.encoders.take_index_right()
        }
    }

    /// Index pulses that come with the sample: none on the board, where the timers latch
    /// them ([`Self::take_index`]).
    pub fn sample_index(&mut self) -> [Option<u32>; 2] {
        [None, None]
    }

    /// The fault lines (left, right) at `tick` (read now).
    pub fn faults(&self, tick: u64) -> (bool, bool) {
        let _ = tick;
        self.faults.read()
    }
}

/// A free-running cycle count for measuring code: the DWT cycle counter (CPU cycles at
/// 84 MHz).
#[inline(always)]
pub fn cycles() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// Starts what [`cycles`] reads.
pub fn start_cycle_counter(core: &mut cortex_m::Peripherals) {
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
}
