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
use odo_unit::timing::ClockSource;
use odo_unit::unit::watchdog::IwdgSetting;
use odo_unit::unit::{IndexCapture, RawCounts};
use stm32f4xx_hal::pac;

/// Widths of the raw counters (left, right), bits.
pub const COUNTER_BITS: [u32; 2] = [encoders::LEFT_BITS, encoders::RIGHT_BITS];

/// Unit of [`cycles`] in `status`.
pub const CYCLES_UNIT: &str = "cycles";

/// Where the USART1 interrupt takes NMEA bytes from: the UART.
pub type GnssRx = GnssUart;

/// What the sampler needs besides TIM5: nothing on the board (the PPS is captured by TIM5).
pub type SamplerExtra = ();

/// The GNSS receiver's UART as the USART1 interrupt reads it (`baud`: its rate, already
/// applied to the UART).
pub fn attach_gnss(uart: GnssUart, baud: u32) -> (GnssRx, SamplerExtra) {
    let _ = baud;
    (uart, ())
}

/// Polls of IWDG_SR after a prescaler and reload change: at least 1 ms at the 16 MHz HSI
/// the CPU runs from when it starts the watchdog (a poll takes at least one cycle), over
/// three times the longest update (5 LSI periods each, 0.3 ms at the slowest LSI, RM0368
/// sec. 17.4.4).
const IWDG_UPDATE_POLLS: u32 = 16_000;

