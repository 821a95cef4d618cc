//! Blackbody (Planck) emission and its colour, for fire and other hot media: Planck's
//! spectral radiance `B(λ, T)`, its CIE 1931 XYZ and its linear sRGB (D65) triple.
//!
//! The colour-matching functions are the CIE 1931 2° standard observer tabulated at 5 nm
//! (linearly interpolated), integrated against Planck's law over 360–830 nm at 1 nm with the
//! trapezoid rule. (The multi-lobe analytic fit of Wyman, Sloan & Shirley 2013 was tried
//! first: it puts 1500 K at (0.5813, 0.3975), 0.0044 off the Planckian locus, too far for a
//! colour test at ±0.003, so the table is used.)
//!
//! # Units
//! - [`planck`]: W·sr⁻¹·m⁻³ (radiance per metre of wavelength).
//! - [`xyz`]: photometric, `Y` is the luminance in cd/m² (`683 lm/W × ∫ B ȳ dλ`), X and Z on
//!   the same scale.
//! - [`rgb`]: linear sRGB in units of [`LUMINANCE_UNIT`] = 10⁶ cd/m², so that the luminance
//!   `0.2126 R + 0.7152 G + 0.0722 B` of an in-gamut colour is `Y / 10⁶`. A blackbody's
//!   luminance is about 8e-9 of that unit at 800 K, 0.0077 at 1500 K, 0.12 at 1800 K, 20 at
//!   2856 K: a fire's hottest parts are of order 0.1–1, and a scene's `scale` stays readable.

/// Planck constant (J·s).
const H: f64 = 6.626_070_15e-34;
/// Speed of light (m/s).
const C: f64 = 299_792_458.0;
/// Boltzmann constant (J/K).
const K_B: f64 = 1.380_649e-23;
/// Luminous efficacy of the photopic peak (lm/W).
pub const KM: f64 = 683.0;
/// The luminance that [`rgb`] reports as 1 (cd/m²).
pub const LUMINANCE_UNIT: f64 = 1.0e6;
/// Wavelength range of the colour integrals (nm).
pub const LAMBDA_MIN_NM: f64 = 360.0;
pub const LAMBDA_MAX_NM: f64 = 830.0;

/// Planck's spectral radiance at wavelength `lambda` (metres) and temperature `t` (kelvin),
/// in W·sr⁻¹·m⁻³. Zero for `t ≤ 0` or a non-positive wavelength.
pub fn planck(lambda: f64, t: f64) -> f64 {
    if !(t > 0.0 && lambda > 0.0) {
        return 0.0;
    }
    let x = H * C / (lambda * K_B * t);
    // exp_m1 keeps the Rayleigh–Jeans end (x ≪ 1) accurate; beyond x ≈ 700 the exponential
    // overflows and the radiance is 0 to every digit anyway.
    if x > 700.0 {
        return 0.0;
    }
    2.0 * H * C * C / lambda.powi(5) / x.exp_m1()
}

