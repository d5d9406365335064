//! The RTIC application of the odometry unit (STM32F401): thin wiring around `odo_core`.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "odo-unit is firmware for the STM32F401: build it with the default target \
         (thumbv7em-none-eabihf); host tools live in odoctl"
    );
}

#[cfg(target_os = "none")]
use defmt_rtt as _;
#[cfg(target_os = "none")]
use panic_probe as _;

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, dispatchers = [SPI1])]
mod app {
    use stm32f4xx_hal::{prelude::*, rcc::Config};

    #[shared]
    struct Shared {}

    #[local]
    struct Local {}

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let _rcc = cx.device.RCC.freeze(Config::hsi().sysclk(84.MHz()));
        defmt::info!("odo-unit {} booted", env!("CARGO_PKG_VERSION"));
        (Shared {}, Local {})
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }
}