/// Starts the independent watchdog with `setting` so that its first period is `setting`'s:
/// the start key (which also starts the LSI), write access, `PR` and `RLR`, then a wait (at
/// most [`IWDG_UPDATE_POLLS`] polls) until IWDG_SR shows both values in the watchdog's
/// clock domain, then a feed, which loads the counter with the new `RLR` and locks `PR` and
/// `RLR` again. Without the wait and the feed the counter would run down from its reset
/// value 0xFFF at the new prescaler until the first feed after start-up (32.8 s at /256).
/// Until the feed it runs at the reset prescaler /4: 0.35-0.96 s over the LSI's range.
/// Returns false when IWDG_SR did not clear in time (the feed then reloads the old value).
pub fn start_iwdg(iwdg: &pac::iwdg::RegisterBlock, setting: IwdgSetting) -> bool {
    iwdg.kr().write(|w| w.key().start());
    iwdg.kr().write(|w| w.key().unlock());
    // Note(unsafe): PR takes any 3-bit value (6 and 7 both divide by 256); `prescaler` is at
    // most 6 (`IwdgSetting::for_timeout`).
    iwdg.pr()
        .write(|w| unsafe { w.pr().bits(setting.prescaler & 0b111) });
    iwdg.rlr().write(|w| w.rl().set(setting.reload));
    let mut updated = false;
    for _ in 0..IWDG_UPDATE_POLLS {
        let sr = iwdg.sr().read();
        if sr.pvu().bit_is_clear() && sr.rvu().bit_is_clear() {
            updated = true;
            break;
        }
    }
    iwdg.kr().write(|w| w.key().feed());
    updated
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

/// Polls of PLLRDY before the PLL counts as not locking: at least 2 ms at the 16 MHz HSI
/// that runs the CPU whenever the PLL is started (start-up, and the clock security system's
/// NMI after the hardware switched to the HSI; a poll takes at least one cycle, about eight
/// in practice: 16 ms), against a lock time of at most 300 us (datasheet DS10086, main PLL
/// characteristics).
const PLL_LOCK_POLLS: u32 = 2 * 16_000;

/// Polls of a clock switch (SWS) or of the PLL's stop (PLLRDY cleared), which take a few
/// cycles of the clocks involved.
const SWITCH_POLLS: u32 = 1_000;

/// Starts the clocks (84 MHz from the PLL, [`BUS_CLOCKS`]) without ever hanging: with the
/// `hse` feature, the HSE is started first and waited for at most [`HSE_STARTUP_MS`] (at the
/// reset clock, the 16 MHz HSI), then the PLL from it for at most [`PLL_LOCK_POLLS`]; if
/// either fails the PLL runs from the HSI instead and the result says so
/// ([`ClockSource::HsiFallback`]). Once the PLL has locked on the HSE, the clock security
/// system is enabled, before the switch to the PLL: an HSE failure from then on raises the
/// NMI, which restarts the PLL from the HSI at the same 84 MHz.
///
/// Board: the default build (feature `hse-bypass`) takes an 8 MHz external clock on OSC_IN
/// in bypass mode, as a Nucleo-64's ST-LINK provides; a board with an 8 MHz crystal builds
/// with `--no-default-features --features hse`; without either, the PLL runs from the 16 MHz
/// HSI, +-1 % at 25 C, +-4 % from -10 to 85 C and -8/+4.5 % from -40 to 105 C (DS10086): the
/// PPS discipline locks within +-5 % ([`ClockSource::tolerance_ppm`]), free-running
/// (indoor) timing is only that good and the UART baud rates may leave the receivers'
/// tolerance (docs/HARDWARE.md). APB1 = 42 MHz, so TIM2-5 count at 84 MHz; APB2 = 84 MHz.
pub fn start_clocks(rcc: pac::RCC) -> (stm32f4xx_hal::rcc::Rcc, ClockSource, BusClocks) {
    use stm32f4xx_hal::rcc::RccExt;
    set_flash_wait_states();
    #[cfg(feature = "hse")]
    {
        rcc.cr().modify(|_, w| {
            #[cfg(feature = "hse-bypass")]
            w.hsebyp().set_bit();
            w.hseon().set_bit()
        });
        // About 10 cycles per poll at 16 MHz.
        let polls = HSE_STARTUP_MS * (16_000_000 / 1000 / 10);
        if poll(polls, || rcc.cr().read().hserdy().bit_is_set()) && lock_pll(&rcc, true) {
            // Note(unsafe): RCC_CR CSSON (bit 19): the clock security system watches the
            // HSE from now on; a failure raises the NMI (handler below).
            rcc.cr()
                .modify(|r, w| unsafe { w.bits(r.bits() | 1 << 19) });
            switch_to_pll(&rcc);
            return (rcc.constrain(), ClockSource::Hse, BUS_CLOCKS);
        }
        // HSEBYP may change only while the HSE is off.
        rcc.cr().modify(|_, w| w.hseon().clear_bit());
        rcc.cr().modify(|_, w| w.hsebyp().clear_bit());
        run_from_hsi_pll(&rcc);
        (rcc.constrain(), ClockSource::HsiFallback, BUS_CLOCKS)
    }
    #[cfg(not(feature = "hse"))]
    {
        run_from_hsi_pll(&rcc);
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

/// True once `done` holds, false after `polls` polls without it.
fn poll(polls: u32, mut done: impl FnMut() -> bool) -> bool {
    (0..polls).any(|_| done())
}

/// Flash wait states and caches for 84 MHz, once at start-up before the PLL runs: 2 WS
/// (RM0368 sec. 3.4.1, table 6: 2 WS for 60-84 MHz at 2.7-3.6 V, the board's 3.3 V supply),
/// prefetch, I- and D-cache. Both PLL sources give the same 84 MHz, so nothing changes
/// these again but the flash driver's data cache resets (`real/flash.rs`).
fn set_flash_wait_states() {
    // Note(unsafe): FLASH_ACR LATENCY = 2 (bits 0-3), PRFTEN (8), ICEN (9), DCEN (10),
    // raw values from RM0368 sec. 3.8.1. Written here, before the flash driver exists and
    // before the clock security system (the NMI) is on, so the read-modify-write is not raced.
    unsafe {
        let flash = &*pac::FLASH::ptr();
        flash
            .acr()
            .modify(|r, w| w.bits((r.bits() & !0xF) | 2 | 0b111 << 8));
    }
}

/// Configures the PLL for 84 MHz from the HSE (`hse`, already running) or the HSI and waits
/// at most [`PLL_LOCK_POLLS`] for the lock; false (PLL off again) if it does not lock. The
/// PLL is stopped first: PLLCFGR may only change while it is off. SYSCLK must not be the
/// PLL (start-up runs from the HSI; the hardware switched to it before the NMI).
fn lock_pll(rcc: &pac::rcc::RegisterBlock, hse: bool) -> bool {
    const PLLON: u32 = 1 << 24;
    const PLLRDY: u32 = 1 << 25;
    // Note(unsafe): raw RCC register values from RM0368 sec. 6.3: RCC_CR PLLON (24) cleared,
    // PLLRDY (25) awaited, RCC_PLLCFGR ([`pllcfgr`]), PLLON set. Only start-up and the NMI
    // run this; start-up runs it before the clock security system is on, so the NMI cannot
    // preempt it.
    unsafe {
        rcc.cr().modify(|r, w| w.bits(r.bits() & !PLLON));
        poll(SWITCH_POLLS, || rcc.cr().read().bits() & PLLRDY == 0);
        rcc.pllcfgr().write(|w| w.bits(pllcfgr(hse)));
        rcc.cr().modify(|r, w| w.bits(r.bits() | PLLON));
    }
    if poll(PLL_LOCK_POLLS, || rcc.cr().read().bits() & PLLRDY != 0) {
        return true;
    }
    // Note(unsafe): RCC_CR PLLON (24) cleared: the PLL that did not lock is stopped.
    rcc.cr().modify(|r, w| unsafe { w.bits(r.bits() & !PLLON) });
    false
}

/// Runs SYSCLK from the locked PLL: AHB /1, APB1 /2, APB2 /1, then the switch (SW = PLL,
/// waited for at most [`SWITCH_POLLS`]; a switch that does not happen leaves every clock
/// wrong: a panic, and the watchdog resets). Once the clock security system is on the NMI may
/// preempt this; every step here is idempotent with the NMI's own switch, so the end state is
/// the same: SYSCLK from the PLL with these prescalers.
fn switch_to_pll(rcc: &pac::rcc::RegisterBlock) {
    // Note(unsafe): raw RCC_CFGR values from RM0368 sec. 6.3.3: HPRE = 0 (bits 4-7),
    // PPRE1 = 0b100 (/2, bits 10-12), PPRE2 = 0 (bits 13-15), then SW = 0b10 (PLL, bits 0-1);
    // SWS (bits 2-3) shows the switch.
    unsafe {
        rcc.cfgr()
            .modify(|r, w| w.bits((r.bits() & !0xFCF0) | 0b100 << 10));
        cortex_m::asm::delay(16);
        rcc.cfgr().modify(|r, w| w.bits((r.bits() & !0b11) | 0b10));
    }
    if !poll(SWITCH_POLLS, || {
        rcc.cfgr().read().bits() >> 2 & 0b11 == 0b10
    }) {
        panic!("SYSCLK did not switch to the PLL");
    }
}

/// SYSCLK at 84 MHz from the PLL fed by the HSI. The HSI always runs, so a PLL that does not
/// lock on it is a broken part: a panic, and the watchdog resets.
fn run_from_hsi_pll(rcc: &pac::rcc::RegisterBlock) {
    if !lock_pll(rcc, false) {
        panic!("the PLL does not lock on the HSI");
    }
    switch_to_pll(rcc);
}

/// The clock security system's NMI: the HSE failed, the hardware switched the system clock
/// to the HSI (stopping the PLL if it ran from the HSE). Restarts the PLL from the HSI at the
/// same 84 MHz (so the timers, UARTs and flash wait states stay right) and flags the
/// fallback.
#[cfg(feature = "hse")]
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    // Note(unsafe): raw RCC registers, RM0368 sec. 6.3: CIR CSSC (bit 23) clears the CSS
    // flag; then the PLL from the HSI ([`run_from_hsi_pll`]; the HSI always runs).
    let rcc = unsafe { &*pac::RCC::ptr() };
    rcc.cir()
        .modify(|r, w| unsafe { w.bits(r.bits() | 1 << 23) });
    run_from_hsi_pll(rcc);
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

/// The low 32 bits of the sample timeline's tick now: TIM5's counter (the timeline is the
/// counter extended to 64 bits, `src/board/sampler.rs`).
#[inline(always)]
pub fn tick_now() -> u32 {
    // Note(unsafe): a read of TIM5 CNT; reads have no side effect.
    unsafe { (*pac::TIM5::ptr()).cnt().read().bits() }
}

/// Starts what [`cycles`] reads.
pub fn start_cycle_counter(core: &mut cortex_m::Peripherals) {
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
}
