//! The panic handler: logs the panic and stops in a HardFault (`udf`), which a debug probe
//! reports with a backtrace (`probe-rs run`, `cargo embed`); without a probe the watchdog
//! resets the unit (`reset_cause = watchdog`).
//!
//! Release builds log one fixed line and leave the where to the backtrace, which the probe
//! reads from the stack and the image's debug information (file, line and the inlined
//! calls): keeping a panic's message and location in the image (`core::fmt` of the
//! `PanicInfo`, the message and `Location` of every bounds and arithmetic check) costs
//! 2.4 KiB of flash. Debug builds log the whole formatted message.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    // A panic while logging the panic stops without a second line.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        log(info);
    }
    hard_fault()
}

/// The whole message, formatted on the target.
#[cfg(debug_assertions)]
fn log(info: &PanicInfo) {
    defmt::error!("{}", defmt::Display2Format(info));
}

/// One fixed line: the probe's backtrace shows where.
#[cfg(not(debug_assertions))]
fn log(_: &PanicInfo) {
    defmt::error!("panicked (the probe's backtrace shows where)");
}

/// Raises a HardFault by `udf`, with the UsageFault handler off so that the fault is not
/// taken as a UsageFault.
fn hard_fault() -> ! {
    // Note(unsafe): SCB_SHCSR (0xE000_ED24) USGFAULTENA (bit 18) cleared; interrupts are off,
    // so nothing else accesses the register meanwhile.
    unsafe {
        let scb = &*cortex_m::peripheral::SCB::PTR;
        scb.shcsr.modify(|r| r & !(1 << 18));
    }
    cortex_m::asm::udf()
}
