//! Image comparison against noisy references (Mitsuba path-traced images with their per-pixel
//! standard error), used by tests, `volrad validate` and docs/validation.md.
//!
//! The arithmetic is `montecarlo::compare`'s; this module adapts `gather::Image`s to it (channel
//! 0, blocks that do not fill the image dropped) and keeps the root crate's policy: a rendered
//! image's own noise counts as error unless the caller states it ([`compare_noisy`]).

use gather::{Image, ImageChannel};
use montecarlo::compare::{block_mean, NoisyImage};

/// How an image compares with a reference over the pixels that matter.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Comparison {
    /// `sqrt(Σ (x−r)² / Σ r²)` over the mask, the reference's noise included.
    pub relative_rms_raw: f64,
    /// The same after taking the stated noise out of the squared error:
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
    compare_noisy(image, None, reference, stderr, threshold, block)
}

/// [`compare`] of two noisy images: `s² = s_image² + s_reference²` comes out of the squared
/// error (e.g. the path-traced reference against Mitsuba's).
pub fn compare_noisy(
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
            "image is {}×{}, reference {}×{}",
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
    let c = montecarlo::compare(&x, &r, threshold).ok_or_else(not_above)?;
    Ok(Comparison {
        relative_rms_raw: c.relative_rms_raw,
        relative_rms: c.relative_rms_error,
        mean_ratio_error: c.relative_mean_difference,
        pixels: c.pixels,
    })
}

/// Means of `factor × factor` blocks of channel 0 (edges that do not fill a block dropped);
/// `factor` 1 is channel 0 itself.
pub fn block_means(image: &Image, factor: u32) -> Result<Image, String> {
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
        // Blocks of 3 on 4×4: the last row and column fill no block and are dropped, leaving
        // one block whose mean (two 1.1 columns, one 0.9) is 1 + 0.1/3.
        let c = compare(&x, &r, None, 0.01, 3).unwrap();
        assert_eq!(c.pixels, 1);
        assert!((c.mean_ratio_error - 0.1 / 3.0).abs() < 1e-6, "{c:?}");
    }

    #[test]
    fn both_images_noise_is_taken_out_only_when_stated() {
        let r = img(4, 4, |_, _| 1.0);
        let x = img(4, 4, |x, _| if x % 2 == 0 { 1.1 } else { 0.9 });
        // The error is sqrt(0.06² + 0.08²) = 0.1, shared between the two images.
        let (sr, sx) = (img(4, 4, |_, _| 0.06), img(4, 4, |_, _| 0.08));
        let both = compare_noisy(&x, Some(&sx), &r, Some(&sr), 0.01, 1).unwrap();
        assert!(both.relative_rms < 1e-3, "{both:?}");
        let reference_only = compare(&x, &r, Some(&sr), 0.01, 1).unwrap();
        assert!((reference_only.relative_rms - 0.08).abs() < 1e-6);
        let small = img(2, 4, |_, _| 0.08);
        assert!(compare_noisy(&x, Some(&small), &r, Some(&sr), 0.01, 1).is_err());
    }

    #[test]
    fn block_means_average_channel_0_and_drop_partial_blocks() {
        let img = Image::new(
            5,
            2,
            1,
            vec![0.0, 2.0, 4.0, 4.0, 9.0, 2.0, 0.0, 4.0, 4.0, 9.0],
        )
        .unwrap();
        let d = block_means(&img, 2).unwrap();
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.pixels, vec![1.0, 4.0]);
        let rgb = Image::new(2, 1, 3, vec![1.0, 5.0, 5.0, 3.0, 5.0, 5.0]).unwrap();
        let d = block_means(&rgb, 1).unwrap();
        assert_eq!((d.channels, d.pixels.clone()), (1, vec![1.0, 3.0]));
        assert!(block_means(&img, 3).is_err(), "2 rows fill no 3×3 block");
    }
}
