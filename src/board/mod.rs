//! The board: every pin and peripheral choice of the firmware, in one place
//! (documented with a wiring table in `docs/HARDWARE.md`).
//!
//! | function                     | peripheral            | pin  | AF | notes |
//! |------------------------------|-----------------------|------|----|-------|
//! | left encoder A / B           | TIM2 CH1 / CH2, QEI x4 (32-bit) | PA15 / PB3 | 1 | boot as JTDI / JTDO: SWD only |
//! | right encoder A / B          | TIM3 CH1 / CH2, QEI x4 (16-bit) | PA6 / PA7  | 2 | |
//! | left index N                 | EXTI0, rising edge    | PB0  | -  | latches TIM2 |
//! | right index N                | EXTI1, rising edge    | PB1  | -  | latches TIM3 |
//! | left encoder fault           | GPIO in, pull-up      | PC2  | -  | active low |
//! | right encoder fault          | GPIO in, pull-up      | PC3  | -  | active low |
//! | GNSS 1-PPS                   | TIM5 CH1 input capture | PA0 | 2  | rising edge; TIM5 also times the samples |
//! | GNSS NMEA (receiver TX)      | USART1 RX             | PA10 | 7  | [`GNSS_BAUD`] 8N1, RS-232 level shifter |
//! | host link TX / RX            | USART2 TX / RX        | PA2 / PA3 | 7 | Nucleo ST-LINK virtual COM port; QEMU `-serial` #2 |
//! | status LED                   | GPIO out              | PA5  | -  | on = PPS locked (Nucleo LD2) |
//!
//! Interrupt priorities (RTIC): TIM5 sample/PPS and EXTI0/1 index = 4; USART1/USART2 = 3;
//! the processing task (SPI2 vector) = 2; the command task (SPI3 vector) = 1.
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

use stm32f4xx_hal::{pac, rcc::Config};

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

/// Watchdog timeout, milliseconds: longer than the worst-case 128 KiB sector erase (2 s at
/// x32 parallelism, during which the CPU stalls on flash reads) with margin.
pub const WATCHDOG_MS: u32 = 4_000;

/// Clock configuration.
///
/// Board: 84 MHz from the PLL. With the `hse` feature off (default) the PLL runs from the
/// 16 MHz HSI (+-1 % at 25 C: irrelevant when PPS-locked, since the period is measured); a
/// board with a crystal builds with `--features hse` for an 8 MHz HSE ([`HSE_HZ`]), which is
/// what makes free-running (indoor) sample timing accurate; a Nucleo-64, whose ST-LINK feeds
/// its 8 MHz clock into OSC_IN, builds with `--features hse-bypass`. APB1 = 42 MHz, so TIM2-5 count
/// at 84 MHz; APB2 = 84 MHz.
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
        use stm32f4xx_hal::prelude::*;
        Config::hsi().sysclk(84.MHz()).pclk1(42.MHz())
    }
}

/// Frequency of the HSE crystal with the `hse` feature, Hz.
#[cfg_attr(not(feature = "hse"), allow(dead_code))]
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
    /// Left index line (EXTI0).
    pub index_left: IndexPin<'B', 0>,
    /// Right index line (EXTI1).
    pub index_right: IndexPin<'B', 1>,
    /// Encoder fault lines.
    pub faults: FaultLines,
}

/// An index input pin, source of its EXTI line.
pub type IndexPin<const P: char, const N: u8> =
    stm32f4xx_hal::gpio::Pin<P, N, stm32f4xx_hal::gpio::Input>;

/// Configures the pins of the table above (alternate functions, pulls, EXTI lines). Pins
/// that only carry a peripheral function are dropped: their configuration stays in the
/// GPIO registers.
pub fn pins(
    gpioa: pac::GPIOA,
    gpiob: pac::GPIOB,
    gpioc: pac::GPIOC,
    syscfg: pac::SYSCFG,
    exti: &mut pac::EXTI,
    rcc: &mut stm32f4xx_hal::rcc::Rcc,
) -> Pins {
    use stm32f4xx_hal::gpio::{Edge, ExtiPin, GpioExt};
    use stm32f4xx_hal::syscfg::SysCfgExt;
    let a = gpioa.split(rcc);
    let b = gpiob.split(rcc);
    let c = gpioc.split(rcc);
    let mut syscfg = syscfg.constrain(rcc);
    // Left encoder on TIM2 (AF1); PA15/PB3 leave their JTAG function (SWD stays usable).
    let _ = a.pa15.into_input().into_alternate::<1>();
    let _ = b.pb3.into_input().into_alternate::<1>();
    // Right encoder on TIM3 (AF2).
    let _ = a.pa6.into_alternate::<2>();
    let _ = a.pa7.into_alternate::<2>();
    // PPS on TIM5 CH1 (AF2).
    let _ = a.pa0.into_alternate::<2>();
    // USART1 RX (GNSS), USART2 TX/RX (host), AF7.
    let _ = a.pa10.into_alternate::<7>();
    let _ = a.pa2.into_alternate::<7>();
    let _ = a.pa3.into_alternate::<7>();
    // Index lines: inputs with pull-ups, rising edge on EXTI0/EXTI1.
    let mut index_left = b.pb0.into_pull_up_input();
    let mut index_right = b.pb1.into_pull_up_input();
    for pin in [&mut index_left as &mut dyn ExtiPin, &mut index_right] {
        pin.make_interrupt_source(&mut syscfg);
        pin.trigger_on_edge(exti, Edge::Rising);
        pin.enable_interrupt(exti);
    }
    Pins {
        led: Led(a.pa5.into_push_pull_output()),
        index_left,
        index_right,
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

    /// Both counters at the sample instant `tick`.
    #[inline(always)]
    pub fn snapshot(&mut self, tick: u64) -> encoders::Snapshot {
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

    /// The counter of `wheel` (0 left, 1 right) now (index interrupt).
    #[inline(always)]
    pub fn latch(&self, wheel: usize) -> u32 {
        #[cfg(not(feature = "qemu"))]
        {
            if wheel == 0 {
                self.encoders.left()
            } else {
                self.encoders.right()
            }
        }
        #[cfg(feature = "qemu")]
        {
            let _ = wheel;
            0
        }
    }

    /// Index pulses of the simulated drive since the last snapshot (none on the board,
    /// where they come through EXTI).
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
