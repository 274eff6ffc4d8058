//! Denormal floats read and written as zero for the span of a closure, as inference engines
//! do (oneDNN, onnxruntime, PyTorch's `set_flush_denormal`). A network's products of small
//! weights and activations underflow into denormals, and every such operation takes a
//! microcode assist on x86: about a tenth of SPAN's run time, and more in some processes than
//! in others. Written by hand because the mode lives in one register and the standard
//! library's `_mm_setcsr` is deprecated.

/// `f()` with this thread's denormals flushed to zero (x86-64's FTZ and DAZ bits of MXCSR,
/// AArch64's FZ bit of FPCR); the thread's previous mode comes back afterwards, also on a
/// panic. Results change only where a value below 2⁻¹²⁶ would have survived, which no 8-,
/// 16-bit or half-float map can hold.
///
/// The compiler assumes the default mode and may move arithmetic on values held in registers
/// across the switch; `f` must read its inputs from memory and write its results there, as
/// the executor's layers do (the switch is a memory barrier).
pub fn flushing_denormals<R>(f: impl FnOnce() -> R) -> R {
    let _restore = Mode::flush();
    f()
}

/// The thread's floating-point mode before `flush`, put back on drop.
struct Mode(usize);

#[cfg(target_arch = "x86_64")]
impl Mode {
    const FLUSH: usize = 0x8040; // FTZ (bit 15) | DAZ (bit 6)

    fn flush() -> Mode {
        let mut csr: u32 = 0;
        // SAFETY: stmxcsr and ldmxcsr read and write this thread's SSE control register only.
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
            let flushed = csr | Self::FLUSH as u32;
            std::arch::asm!("ldmxcsr [{}]", in(reg) &flushed, options(nostack, readonly));
        }
        Mode(csr as usize)
    }
}

#[cfg(target_arch = "x86_64")]
impl Drop for Mode {
    fn drop(&mut self) {
        let csr = self.0 as u32;
        // SAFETY: as in `flush`; the value is one this thread held.
        unsafe { std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly)) };
    }
}

#[cfg(target_arch = "aarch64")]
impl Mode {
    const FLUSH: usize = 1 << 24; // FZ

    fn flush() -> Mode {
        let fpcr: usize;
        // SAFETY: reads and writes this thread's floating-point control register only.
        unsafe {
            std::arch::asm!("mrs {}, fpcr", out(reg) fpcr, options(nomem, nostack));
            std::arch::asm!("msr fpcr, {}", in(reg) fpcr | Self::FLUSH, options(nomem, nostack));
        }
        Mode(fpcr)
    }
}

#[cfg(target_arch = "aarch64")]
impl Drop for Mode {
    fn drop(&mut self) {
        // SAFETY: as in `flush`; the value is one this thread held.
        unsafe { std::arch::asm!("msr fpcr, {}", in(reg) self.0, options(nomem, nostack)) };
    }
}

#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
impl Mode {
    fn flush() -> Mode {
        Mode(0)
    }
}

#[cfg(test)]
mod tests {
    use super::flushing_denormals;
    use std::hint::black_box;

    #[test]
    fn denormals_are_zero_inside_and_kept_outside() {
        let tiny = black_box(f32::MIN_POSITIVE);
        let half = black_box(0.5f32);
        let outside = tiny * half;
        assert!(outside > 0.0 && !outside.is_normal(), "a denormal outside");
        // Through memory, as `flushing_denormals` asks (in registers the product could be
        // the one computed above).
        let inside = flushing_denormals(|| black_box(black_box(tiny) * black_box(half)));
        if cfg!(any(target_arch = "x86_64", target_arch = "aarch64")) {
            assert_eq!(inside, 0.0);
        }
        let after = black_box(black_box(tiny) * black_box(half));
        assert_eq!(after, outside, "the mode comes back");
        let caught = std::panic::catch_unwind(|| flushing_denormals(|| panic!("inside")));
        assert!(caught.is_err());
        let after = black_box(black_box(tiny) * black_box(half));
        assert_eq!(after, outside, "the mode comes back after a panic");
    }
}
