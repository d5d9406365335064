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
//! | GNSS NMEA (receiver TX)      | USART1 RX             | PA10 | 7  | `gnss_baud` setting 8N1, RS-232 level shifter, pull-up |
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
//! from a deterministic simulated drive, the PPS captures and NMEA bytes from a simulated
//! GNSS receiver, the settings flash is RAM. What differs between the two lives in
//! [`variant`] (`real/` or `qemu/`).

pub mod flash;
pub mod sampler;
pub mod serial;
pub mod stack;

/// The board this build runs on: the STM32F401 board (`real/`) or QEMU's `netduinoplus2`
/// (`qemu/`, feature `qemu`). Both offer the same items.
#[cfg_attr(not(feature = "qemu"), path = "real/mod.rs")]
#[cfg_attr(feature = "qemu", path = "qemu/mod.rs")]
pub mod variant;

pub use variant::{
    attach_gnss, cycles, start_clocks, start_cycle_counter, tick_now, timer_hz, unique_id,
    Acquisition, GnssRx, SamplerExtra, COUNTER_BITS, CYCLES_UNIT,
};

use odo_unit::unit::watchdog::{IwdgSetting, LSI_MAX_HZ, LSI_NOMINAL_HZ};
use stm32f4xx_hal::pac;

/// The bus clocks the peripherals run at, Hz.
#[derive(Debug, Clone, Copy)]
pub struct BusClocks {
    /// APB1 (USART2).
    pub pclk1: u32,
    /// APB2 (USART1).
    pub pclk2: u32,
    /// The APB1 timers (TIM2-5).
    pub timer: u32,
}

/// Watchdog timeout, milliseconds, at the LSI's nominal 32 kHz. The LSI runs anywhere
/// from 17 to 47 kHz (datasheet DS10086), so the real timeout lies between 2.7 s and 7.5 s
/// ([`WATCHDOG_MIN_MS`]).
pub const WATCHDOG_MS: u32 = 4_000;

/// The IWDG setting for [`WATCHDOG_MS`]: /32, reload 3999.
pub const WATCHDOG: IwdgSetting = match IwdgSetting::for_timeout(WATCHDOG_MS, LSI_NOMINAL_HZ) {
    Some(setting) => setting,
    None => panic!("WATCHDOG_MS outside the IWDG's range"),
};

/// Shortest watchdog timeout over the LSI's range (47 kHz), milliseconds: 2,723, which is
/// 3.4 times the longest flash stall ([`flash::MAX_ERASE_MS`], 800 ms), before which the
/// flash driver feeds the watchdog.
pub const WATCHDOG_MIN_MS: u32 = WATCHDOG.timeout_us(LSI_MAX_HZ) / 1000;

const _: () = assert!(WATCHDOG_MIN_MS > 3 * flash::MAX_ERASE_MS);

use odo_unit::protocol::{reset_cause::RCC_CSR_RMVF, ResetCause};
pub use odo_unit::timing::ClockSource;

/// The watchdog stops while a debugger halts the core (DBGMCU_APB1_FZ DBG_IWDG_STOP), so
/// that a debug session is not reset; the `watchdog-in-debug` feature keeps it running,
/// for the watchdog bring-up check (docs/HARDWARE.md).
pub const WATCHDOG_STOPS_IN_DEBUG: bool = !cfg!(feature = "watchdog-in-debug");

/// Starts the independent watchdog ([`WATCHDOG`]; stopped while halted by a debugger
/// unless the `watchdog-in-debug` feature is on). Its first period is already the configured
/// one: the start waits for the new prescaler and reload value to reach the watchdog and
/// feeds it once ([`variant::start_iwdg`]).
pub fn start_watchdog(
    iwdg: pac::IWDG,
    dbgmcu: &pac::DBGMCU,
) -> stm32f4xx_hal::watchdog::IndependentWatchdog {
    dbgmcu
        .apb1_fz()
        .modify(|_, w| w.dbg_iwdg_stop().bit(WATCHDOG_STOPS_IN_DEBUG));
    if !variant::start_iwdg(&iwdg, WATCHDOG) {
        defmt::error!("watchdog: prescaler/reload update not confirmed (IWDG_SR)");
    }
    stm32f4xx_hal::watchdog::IndependentWatchdog::new(iwdg)
}

