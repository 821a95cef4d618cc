//! Fused multiply-add for kernels compiled twice, once portable and once for CPUs that have
//! FMA (a `#[target_feature(enable = "fma")]` wrapper chosen at run time by [`available`]):
//! the kernel takes `const FMA: bool` and writes every `a b + c` as [`mul_add::<FMA>`], so
//! one source gives both builds. The light pass's ray sweep and the renders' light lattice
//! are written this way.

/// Whether this CPU has fused multiply-add (checked once, cached by the standard library).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `a b + c`, fused (one rounding) when `FMA`, else a multiply and an add. Pass `true` only
/// inside code compiled with FMA: elsewhere a fused multiply-add is a slow libm call.
#[inline(always)]
pub fn mul_add<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}