/// The CIE 1931 2° standard observer at 5 nm from 360 to 830 nm, `[x̄, ȳ, z̄]` per row (CIE
/// 015:2004, table T.4, as distributed by the CVRL database).
const CIE_1931_5NM: [[f64; 3]; 95] = [
    [0.000129900000, 0.000003917000, 0.000606100000], // 360 nm
    [0.000232100000, 0.000006965000, 0.001086000000], // 365 nm
    [0.000414900000, 0.000012390000, 0.001946000000], // 370 nm
    [0.000741600000, 0.000022020000, 0.003486000000], // 375 nm
    [0.001368000000, 0.000039000000, 0.006450001000], // 380 nm
    [0.002236000000, 0.000064000000, 0.010549990000], // 385 nm
    [0.004243000000, 0.000120000000, 0.020050010000], // 390 nm
    [0.007650000000, 0.000217000000, 0.036210000000], // 395 nm
    [0.014310000000, 0.000396000000, 0.067850010000], // 400 nm
    [0.023190000000, 0.000640000000, 0.110200000000], // 405 nm
    [0.043510000000, 0.001210000000, 0.207400000000], // 410 nm
    [0.077630000000, 0.002180000000, 0.371300000000], // 415 nm
    [0.134380000000, 0.004000000000, 0.645600000000], // 420 nm
    [0.214770000000, 0.007300000000, 1.039050100000], // 425 nm
    [0.283900000000, 0.011600000000, 1.385600000000], // 430 nm
    [0.328500000000, 0.016840000000, 1.622960000000], // 435 nm
    [0.348280000000, 0.023000000000, 1.747060000000], // 440 nm
    [0.348060000000, 0.029800000000, 1.782600000000], // 445 nm
    [0.336200000000, 0.038000000000, 1.772110000000], // 450 nm
    [0.318700000000, 0.048000000000, 1.744100000000], // 455 nm
    [0.290800000000, 0.060000000000, 1.669200000000], // 460 nm
    [0.251100000000, 0.073900000000, 1.528100000000], // 465 nm
    [0.195360000000, 0.090980000000, 1.287640000000], // 470 nm
    [0.142100000000, 0.112600000000, 1.041900000000], // 475 nm
    [0.095640000000, 0.139020000000, 0.812950100000], // 480 nm
    [0.057950010000, 0.169300000000, 0.616200000000], // 485 nm
    [0.032010000000, 0.208020000000, 0.465180000000], // 490 nm
    [0.014700000000, 0.258600000000, 0.353300000000], // 495 nm
    [0.004900000000, 0.323000000000, 0.272000000000], // 500 nm
    [0.002400000000, 0.407300000000, 0.212300000000], // 505 nm
    [0.009300000000, 0.503000000000, 0.158200000000], // 510 nm
    [0.029100000000, 0.608200000000, 0.111700000000], // 515 nm
    [0.063270000000, 0.710000000000, 0.078249990000], // 520 nm
    [0.109600000000, 0.793200000000, 0.057250010000], // 525 nm
    [0.165500000000, 0.862000000000, 0.042160000000], // 530 nm
    [0.225749900000, 0.914850100000, 0.029840000000], // 535 nm
    [0.290400000000, 0.954000000000, 0.020300000000], // 540 nm
    [0.359700000000, 0.980300000000, 0.013400000000], // 545 nm
    [0.433449900000, 0.994950100000, 0.008749999000], // 550 nm
    [0.512050100000, 1.000000000000, 0.005749999000], // 555 nm
    [0.594500000000, 0.995000000000, 0.003900000000], // 560 nm
    [0.678400000000, 0.978600000000, 0.002749999000], // 565 nm
    [0.762100000000, 0.952000000000, 0.002100000000], // 570 nm
    [0.842500000000, 0.915400000000, 0.001800000000], // 575 nm
    [0.916300000000, 0.870000000000, 0.001650001000], // 580 nm
    [0.978600000000, 0.816300000000, 0.001400000000], // 585 nm
    [1.026300000000, 0.757000000000, 0.001100000000], // 590 nm
    [1.056700000000, 0.694900000000, 0.001000000000], // 595 nm
    [1.062200000000, 0.631000000000, 0.000800000000], // 600 nm
    [1.045600000000, 0.566800000000, 0.000600000000], // 605 nm
    [1.002600000000, 0.503000000000, 0.000340000000], // 610 nm
    [0.938400000000, 0.441200000000, 0.000240000000], // 615 nm
    [0.854449900000, 0.381000000000, 0.000190000000], // 620 nm
    [0.751400000000, 0.321000000000, 0.000100000000], // 625 nm
    [0.642400000000, 0.265000000000, 0.000049999990], // 630 nm
    [0.541900000000, 0.217000000000, 0.000030000000], // 635 nm
    [0.447900000000, 0.175000000000, 0.000020000000], // 640 nm
    [0.360800000000, 0.138200000000, 0.000010000000], // 645 nm
    [0.283500000000, 0.107000000000, 0.000000000000], // 650 nm
    [0.218700000000, 0.081600000000, 0.000000000000], // 655 nm
    [0.164900000000, 0.061000000000, 0.000000000000], // 660 nm
    [0.121200000000, 0.044580000000, 0.000000000000], // 665 nm
    [0.087400000000, 0.032000000000, 0.000000000000], // 670 nm
    [0.063600000000, 0.023200000000, 0.000000000000], // 675 nm
    [0.046770000000, 0.017000000000, 0.000000000000], // 680 nm
    [0.032900000000, 0.011920000000, 0.000000000000], // 685 nm
    [0.022700000000, 0.008210000000, 0.000000000000], // 690 nm
    [0.015840000000, 0.005723000000, 0.000000000000], // 695 nm
    [0.011359160000, 0.004102000000, 0.000000000000], // 700 nm
    [0.008110916000, 0.002929000000, 0.000000000000], // 705 nm
    [0.005790346000, 0.002091000000, 0.000000000000], // 710 nm
    [0.004109457000, 0.001484000000, 0.000000000000], // 715 nm
    [0.002899327000, 0.001047000000, 0.000000000000], // 720 nm
    [0.002049190000, 0.000740000000, 0.000000000000], // 725 nm
    [0.001439971000, 0.000520000000, 0.000000000000], // 730 nm
    [0.000999949300, 0.000361100000, 0.000000000000], // 735 nm
    [0.000690078600, 0.000249200000, 0.000000000000], // 740 nm
    [0.000476021300, 0.000171900000, 0.000000000000], // 745 nm
    [0.000332301100, 0.000120000000, 0.000000000000], // 750 nm
    [0.000234826100, 0.000084800000, 0.000000000000], // 755 nm
    [0.000166150500, 0.000060000000, 0.000000000000], // 760 nm
    [0.000117413000, 0.000042400000, 0.000000000000], // 765 nm
    [0.000083075270, 0.000030000000, 0.000000000000], // 770 nm
    [0.000058706520, 0.000021200000, 0.000000000000], // 775 nm
    [0.000041509940, 0.000014990000, 0.000000000000], // 780 nm
    [0.000029353260, 0.000010600000, 0.000000000000], // 785 nm
    [0.000020673830, 0.000007465700, 0.000000000000], // 790 nm
    [0.000014559770, 0.000005257800, 0.000000000000], // 795 nm
    [0.000010253980, 0.000003702900, 0.000000000000], // 800 nm
    [0.000007221456, 0.000002607800, 0.000000000000], // 805 nm
    [0.000005085868, 0.000001836600, 0.000000000000], // 810 nm
    [0.000003581652, 0.000001293400, 0.000000000000], // 815 nm
    [0.000002522525, 0.000000910930, 0.000000000000], // 820 nm
    [0.000001776509, 0.000000641530, 0.000000000000], // 825 nm
    [0.000001251141, 0.000000451810, 0.000000000000], // 830 nm
];