/// Keeps the debug port usable while the core sleeps in `wfi`, in debug builds: DBGMCU_CR
/// DBG_SLEEP keeps HCLK running in Sleep mode, so that a debugger can attach to a sleeping
/// core and read its memory (RTT). Set before every sleep, because probe-rs clears it when a
/// session ends. Release builds sleep with HCLK off; the probe connects under reset
/// (`Embed.toml`, the runner in `.cargo/config.toml`).
#[inline(always)]
pub fn keep_debug_port_awake() {
    #[cfg(debug_assertions)]
    // Note(unsafe): DBGMCU_CR DBG_SLEEP (bit 0) set; only this code and the debugger write
    // the register, and a debugger's write in between is only undone for DBG_SLEEP.
    unsafe {
        (*pac::DBGMCU::ptr())
            .cr()
            .modify(|_, w| w.dbg_sleep().set_bit())
    };
}

/// Why the MCU last started, read from RCC_CSR once at start.
static RESET_CAUSE: core::sync::atomic::AtomicU8 = core::sync::atomic::AtomicU8::new(0);

/// Reads why the MCU started (RCC_CSR, [`ResetCause::from_rcc_csr`]) and clears the flags,
/// so that the next start sees only its own cause; once, at start.
pub fn take_reset_cause(rcc: &pac::RCC) -> ResetCause {
    let cause = ResetCause::from_rcc_csr(rcc.csr().read().bits());
    // Note(unsafe): RCC_CSR RMVF (bit 24) clears the reset flags; LSION is kept.
    rcc.csr()
        .modify(|r, w| unsafe { w.bits(r.bits() | RCC_CSR_RMVF) });
    RESET_CAUSE.store(cause.code(), core::sync::atomic::Ordering::Relaxed);
    cause
}

/// Why the MCU last started ([`take_reset_cause`]).
pub fn reset_cause() -> ResetCause {
    ResetCause::from_code(RESET_CAUSE.load(core::sync::atomic::Ordering::Relaxed))
}

/// Set by the clock security system's NMI when the HSE failed after start-up.
pub(crate) static HSE_FAILED: core::sync::atomic::AtomicBool =
    core::sync::atomic::AtomicBool::new(false);

/// The clock source now: [`ClockSource::HsiFallback`] once the clock security system has
/// switched away from a failed HSE.
pub fn clock_source(at_start: ClockSource) -> ClockSource {
    if HSE_FAILED.load(core::sync::atomic::Ordering::Relaxed) {
        ClockSource::HsiFallback
    } else {
        at_start
    }
}

