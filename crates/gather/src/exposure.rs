//! Automatic exposure for 8-bit pictures: the exposure at which the bright end of an image
//! (its 99.5th percentile of pixel radiance, all channels) shows at [`AUTO_EXPOSURE_LEVEL`]
//! of white under [`tone_map`](crate::image_io::tone_map)'s curve `1 − exp(−exposure · L)`.
//!
//! A percentile rather than the maximum, so that a few hot pixels (a light's glint, path
//! tracing noise) do not darken the rest; the top half percent may clip, as a photographer's
//! meter lets speculars clip.

use crate::image_io::Image;

/// Display value (before sRGB encoding) the metered radiance is mapped to.
pub const AUTO_EXPOSURE_LEVEL: f64 = 0.85;

/// Which radiance is metered: this fraction of the pixel values lies at or below it.
pub const AUTO_EXPOSURE_PERCENTILE: f64 = 0.995;

/// The exposure that maps the image's 99.5th-percentile radiance to
/// [`AUTO_EXPOSURE_LEVEL`]; 1 for an image with no positive finite value (all black).
pub fn auto_exposure(image: &Image) -> f64 {
    let mut values: Vec<f32> = image
        .pixels
        .iter()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    if values.is_empty() {
        return 1.0;
    }
    // Zeros (empty background) count towards the percentile: they are part of the picture.
    let zeros = image.pixels.len() - values.len();
    let rank = ((AUTO_EXPOSURE_PERCENTILE * image.pixels.len() as f64).ceil() as usize)
        .clamp(1, image.pixels.len());
    let index = rank.saturating_sub(zeros + 1).min(values.len() - 1);
    let (_, &mut metered, _) = values.select_nth_unstable_by(index, f32::total_cmp);
    -(1.0 - AUTO_EXPOSURE_LEVEL).ln() / metered as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(pixels: Vec<f32>) -> Image {
        Image {
            width: pixels.len() as u32,
            height: 1,
            channels: 1,
            pixels,
        }
    }

    #[test]
    fn the_metered_radiance_shows_at_the_chosen_level() {
        // 1000 pixels from 0.001 to 1: the 995th value is 0.995.
        let img = image((1..=1000).map(|i| i as f32 / 1000.0).collect());
        let e = auto_exposure(&img);
        let shown = 1.0 - (-e * 0.995f64).exp();
        assert!((shown - AUTO_EXPOSURE_LEVEL).abs() < 1e-6, "{shown}");
        // Scaling the picture's radiance scales the exposure inversely: the same picture.
        let dim = image(img.pixels.iter().map(|v| v * 0.01).collect());
        assert!((auto_exposure(&dim) / e - 100.0).abs() < 1e-3);
    }

    #[test]
    fn hot_pixels_and_empty_background_do_not_set_the_exposure() {
        // 90 % empty background, a cloud at radiance 0.2, and three hot pixels.
        let mut pixels = vec![0.0f32; 9000];
        pixels.extend(std::iter::repeat_n(0.2f32, 997));
        pixels.extend([50.0, 80.0, f32::NAN]);
        let e = auto_exposure(&image(pixels));
        let shown = 1.0 - (-e * 0.2f64).exp();
        assert!((shown - AUTO_EXPOSURE_LEVEL).abs() < 1e-6, "{shown}");
        assert_eq!(auto_exposure(&image(vec![0.0; 10])), 1.0);
    }
}
