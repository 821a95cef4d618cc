//! `e^x` as straight-line code for the first bounce's per-piece transmittances, compiled with
//! fused multiply-adds where the CPU has them.
//!
//! A render of the load test's cloud takes about a million `exp`s (two per sub-cell piece),
//! each a libm call through its errno wrapper. Inlined into an FMA-compiled caller this one
//! is a handful of FMAs and a table load that overlap with the work around them. It is
//! within about one ulp of libm's (the test `agrees_with_libm_to_two_ulps` checks), so the
//! images differ from the portable build's in the last bits only.
//!
//! The light pass's `interception` (`1 − e^{−x}` in `medium::light_pass`) is a different
//! kernel on purpose: it must keep its relative accuracy for thin cells (where `1 − exp`
//! cancels) and vectorise across rays (no table load, no branch), at 1e-9 instead of 1 ulp.

/// `e^x`: [`exp_fused`] inside FMA-compiled code (`FMA` true), libm's otherwise (without FMA
/// the polynomial is slower than the call).
#[inline(always)]
pub(crate) fn exp<const FMA: bool>(x: f64) -> f64 {
    if FMA {
        exp_fused(x)
    } else {
        x.exp()
    }
}

/// `2^{j/64}` for `j = 0..64`, each the nearest `f64` (computed to 60 digits).
const EXP2_SIXTY_FOURTHS: [u64; 64] = [
    0x3ff0000000000000,
    0x3ff02c9a3e778061,
    0x3ff059b0d3158574,
    0x3ff0874518759bc8,
    0x3ff0b5586cf9890f,
    0x3ff0e3ec32d3d1a2,
    0x3ff11301d0125b51,
    0x3ff1429aaea92de0,
    0x3ff172b83c7d517b,
    0x3ff1a35beb6fcb75,
    0x3ff1d4873168b9aa,
    0x3ff2063b88628cd6,
    0x3ff2387a6e756238,
    0x3ff26b4565e27cdd,
    0x3ff29e9df51fdee1,
    0x3ff2d285a6e4030b,
    0x3ff306fe0a31b715,
    0x3ff33c08b26416ff,
    0x3ff371a7373aa9cb,
    0x3ff3a7db34e59ff7,
    0x3ff3dea64c123422,
    0x3ff4160a21f72e2a,
    0x3ff44e086061892d,
    0x3ff486a2b5c13cd0,
    0x3ff4bfdad5362a27,
    0x3ff4f9b2769d2ca7,
    0x3ff5342b569d4f82,
    0x3ff56f4736b527da,
    0x3ff5ab07dd485429,
    0x3ff5e76f15ad2148,
    0x3ff6247eb03a5585,
    0x3ff6623882552225,
    0x3ff6a09e667f3bcd,
    0x3ff6dfb23c651a2f,
    0x3ff71f75e8ec5f74,
    0x3ff75feb564267c9,
    0x3ff7a11473eb0187,
    0x3ff7e2f336cf4e62,
    0x3ff82589994cce13,
    0x3ff868d99b4492ed,
    0x3ff8ace5422aa0db,
    0x3ff8f1ae99157736,
    0x3ff93737b0cdc5e5,
    0x3ff97d829fde4e50,
    0x3ff9c49182a3f090,
    0x3ffa0c667b5de565,
    0x3ffa5503b23e255d,
    0x3ffa9e6b5579fdbf,
    0x3ffae89f995ad3ad,
    0x3ffb33a2b84f15fb,
    0x3ffb7f76f2fb5e47,
    0x3ffbcc1e904bc1d2,
    0x3ffc199bdd85529c,
    0x3ffc67f12e57d14b,
    0x3ffcb720dcef9069,
    0x3ffd072d4a07897c,
    0x3ffd5818dcfba487,
    0x3ffda9e603db3285,
    0x3ffdfc97337b9b5f,
    0x3ffe502ee78b3ff6,
    0x3ffea4afa2a490da,
    0x3ffefa1bee615a27,
    0x3fff50765b6e4540,
    0x3fffa7c1819e90d8,
];

/// `e^x` to within about one ulp, for `x` of any value (outside `±708`, and for NaN, libm's
/// `exp` answers: the result over- or underflows there).
///
/// `x = (64 e + j) ln2/64 + r` with `|r| ≤ ln2/128`, so `e^x = 2^e 2^{j/64} e^r`, and `e^r` is
/// its degree-5 Taylor polynomial (the next term is below `4e-17`). Fast only inside a
/// function compiled with FMA (else each `mul_add` is a libm call).
#[inline(always)]
pub(crate) fn exp_fused(x: f64) -> f64 {
    // The branch is almost never taken: it costs a predicted compare.
    if !(x.abs() < 708.0) {
        return x.exp();
    }
    // 1.5 · 2^52: adding it rounds to an integer, which then sits in the low mantissa bits.
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    const SIXTY_FOUR_OVER_LN2: f64 = 92.332_482_616_893_66;
    // ln2/64 in two parts, so that r keeps the bits that k · ln2/64 cancels.
    const LN2_OVER_64_HI: f64 = 0.010_830_424_696_249_145;
    const LN2_OVER_64_LO: f64 = 3.623_510_646_634_843e-19;
    let shifted = x.mul_add(SIXTY_FOUR_OVER_LN2, SHIFT);
    let k = shifted.to_bits() as i64 - SHIFT.to_bits() as i64;
    let kd = shifted - SHIFT;
    let r = kd.mul_add(-LN2_OVER_64_LO, kd.mul_add(-LN2_OVER_64_HI, x));
    // k = 64 e + j with 0 ≤ j < 64 (two's complement: also for negative k).
    let j = (k & 63) as usize;
    let e = k >> 6;
    // |x| < 708 keeps 2^e 2^{j/64} a normal number: the exponent field does not wrap.
    let scale = f64::from_bits(EXP2_SIXTY_FOURTHS[j].wrapping_add((e as u64) << 52));
    let r2 = r * r;
    let low = r.mul_add(1.0 / 6.0, 0.5);
    let high = r.mul_add(1.0 / 120.0, 1.0 / 24.0);
    let expm1_r = r2.mul_add(r2.mul_add(high, low), r);
    scale.mul_add(expm1_r, scale)
}

#[cfg(test)]
mod tests {
    use super::exp_fused;

    /// Ulps between two finite positive floats.
    fn ulps(a: f64, b: f64) -> u64 {
        a.to_bits().abs_diff(b.to_bits())
    }

    #[test]
    fn agrees_with_libm_to_two_ulps() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst = 0;
        // Over the whole range, near zero (where pieces are thin), and at the table's seams.
        let seams = (-200..200).map(|k| k as f64 * std::f64::consts::LN_2 / 128.0);
        let samples = (0..300_000)
            .map(|i| match i % 3 {
                0 => -710.0 + 1420.0 * uniform(),
                1 => (uniform() - 0.5) * 10f64.powf(-12.0 + 13.0 * uniform()),
                _ => -40.0 * uniform(),
            })
            .chain(seams)
            .chain([
                0.0, -0.0, 1.0, -1.0, 707.9, -707.9, 708.5, -708.5, -745.0, -800.0,
            ]);
        for x in samples {
            let (got, want) = (exp_fused(x), x.exp());
            let d = ulps(got, want);
            assert!(d <= 2, "exp({x:e}) = {got:e}, libm {want:e}: {d} ulps");
            worst = worst.max(d);
        }
        assert!(exp_fused(f64::NAN).is_nan());
        assert_eq!(exp_fused(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp_fused(f64::INFINITY), f64::INFINITY);
        assert!(worst >= 1, "identical everywhere: is libm being called?");
    }
}
