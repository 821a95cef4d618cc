//! Comparing a noisy render with a noisy reference image, taking both noises out: the one
//! image comparison of volrad (tests, examples, `volrad validate`, `volrad compare`,
//! docs/validation.md).
//!
//! [`compare`] works on [`NoisyImage`] channels; [`compare_images`] adapts `gather::Image`s to
//! it (channel 0 with its optional standard-error image, blocks that do not fill the image
//! dropped).

use gather::{Image, ImageChannel};

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
        let n = (factor as f64).powi(2);
        Some(NoisyImage {
            mean: block_mean(&self.mean, factor)?,
            std_error: block_map(&self.std_error, factor, |v| v * v, |sum| sum.sqrt() / n)?,
        })
    }
}

/// Means of `factor × factor` pixel blocks (sums in f64). `None` when the size is not a
/// multiple of `factor` or `factor` is 0.
pub fn block_mean(image: &ImageChannel, factor: u32) -> Option<ImageChannel> {
    let n = (factor as f64).powi(2);
    block_map(image, factor, |v| v, |sum| sum / n)
}

/// `finish(Σ term(v))` over each `factor × factor` block, in f64.
fn block_map(
    image: &ImageChannel,
    factor: u32,
    term: impl Fn(f64) -> f64,
    finish: impl Fn(f64) -> f64,
) -> Option<ImageChannel> {
    let (w, h) = (image.width, image.height);
    if factor == 0 || w % factor != 0 || h % factor != 0 {
        return None;
    }
    let (bw, bh) = (w / factor, h / factor);
    let mut pixels = Vec::with_capacity((bw * bh) as usize);
    for by in 0..bh {
        for bx in 0..bw {
            let mut sum = 0.0f64;
            for y in by * factor..(by + 1) * factor {
                for x in bx * factor..(bx + 1) * factor {
                    sum += term(image.get(x, y) as f64);
                }
            }
            pixels.push(finish(sum) as f32);
        }
    }
    Some(ImageChannel {
        width: bw,
        height: bh,
        pixels,
    })
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

/// Compares `x` with the reference `r` (same size). `None` when sizes differ (means or
/// standard errors) or no pixel is above the threshold.
pub fn compare(x: &NoisyImage, r: &NoisyImage, threshold: f64) -> Option<Comparison> {
    let size = |c: &ImageChannel| (c.width, c.height, c.pixels.len());
    let reference_size = size(&r.mean);
    if [&x.mean, &x.std_error, &r.std_error]
        .iter()
        .any(|c| size(c) != reference_size)
    {
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

/// Compares channel 0 of `image` with channel 0 of `reference` over the pixels where the
/// reference exceeds `threshold` times its maximum, taking the stated standard errors out
/// (`s² = s_image² + s_reference²`; an image without one counts its own noise as error).
/// With `block > 1` both images (and the error variances, divided by block²) are first
/// averaged over `block × block` pixel blocks, edges that fill no block dropped. Errs, saying
/// why, when sizes differ or no pixel is above the threshold.
pub fn compare_images(
    image: &Image,
    image_stderr: Option<&Image>,
    reference: &Image,
    reference_stderr: Option<&Image>,
    threshold: f64,
    block: u32,
) -> Result<Comparison, String> {
    let size = |i: &Image| (i.width, i.height);
    if size(image) != size(reference) {
        return Err(format!(
            "sizes differ: image is {}×{}, reference {}×{}",
            image.width, image.height, reference.width, reference.height
        ));
    }
    if [image_stderr, reference_stderr]
        .into_iter()
        .flatten()
        .any(|s| size(s) != size(reference))
    {
        return Err("standard-error image size differs from the reference".into());
    }
    let block = block.max(1);
    let noisy = |mean: &Image, stderr: Option<&Image>| {
        let mean = channel0_cropped(mean, block);
        let std_error = match stderr {
            Some(s) => channel0_cropped(s, block),
            None => ImageChannel {
                pixels: vec![0.0; mean.pixels.len()],
                ..mean.clone()
            },
        };
        NoisyImage { mean, std_error }.block_average(block)
    };
    let not_above = || "the reference has no pixels above the threshold".to_string();
    // Cropped to whole blocks, so block averages exist.
    let (x, r) = noisy(image, image_stderr)
        .zip(noisy(reference, reference_stderr))
        .ok_or_else(not_above)?;
    compare(&x, &r, threshold).ok_or_else(not_above)
}

/// The largest `|x − r|` between channel 0 of `image` (`x`) and of `reference` (`r`) over the
/// pixels where the reference exceeds `threshold` times its maximum (those [`compare_images`]
/// compares with `block` 1), as a share of that maximum. Errs, saying why, when sizes differ
/// or no pixel is above the threshold.
pub fn largest_difference(image: &Image, reference: &Image, threshold: f64) -> Result<f64, String> {
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(format!(
            "sizes differ: image is {}×{}, reference {}×{}",
            image.width, image.height, reference.width, reference.height
        ));
    }
    let (x, r) = (channel0_cropped(image, 1), channel0_cropped(reference, 1));
    let max = r.pixels.iter().copied().fold(0.0f32, f32::max) as f64;
    let largest = r
        .pixels
        .iter()
        .zip(&x.pixels)
        .map(|(&rv, &xv)| (rv as f64, xv as f64))
        .filter(|&(rv, _)| rv > threshold * max)
        .map(|(rv, xv)| (xv - rv).abs())
        .reduce(f64::max);
    match largest {
        Some(d) if max > 0.0 => Ok(d / max),
        _ => Err("the reference has no pixels above the threshold".into()),
    }
}

/// Means of `factor × factor` blocks of channel 0 of `image` (edges that do not fill a block
/// dropped), as a one-channel image; `factor` 1 is channel 0 itself.
pub fn downscale_channel0(image: &Image, factor: u32) -> Result<Image, String> {
    let factor = factor.max(1);
    let blocks = block_mean(&channel0_cropped(image, factor), factor)
        .ok_or("block size does not divide the cropped image")?;
    Image::new(blocks.width, blocks.height, 1, blocks.pixels).map_err(|_| {
        format!(
            "a {}×{} image has no whole {factor}×{factor} block",
            image.width, image.height
        )
    })
}

/// Channel 0 of `image`, cut to whole multiples of `block` in each direction.
fn channel0_cropped(image: &Image, block: u32) -> ImageChannel {
    let (width, height) = (image.width / block * block, image.height / block * block);
    let mut pixels = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        pixels.extend((0..width).map(|x| image.get(x, y, 0)));
    }
    ImageChannel {
        width,
        height,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(width: u32, height: u32, pixels: Vec<f32>) -> ImageChannel {
        ImageChannel {
            width,
            height,
            pixels,
        }
    }

    #[test]
    fn block_average_means_values_and_adds_errors_in_quadrature() {
        let noisy = NoisyImage {
            mean: channel(4, 2, vec![0.0, 2.0, 4.0, 4.0, 2.0, 0.0, 4.0, 4.0]),
            std_error: channel(4, 2, vec![0.4, 0.4, 0.4, 0.4, 0.4, 0.4, 0.0, 0.0]),
        };
        let b = noisy.block_average(2).unwrap();
        assert_eq!((b.mean.width, b.mean.height), (2, 1));
        assert_eq!(b.mean.pixels, vec![1.0, 4.0]);
        // Four independent errors of 0.4: sqrt(4 · 0.16) / 4 = 0.2; two of 0.4: sqrt(0.32) / 4.
        assert!((b.std_error.pixels[0] - 0.2).abs() < 1e-7);
        assert!((b.std_error.pixels[1] - 0.32f32.sqrt() / 4.0).abs() < 1e-7);
        assert!(noisy.block_average(3).is_none() && noisy.block_average(0).is_none());
        assert_eq!(block_mean(&noisy.mean, 2), Some(b.mean));
    }

    #[test]
    fn both_noises_are_taken_out_and_mismatched_errors_refused() {
        let r = NoisyImage {
            mean: channel(2, 2, vec![1.0; 4]),
            std_error: channel(2, 2, vec![0.06; 4]),
        };
        let x = NoisyImage {
            mean: channel(2, 2, vec![1.1, 0.9, 1.1, 0.9]),
            std_error: channel(2, 2, vec![0.08; 4]),
        };
        // |x − r| = 0.1 = sqrt(0.06² + 0.08²): the difference is exactly the two noises.
        let c = compare(&x, &r, 0.01).unwrap();
        assert!(c.relative_rms_error < 1e-3, "{c:?}");
        assert!((c.relative_rms_raw - 0.1).abs() < 1e-6);
        assert!((c.chi2_per_pixel - 1.0).abs() < 1e-4);
        // A standard-error image of another size is refused, not indexed out of bounds.
        let short = NoisyImage {
            std_error: channel(1, 2, vec![0.08; 2]),
            ..x.clone()
        };
        assert!(compare(&short, &r, 0.01).is_none());
    }

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
        let c = compare_images(&r, None, &r, None, 0.01, 1).unwrap();
        assert_eq!(c.relative_rms_error, 0.0);
        let x = img(8, 8, |x, y| 1.1 * (x + y) as f32);
        let c = compare_images(&x, None, &r, None, 0.01, 1).unwrap();
        assert!((c.relative_rms_error - 0.1).abs() < 1e-6);
        assert!((c.relative_mean_difference - 0.1).abs() < 1e-6);
    }

    #[test]
    fn the_largest_difference_is_a_share_of_the_peak_over_the_pixels_above_the_threshold() {
        let r = img(4, 1, |x, _| [0.001, 1.0, 2.0, 4.0][x as usize]);
        // 0.5 off in the dim pixel (below 1 % of the peak), 0.2 in the brightest.
        let x = img(4, 1, |x, _| [0.501, 1.1, 2.0, 4.2][x as usize]);
        let largest = largest_difference(&x, &r, 0.01).unwrap();
        assert!((largest - 0.2 / 4.0).abs() < 1e-6, "{largest}");
        assert_eq!(largest_difference(&r, &r, 0.01), Ok(0.0));
        assert!(largest_difference(&img(2, 2, |_, _| 1.0), &r, 0.01).is_err());
        assert!(largest_difference(&r, &img(4, 1, |_, _| 0.0), 0.01).is_err());
    }

    #[test]
    fn reference_noise_is_taken_out_and_blocks_average() {
        // Error exactly equal to the stated noise: the noise-corrected error is zero.
        let r = img(4, 4, |_, _| 1.0);
        let x = img(4, 4, |x, _| if x % 2 == 0 { 1.1 } else { 0.9 });
        let s = img(4, 4, |_, _| 0.1);
        let c = compare_images(&x, None, &r, Some(&s), 0.01, 1).unwrap();
        assert!(c.relative_rms_error < 1e-3 && (c.relative_rms_raw - 0.1).abs() < 1e-6);
        // Blocks of 2 average the alternating error away.
        let c = compare_images(&x, None, &r, None, 0.01, 2).unwrap();
        assert!(c.relative_rms_error < 1e-6);
        // Blocks of 3 on 4×4: the last row and column fill no block and are dropped, leaving
        // one block whose mean (two 1.1 columns, one 0.9) is 1 + 0.1/3.
        let c = compare_images(&x, None, &r, None, 0.01, 3).unwrap();
        assert_eq!(c.pixels, 1);
        assert!(
            (c.relative_mean_difference - 0.1 / 3.0).abs() < 1e-6,
            "{c:?}"
        );
    }

    #[test]
    fn both_images_noise_is_taken_out_only_when_stated() {
        let r = img(4, 4, |_, _| 1.0);
        let x = img(4, 4, |x, _| if x % 2 == 0 { 1.1 } else { 0.9 });
        // The error is sqrt(0.06² + 0.08²) = 0.1, shared between the two images.
        let (sr, sx) = (img(4, 4, |_, _| 0.06), img(4, 4, |_, _| 0.08));
        let both = compare_images(&x, Some(&sx), &r, Some(&sr), 0.01, 1).unwrap();
        assert!(both.relative_rms_error < 1e-3, "{both:?}");
        let reference_only = compare_images(&x, None, &r, Some(&sr), 0.01, 1).unwrap();
        assert!((reference_only.relative_rms_error - 0.08).abs() < 1e-6);
        let small = img(2, 4, |_, _| 0.08);
        assert!(compare_images(&x, Some(&small), &r, Some(&sr), 0.01, 1).is_err());
        assert!(compare_images(&small, None, &r, None, 0.01, 1).is_err());
    }

    #[test]
    fn downscale_averages_channel_0_and_drops_partial_blocks() {
        let img = Image::new(
            5,
            2,
            1,
            vec![0.0, 2.0, 4.0, 4.0, 9.0, 2.0, 0.0, 4.0, 4.0, 9.0],
        )
        .unwrap();
        let d = downscale_channel0(&img, 2).unwrap();
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.pixels, vec![1.0, 4.0]);
        let rgb = Image::new(2, 1, 3, vec![1.0, 5.0, 5.0, 3.0, 5.0, 5.0]).unwrap();
        let d = downscale_channel0(&rgb, 1).unwrap();
        assert_eq!((d.channels, d.pixels.clone()), (1, vec![1.0, 3.0]));
        assert!(
            downscale_channel0(&img, 3).is_err(),
            "2 rows fill no 3×3 block"
        );
    }
}