/// The CIE 1931 2° colour-matching functions `[x̄, ȳ, z̄]` at `lambda_nm` (nanometres):
/// the 5 nm table linearly interpolated, 0 outside 360–830 nm.
pub fn cie_1931(lambda_nm: f64) -> [f64; 3] {
    if !(LAMBDA_MIN_NM..=LAMBDA_MAX_NM).contains(&lambda_nm) {
        return [0.0; 3];
    }
    let u = (lambda_nm - LAMBDA_MIN_NM) / 5.0;
    let i = (u.floor() as usize).min(CIE_1931_5NM.len() - 2);
    let f = u - i as f64;
    let (a, b) = (CIE_1931_5NM[i], CIE_1931_5NM[i + 1]);
    [0, 1, 2].map(|c| a[c] + f * (b[c] - a[c]))
}

/// CIE XYZ of a blackbody at `t` kelvin; `Y` is its luminance in cd/m². Zero for `t ≤ 0` or
/// a non-finite `t`.
pub fn xyz(t: f64) -> [f64; 3] {
    if !(t > 0.0 && t.is_finite()) {
        return [0.0; 3];
    }
    let n = (LAMBDA_MAX_NM - LAMBDA_MIN_NM) as usize; // 1 nm steps
    let mut sum = [0.0; 3];
    for i in 0..=n {
        let l = LAMBDA_MIN_NM + i as f64;
        let w = if i == 0 || i == n { 0.5 } else { 1.0 };
        let b = planck(l * 1e-9, t) * w;
        let cmf = cie_1931(l);
        for c in 0..3 {
            sum[c] += b * cmf[c];
        }
    }
    // dλ = 1 nm = 1e-9 m.
    sum.map(|s| KM * s * 1e-9)
}