/// What `status` reports of the board, `at_start` being the clock source start-up found.
pub fn report(at_start: ClockSource) -> odo_unit::unit::BoardReport {
    odo_unit::unit::BoardReport {
        clock: clock_source(at_start),
        stack: stack::high_water(),
        cycles_unit: CYCLES_UNIT,
        reset_cause: reset_cause(),
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
/// that only carry a peripheral function are set in the GPIO registers directly (the HAL's
/// typestate conversions cost flash for nothing kept); the LED and the fault lines stay HAL
/// pins.
pub fn pins(
    gpioa: pac::GPIOA,
    // Taken, so that nothing else owns port B; its registers are written below.
    _gpiob: pac::GPIOB,
    gpioc: pac::GPIOC,
    rcc: &mut stm32f4xx_hal::rcc::Rcc,
) -> Pins {
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::rcc::{Enable, Reset};
    let a = gpioa.split(rcc);
    let c = gpioc.split(rcc);
    // Port B as `split` leaves a port: clock on, registers at their reset values.
    pac::GPIOB::enable(rcc);
    pac::GPIOB::reset(rcc);
    // Note(unsafe): port A's registers, whose pins PA0, PA2, PA3, PA6, PA7, PA10 and PA15 no
    // HAL pin owns (dropped by `split`'s caller); only their fields are changed.
    let pa = unsafe { &*pac::GPIOA::ptr() };
    // Port A: PA0 TIM5 CH1 (AF2, PPS, pulled down so that an unplugged receiver reads as no
    // edges); PA2, PA3 USART2 TX/RX (AF7, host); PA6, PA7 TIM3 CH1/CH2 (AF2, right
    // encoder); PA10 USART1 RX (AF7, GNSS, pulled up: an unplugged receiver, or its RS-232
    // transceiver without power, reads as an idle line, not noise); PA15 TIM2 CH1 (AF1,
    // left encoder; it leaves its JTAG function, SWD stays usable; its reset pull-up stays).
    apply(pa, &PORT_A);
    // Note(unsafe): port B's registers as port A's block: the PAC gives each port its own
    // type for its reset values, the register layout is the same (RM0368 sec. 8.4.11).
    let pb = unsafe { &*(pac::GPIOB::ptr() as *const pac::gpioa::RegisterBlock) };
    apply(pb, &PORT_B);
    Pins {
        led: Led(a.pa5.into_push_pull_output()),
        faults: FaultLines {
            left: c.pc2.into_pull_up_input(),
            right: c.pc3.into_pull_up_input(),
        },
    }
}

/// GPIOx_PUPDR: pull-up.
const PULL_UP: u32 = 0b01;
/// GPIOx_PUPDR: pull-down.
const PULL_DOWN: u32 = 0b10;

/// Port A: PA0 TIM5 CH1 (AF2, PPS, pulled down so that an unplugged receiver reads as no
/// edges); PA2, PA3 USART2 TX/RX (AF7, host); PA6, PA7 TIM3 CH1/CH2 (AF2, right encoder);
/// PA10 USART1 RX (AF7, GNSS, pulled up: an unplugged receiver, or its RS-232 transceiver
/// without power, reads as an idle line, not noise); PA15 TIM2 CH1 (AF1, left encoder; it
/// leaves its JTAG function, SWD stays usable; its reset pull-up stays).
const PORT_A: PortConfig = PortConfig::new(
    &[(0, 2), (2, 7), (3, 7), (6, 2), (7, 2), (10, 7), (15, 1)],
    &[(0, PULL_DOWN), (10, PULL_UP)],
);

/// Port B: PB1 TIM3 CH4 (AF2, right index) and PB10 TIM2 CH3 (AF1, left index), pulled up
/// (open-collector or line-driver outputs both work); PB3 TIM2 CH2 (AF1, left encoder).
const PORT_B: PortConfig =
    PortConfig::new(&[(1, 2), (3, 1), (10, 1)], &[(1, PULL_UP), (10, PULL_UP)]);

/// Register fields of a port's alternate-function pins: values and masks of AFRL/AFRH,
/// MODER and PUPDR (RM0368 sec. 8.4).
struct PortConfig {
    afr: [u32; 2],
    afr_mask: [u32; 2],
    moder: u32,
    moder_mask: u32,
    pupdr: u32,
    pupdr_mask: u32,
}

impl PortConfig {
    /// The `(pin, alternate function)` pins in alternate-function mode (MODER 0b10) and
    /// the `(pin, PUPDR value)` pulls.
    const fn new(afs: &[(u32, u32)], pulls: &[(u32, u32)]) -> Self {
        let mut c = Self {
            afr: [0; 2],
            afr_mask: [0; 2],
            moder: 0,
            moder_mask: 0,
            pupdr: 0,
            pupdr_mask: 0,
        };
        let mut i = 0;
        while i < afs.len() {
            let (pin, af) = afs[i];
            let (reg, shift) = ((pin / 8) as usize, (pin % 8) * 4);
            c.afr[reg] |= af << shift;
            c.afr_mask[reg] |= 0xF << shift;
            c.moder |= 0b10 << (2 * pin);
            c.moder_mask |= 0b11 << (2 * pin);
            i += 1;
        }
        let mut i = 0;
        while i < pulls.len() {
            let (pin, pull) = pulls[i];
            c.pupdr |= pull << (2 * pin);
            c.pupdr_mask |= 0b11 << (2 * pin);
            i += 1;
        }
        c
    }
}

/// Writes `c` into a port: AFRL/AFRH first, then MODER, as the HAL does, then PUPDR; the
/// other pins' fields are kept.
fn apply(port: &pac::gpioa::RegisterBlock, c: &PortConfig) {
    // Note(unsafe): read-modify-write of whole GPIO registers; every field written holds a
    // valid value (AF 0-15, MODER 0b10, PUPDR 0b01 or 0b10).
    unsafe {
        port.afrl()
            .modify(|r, w| w.bits(r.bits() & !c.afr_mask[0] | c.afr[0]));
        port.afrh()
            .modify(|r, w| w.bits(r.bits() & !c.afr_mask[1] | c.afr[1]));
        port.moder()
            .modify(|r, w| w.bits(r.bits() & !c.moder_mask | c.moder));
        port.pupdr()
            .modify(|r, w| w.bits(r.bits() & !c.pupdr_mask | c.pupdr));
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
