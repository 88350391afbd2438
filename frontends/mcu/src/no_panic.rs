//! The panic handlers of both firmware binaries (`src/main.rs` and `src/bin/audit.rs`).

/// In a release build no code path can panic, and the linker proves it: the handler
/// calls a function that exists nowhere, so the firmware links only when the optimiser
/// has removed every call to the handler. A bounds check it cannot remove (an index it
/// cannot prove in range, a divisor it cannot prove non-zero) fails the build with
/// "undefined symbol: shearwarp_firmware_has_a_panic_path"; `frontends/mcu/panics.sh`
/// lists where those calls are.
#[cfg(not(any(debug_assertions, list_panics)))]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    extern "C" {
        fn shearwarp_firmware_has_a_panic_path() -> !;
    }
    // SAFETY: never called. The symbol is undefined on purpose: a firmware where this
    // call survives does not link.
    unsafe { shearwarp_firmware_has_a_panic_path() }
}

/// Debug builds keep their checks (overflow included): a panic ends the run with a
/// failure status. So does the build `panics.sh` inspects.
#[cfg(any(debug_assertions, list_panics))]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