/// Chromaticity `(x, y)` of a blackbody at `t` kelvin; `None` for `t ≤ 0` (no light).
pub fn chromaticity(t: f64) -> Option<(f64, f64)> {
    let [x, y, z] = xyz(t);
    let s = x + y + z;
    (s > 0.0).then(|| (x / s, y / s))
}

/// Linear sRGB (D65 white) from CIE XYZ (IEC 61966-2-1).
pub fn xyz_to_linear_srgb([x, y, z]: [f64; 3]) -> [f64; 3] {
    [
        3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z,
        -0.969_266_0 * x + 1.876_010_8 * y + 0.041_556_0 * z,
        0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z,
    ]
}

/// The linear sRGB colour of a blackbody at `t` kelvin, in units of [`LUMINANCE_UNIT`]
/// cd/m². Below about 1900 K the Planckian locus leaves the sRGB gamut (blue goes negative):
/// negative components are clipped to 0, because an emission must be ≥ 0; the hue there is
/// the gamut's nearest red-orange. Zero for `t ≤ 0` or a non-finite `t`.
pub fn rgb(t: f64) -> [f64; 3] {
    xyz_to_linear_srgb(xyz(t)).map(|c| (c / LUMINANCE_UNIT).max(0.0))
}

/// [`rgb`] tabulated from 0 to a maximum temperature: at 1 K steps up to
/// [`RgbTable::LINEAR_UP_TO`] kelvin, then at steps of 0.1 % of the temperature (10 K at
/// 10⁴ K, 100 K at 10⁵ K). A medium's cells take many distinct temperatures, and a
/// 471-wavelength integral per cell would cost more than the table; 1 K steps all the way to
/// the 10⁵ K a scene may ask for cost 4.7·10⁷ Planck evaluations (seconds, found by the scene
/// fuzzer), where the colour changes by far less than 0.1 % per 0.1 %. It holds XYZ,
/// interpolated geometrically between entries (linearly in the logarithm, as each grows like
/// `exp(−c₂/λT)`; linear interpolation was off by 1.2e-4 at 800 K), then converted and
/// clipped like [`rgb`]: interpolating the clipped RGB itself fails where blue crosses 0 near
/// 1900 K. The relative error is below 1e-4 from 500 K up (tested), where any visible fire
/// lies.
#[derive(Clone, Debug)]
pub struct RgbTable {
    xyz: Vec<[f64; 3]>,
}

impl RgbTable {
    /// The table's entries are 1 K apart up to here, then 0.1 % of the temperature apart.
    pub const LINEAR_UP_TO: f64 = 1.0e4;
    /// The step in `ln T` above [`Self::LINEAR_UP_TO`].
    const LOG_STEP: f64 = 1.0e-3;

    /// The temperature of entry `i`.
    fn temperature(i: usize) -> f64 {
        let k = Self::LINEAR_UP_TO as usize;
        if i <= k {
            i as f64
        } else {
            Self::LINEAR_UP_TO * ((i - k) as f64 * Self::LOG_STEP).exp()
        }
    }

    /// Entry index and fraction of `t > 0`: `t` lies between entries `i` and `i + 1`.
    fn position(t: f64) -> (usize, f64) {
        let x = if t <= Self::LINEAR_UP_TO {
            t
        } else {
            Self::LINEAR_UP_TO + (t / Self::LINEAR_UP_TO).ln() / Self::LOG_STEP
        };
        let i = x.floor();
        (i as usize, x - i)
    }

