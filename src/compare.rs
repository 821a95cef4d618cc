//! Image comparison against noisy references (Mitsuba path-traced images with their per-pixel
//! standard error), used by tests, `volrad validate` and docs/validation.md.

use gather::Image;

/// How an image compares with a reference over the pixels that matter.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Comparison {
    /// `sqrt(Σ (x−r)² / Σ r²)` over the mask, the reference's noise included.
    pub relative_rms_raw: f64,
    /// The same after taking the reference's own noise out of the squared error:
    /// `sqrt(max(0, Σ[(x−r)² − s²]) / Σ r²)`.
    pub relative_rms: f64,
    /// Relative difference of the image means over the mask.
    pub mean_ratio_error: f64,
    /// Pixels in the mask (reference above `threshold · max`).
    pub pixels: usize,
}

/// Compares channel 0 of `image` with `reference` and its per-pixel standard error `stderr`,
/// over the pixels where the reference exceeds `threshold` times its maximum. With `block > 1`
/// both images (and the error variance, divided by block²) are first averaged over
/// `block × block` pixel blocks.
pub fn compare(
    image: &Image,
    reference: &Image,
    stderr: Option<&Image>,
    threshold: f64,
    block: u32,
) -> Result<Comparison, String> {
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(format!(
            "image is {}×{}, reference {}×{}",
            image.width, image.height, reference.width, reference.height
        ));
    }
    if let Some(s) = stderr {
        if (s.width, s.height) != (reference.width, reference.height) {
            return Err("standard-error image size differs from the reference".into());
        }
    }
    let block = block.max(1);
    let (bw, bh) = (reference.width / block, reference.height / block);
    let mean_block = |img: &Image, bx: u32, by: u32, square: bool| {
        let mut s = 0.0;
        for y in by * block..(by + 1) * block {
            for x in bx * block..(bx + 1) * block {
                let v = img.get(x, y, 0) as f64;
                s += if square { v * v } else { v };
            }
        }
        s / (block * block) as f64
    };
    let mut refs = Vec::with_capacity((bw * bh) as usize);
    for by in 0..bh {
        for bx in 0..bw {
            let r = mean_block(reference, bx, by, false);
            let x = mean_block(image, bx, by, false);
            // Variance of a block mean of independent pixels: mean of s² / block².
            let var = stderr.map_or(0.0, |s| {
                mean_block(s, bx, by, true) / (block * block) as f64
            });
            refs.push((r, x, var));
        }
    }
    let max = refs.iter().map(|t| t.0).fold(0.0, f64::max);
    let (mut num, mut noise, mut den, mut sum_x, mut sum_r, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0);
    for &(r, x, var) in &refs {
        if r > threshold * max {
            num += (x - r).powi(2);
            noise += var;
            den += r * r;
            sum_x += x;
            sum_r += r;
            n += 1;
        }
    }
    if n == 0 || den == 0.0 {
        return Err("the reference has no pixels above the threshold".into());
    }
    Ok(Comparison {
        relative_rms_raw: (num / den).sqrt(),
        relative_rms: ((num - noise).max(0.0) / den).sqrt(),
        mean_ratio_error: sum_x / sum_r - 1.0,
        pixels: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> Image {
        let mut p = Vec::new();
        for y in 0..h {
            for x in 0..w {
                p.push(f(x, y));
            }
        }
        Image::new(w, h, 1, p).unwrap()
    }

    #[test]
    fn identical_images_have_zero_error_and_scaled_ones_the_scale() {
        let r = img(8, 8, |x, y| (x + y) as f32);
        let c = compare(&r, &r, None, 0.01, 1).unwrap();
        assert_eq!(c.relative_rms, 0.0);
        let x = img(8, 8, |x, y| 1.1 * (x + y) as f32);
        let c = compare(&x, &r, None, 0.01, 1).unwrap();
        assert!((c.relative_rms - 0.1).abs() < 1e-6);
        assert!((c.mean_ratio_error - 0.1).abs() < 1e-6);
    }

    #[test]
    fn reference_noise_is_taken_out() {
        // Error exactly equal to the stated noise: the noise-corrected error is zero.
        let r = img(4, 4, |_, _| 1.0);
        let x = img(4, 4, |x, _| if x % 2 == 0 { 1.1 } else { 0.9 });
        let s = img(4, 4, |_, _| 0.1);
        let c = compare(&x, &r, Some(&s), 0.01, 1).unwrap();
        assert!(c.relative_rms < 1e-3 && (c.relative_rms_raw - 0.1).abs() < 1e-6);
        // Blocks of 2 average the alternating error away.
        let c = compare(&x, &r, None, 0.01, 2).unwrap();
        assert!(c.relative_rms < 1e-6);
    }
}
