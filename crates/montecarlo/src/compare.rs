//! Comparing a noisy render with a noisy reference image, taking both noises out.

use gather::ImageChannel;

/// A channel with the standard error of each pixel, e.g. a Monte Carlo render or a
/// reference image with its stderr image.
#[derive(Clone, Debug, PartialEq)]
pub struct NoisyImage {
    pub mean: ImageChannel,
    pub std_error: ImageChannel,
}

impl NoisyImage {
    /// Means of `factor × factor` pixel blocks (the image of the same camera with pixels
    /// `factor` times larger, since a pixel is the mean over its area), with the block
    /// errors `sqrt(Σ s²) / factor²` of independent pixels. `None` when the size is not a
    /// multiple of `factor` or `factor` is 0.
    pub fn block_average(&self, factor: u32) -> Option<NoisyImage> {
        let (w, h) = (self.mean.width, self.mean.height);
        if factor == 0 || w % factor != 0 || h % factor != 0 {
            return None;
        }
        let (bw, bh) = (w / factor, h / factor);
        let n = (factor * factor) as f64;
        let mut mean = Vec::with_capacity((bw * bh) as usize);
        let mut se = Vec::with_capacity((bw * bh) as usize);
        for by in 0..bh {
            for bx in 0..bw {
                let (mut m, mut v) = (0.0f64, 0.0f64);
                for y in by * factor..(by + 1) * factor {
                    for x in bx * factor..(bx + 1) * factor {
                        m += self.mean.get(x, y) as f64;
                        v += (self.std_error.get(x, y) as f64).powi(2);
                    }
                }
                mean.push((m / n) as f32);
                se.push((v.sqrt() / n) as f32);
            }
        }
        let image = |pixels| ImageChannel {
            width: bw,
            height: bh,
            pixels,
        };
        Some(NoisyImage {
            mean: image(mean),
            std_error: image(se),
        })
    }
}

/// Agreement of a render `x` with a reference `r`, over the pixels where the reference is
/// above `threshold × max(r)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Comparison {
    /// Pixels compared.
    pub pixels: usize,
    /// Relative RMS error with both noises taken out:
    /// `err² = Σ[(x−r)² − s_r² − s_x²] / Σ r²` (0 when that is negative).
    pub relative_rms_error: f64,
    /// Relative RMS difference as measured, noise included: `sqrt(Σ(x−r)² / Σ r²)`.
    pub relative_rms_raw: f64,
    /// Relative RMS of the two noises together: `sqrt(Σ(s_r² + s_x²) / Σ r²)`.
    pub relative_rms_noise: f64,
    /// `(mean x − mean r) / mean r` over the compared pixels.
    pub relative_mean_difference: f64,
    /// Standard error of that mean difference (both noises), relative to `mean r`.
    pub relative_mean_std_error: f64,
    /// `Σ (x−r)² / (s_x² + s_r²) / pixels`: about 1 when the difference is pure noise.
    pub chi2_per_pixel: f64,
}

/// Compares `x` with the reference `r` (same size). `None` when sizes differ or no pixel
/// is above the threshold.
pub fn compare(x: &NoisyImage, r: &NoisyImage, threshold: f64) -> Option<Comparison> {
    if x.mean.pixels.len() != r.mean.pixels.len() || x.mean.width != r.mean.width {
        return None;
    }
    let max = r.mean.pixels.iter().copied().fold(0.0f32, f32::max) as f64;
    let (mut n, mut d2, mut noise, mut r2, mut sx, mut sr, mut chi2) =
        (0usize, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..r.mean.pixels.len() {
        let rv = r.mean.pixels[i] as f64;
        if rv <= threshold * max {
            continue;
        }
        let xv = x.mean.pixels[i] as f64;
        let var = (x.std_error.pixels[i] as f64).powi(2) + (r.std_error.pixels[i] as f64).powi(2);
        n += 1;
        d2 += (xv - rv).powi(2);
        noise += var;
        r2 += rv * rv;
        sx += xv;
        sr += rv;
        if var > 0.0 {
            chi2 += (xv - rv).powi(2) / var;
        }
    }
    if n == 0 || r2 == 0.0 {
        return None;
    }
    Some(Comparison {
        pixels: n,
        relative_rms_error: ((d2 - noise).max(0.0) / r2).sqrt(),
        relative_rms_raw: (d2 / r2).sqrt(),
        relative_rms_noise: (noise / r2).sqrt(),
        relative_mean_difference: (sx - sr) / sr,
        relative_mean_std_error: noise.sqrt() / sr,
        chi2_per_pixel: chi2 / n as f64,
    })
}