    /// A table covering `[0, t_max]` kelvin (`t_max` is clamped to `[0, 1e5]`).
    pub fn new(t_max: f64) -> Self {
        let t_max = if t_max.is_finite() {
            t_max.clamp(0.0, 1e5)
        } else {
            0.0
        };
        let (i, f) = Self::position(t_max.max(f64::MIN_POSITIVE));
        let n = i + usize::from(f > 0.0) + 1;
        let xyz = (0..=n).map(|i| xyz(Self::temperature(i))).collect();
        RgbTable { xyz }
    }

    /// The colour at `t` kelvin: 0 for `t ≤ 0` or non-finite `t`, the last entry beyond the
    /// table's end.
    pub fn get(&self, t: f64) -> [f64; 3] {
        if !(t > 0.0 && t.is_finite()) {
            return [0.0; 3];
        }
        let last = self.xyz.len() - 1;
        let (i, f) = Self::position(t);
        let i = i.min(last);
        let xyz = if i == last {
            self.xyz[last]
        } else {
            let (a, b) = (self.xyz[i], self.xyz[i + 1]);
            [0, 1, 2].map(|c| {
                if a[c] > 0.0 && b[c] > 0.0 {
                    a[c] * (b[c] / a[c]).powf(f)
                } else {
                    // Below ~50 K X, Y or Z underflows to 0: no light either way.
                    a[c] + f * (b[c] - a[c])
                }
            })
        };
        xyz_to_linear_srgb(xyz).map(|c| (c / LUMINANCE_UNIT).max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Planckian-locus chromaticities (CIE 1931 2°), from the CIE illuminant A definition
    /// (2856 K) and published Planckian-locus tables.
    #[test]
    fn chromaticity_matches_planckian_locus() {
        let table = [
            (1500.0, 0.5857, 0.3931),
            (2856.0, 0.4476, 0.4074),
            (4000.0, 0.3805, 0.3768),
            (6500.0, 0.3135, 0.3237),
        ];
        for (t, x0, y0) in table {
            let (x, y) = chromaticity(t).unwrap();
            assert!(
                (x - x0).abs() < 0.003 && (y - y0).abs() < 0.003,
                "{t} K: ({x:.4}, {y:.4}) vs ({x0}, {y0})"
            );
        }
    }

    /// Luminance ratio between two temperatures against an independent fine integration
    /// (0.05 nm, Simpson's rule) of Planck × ȳ.
    #[test]
    fn luminance_ratio_matches_fine_integration() {
        let fine_y = |t: f64| {
            let n = 9400; // even, 0.05 nm steps over 360–830 nm
            let h = (LAMBDA_MAX_NM - LAMBDA_MIN_NM) / n as f64;
            let mut s = 0.0;
            for i in 0..=n {
                let l = LAMBDA_MIN_NM + i as f64 * h;
                let w = if i == 0 || i == n {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                s += w * planck(l * 1e-9, t) * cie_1931(l)[1];
            }
            KM * s * h * 1e-9 / 3.0
        };
        for (t1, t2) in [(1000.0, 1800.0), (1500.0, 6500.0)] {
            let ratio = xyz(t2)[1] / xyz(t1)[1];
            let want = fine_y(t2) / fine_y(t1);
            assert!(
                (ratio / want - 1.0).abs() < 1e-4,
                "{t1}→{t2} K: {ratio} vs {want}"
            );
        }
        // And the absolute scale: Y at 2856 K against the fine integral, to 0.01 %.
        let y = xyz(2856.0)[1];
        let want = fine_y(2856.0);
        assert!((y / want - 1.0).abs() < 1e-4, "{y} vs {want}");
    }

    /// Wien's displacement law: B(λ, T) peaks at b/T with b = 2.897 771 955e-3 m·K.
    #[test]
    fn planck_peak_follows_wien() {
        for t in [800.0, 1500.0, 5772.0, 10000.0] {
            let expected = 2.897_771_955e-3 / t;
            // Golden-section search for the maximum on [0.3, 3] × expected.
            let (mut a, mut b) = (0.3 * expected, 3.0 * expected);
            let g = (5f64.sqrt() - 1.0) / 2.0;
            for _ in 0..200 {
                let c = b - g * (b - a);
                let d = a + g * (b - a);
                if planck(c, t) > planck(d, t) {
                    b = d;
                } else {
                    a = c;
                }
            }
            let peak = 0.5 * (a + b);
            assert!(
                (peak / expected - 1.0).abs() < 0.005,
                "{t} K: peak at {peak} m, Wien says {expected} m"
            );
        }
    }

    /// Stefan–Boltzmann: π ∫ B dλ over all wavelengths is σT⁴; checks Planck's constants.
    #[test]
    fn planck_integrates_to_stefan_boltzmann() {
        let t = 3000.0;
        let (lo, hi, n) = (50e-9, 200e-6, 400_000);
        let h = (hi - lo) / n as f64;
        let s: f64 = (0..n)
            .map(|i| planck(lo + (i as f64 + 0.5) * h, t))
            .sum::<f64>()
            * h;
        let sigma = 5.670_374_419e-8;
        let exitance = std::f64::consts::PI * s;
        assert!(
            (exitance / (sigma * t.powi(4)) - 1.0).abs() < 1e-3,
            "{exitance} vs {}",
            sigma * t.powi(4)
        );
    }

    #[test]
    fn rgb_is_warm_for_fire_and_neutral_near_6500k() {
        let [r, g, b] = rgb(1500.0);
        assert!(r > g && g > b && b >= 0.0, "{r} {g} {b}");
        // D65 is close to (not on) the Planckian locus: 6504 K is nearly white.
        let [r, g, b] = rgb(6504.0);
        assert!(
            (r / g - 1.0).abs() < 0.1 && (b / g - 1.0).abs() < 0.1,
            "{r} {g} {b}"
        );
        // Hotter is brighter.
        assert!(rgb(1800.0)[1] > rgb(800.0)[1]);
        assert_eq!(rgb(0.0), [0.0; 3]);
        assert_eq!(rgb(-5.0), [0.0; 3]);
        assert_eq!(rgb(f64::NAN), [0.0; 3]);
    }

    #[test]
    fn rgb_table_matches_direct_evaluation() {
        let table = RgbTable::new(3000.0);
        for t in [500.5, 799.3, 1234.56, 1901.7, 2999.9, 3000.0] {
            let a = table.get(t);
            let b = rgb(t);
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-4 * b[c].max(1e-3 * b[1]),
                    "{t} K channel {c}: {} vs {}",
                    a[c],
                    b[c]
                );
            }
        }
        assert_eq!(table.get(0.0), [0.0; 3]);
        assert_eq!(table.get(-1.0), [0.0; 3]);
        assert_eq!(table.get(f64::INFINITY), [0.0; 3]);
    }

    /// Up to the 10⁵ K a scene may ask for, the table stays small (1 K steps all the way
    /// took seconds to build) and as accurate as below 10⁴ K.
    #[test]
    fn rgb_table_to_the_highest_temperature_is_small_and_accurate() {
        let table = RgbTable::new(1e5);
        assert!(table.xyz.len() < 12_400, "{} entries", table.xyz.len());
        for t in [
            600.25, 9999.5, 10_000.0, 10_004.9, 12_345.6, 54_321.0, 99_999.9, 1e5,
        ] {
            let a = table.get(t);
            let b = rgb(t);
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-4 * b[c].max(1e-3 * b[1]),
                    "{t} K channel {c}: {} vs {}",
                    a[c],
                    b[c]
                );
            }
        }
        // Below the switch, the entries are where they always were (1 K apart).
        let small = RgbTable::new(3000.0);
        assert_eq!(small.xyz.len(), 3002);
        assert_eq!(small.get(1234.56), table.get(1234.56));
    }
}
