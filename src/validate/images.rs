//! The report's pictures: side-by-side panels (reference | method | error map) and the error
//! map's colour scale, as 8-bit RGB written to PNG.

use std::path::Path;

use anyhow::Result;
use gather::image_io::tone_map;
use gather::Image;
use montecarlo::compare::downscale_channel0;

use super::MASK_THRESHOLD;

/// Relative error at which the error map saturates (full blue or full red).
pub const ERROR_MAP_SCALE: f64 = 0.2;

/// Widest panel in the side-by-side images; wider cameras are block-averaged down so that the
/// committed images stay small.
const MAX_PANEL_WIDTH: u32 = 256;

/// An 8-bit RGB picture.
pub(super) struct Rgb {
    width: u32,
    height: u32,
    data: Vec<u8>,
}

impl Rgb {
    fn filled(width: u32, height: u32, value: u8) -> Rgb {
        Rgb {
            width,
            height,
            data: vec![value; (width * height * 3) as usize],
        }
    }

    fn put(&mut self, x: u32, y: u32, rgb: [u8; 3]) {
        let i = ((y * self.width + x) * 3) as usize;
        self.data[i..i + 3].copy_from_slice(&rgb);
    }
}

/// Block means of channel 0 for the panels (partial blocks at the edges dropped).
fn downscale(image: &Image, factor: u32) -> Result<Image> {
    downscale_channel0(image, factor).map_err(|e| anyhow::anyhow!("downscaling a panel: {e}"))
}

/// Diverging false colour of a relative error: blue (−scale) – white (0) – red (+scale).
fn error_colour(relative: f64) -> [u8; 3] {
    let t = (relative / ERROR_MAP_SCALE).clamp(-1.0, 1.0);
    let fade = ((1.0 - t.abs()) * 255.0 + 0.5) as u8;
    if t < 0.0 {
        [fade, fade, 255]
    } else {
        [255, fade, fade]
    }
}

/// Grey of pixels outside the error mask.
const MASKED: [u8; 3] = [48, 48, 48];
const GAP: u32 = 4;

/// Side of the pixel blocks the error map averages over: per-pixel errors would show mostly
/// the reference's noise, block means show the method's systematic error.
pub const ERROR_MAP_BLOCK: u32 = 4;

/// Exposure of the panels: the reference's maximum maps to `1 − e^−1` (63 %, sRGB 82 % white).
fn panel_exposure(reference: &Image) -> f64 {
    let max = reference.pixels.iter().copied().fold(0.0f32, f32::max) as f64;
    if max > 0.0 {
        1.0 / max
    } else {
        1.0
    }
}

/// reference | method | relative error `(x − r)/r` of `ERROR_MAP_BLOCK`² block means (blocks
/// whose reference is below the mask threshold grey), channel 0. Both radiance panels share
/// one exposure.
pub(super) fn side_by_side(reference: &Image, method: &Image) -> Result<Rgb> {
    let factor = reference.width.div_ceil(MAX_PANEL_WIDTH).max(1);
    let r = downscale(reference, factor)?;
    let x = downscale(method, factor)?;
    let exposure = panel_exposure(&r);
    let (w, h) = (r.width, r.height);
    let mut out = Rgb::filled(3 * w + 2 * GAP, h, 255);
    for y in 0..h {
        for i in 0..w {
            out.put(i, y, [tone_map(r.get(i, y, 0), exposure); 3]);
            out.put(w + GAP + i, y, [tone_map(x.get(i, y, 0), exposure); 3]);
            out.put(2 * (w + GAP) + i, y, MASKED);
        }
    }
    let block = ERROR_MAP_BLOCK.min(w).min(h).max(1);
    let (rb, xb) = (downscale(&r, block)?, downscale(&x, block)?);
    let max = rb.pixels.iter().copied().fold(0.0f32, f32::max) as f64;
    for by in 0..rb.height {
        for bx in 0..rb.width {
            let (rv, xv) = (rb.get(bx, by, 0) as f64, xb.get(bx, by, 0) as f64);
            if !(rv > MASK_THRESHOLD * max && rv > 0.0) {
                continue;
            }
            let colour = error_colour((xv - rv) / rv);
            for y in by * block..(by + 1) * block {
                for i in bx * block..(bx + 1) * block {
                    out.put(2 * (w + GAP) + i, y, colour);
                }
            }
        }
    }
    Ok(out)
}

/// The error map's colour scale, −scale on the left to +scale on the right.
pub(super) fn error_scale_bar() -> Rgb {
    let (w, h) = (256, 12);
    let mut out = Rgb::filled(w, h, 0);
    for x in 0..w {
        let rel = ERROR_MAP_SCALE * (2.0 * (x as f64 + 0.5) / w as f64 - 1.0);
        for y in 0..h {
            out.put(x, y, error_colour(rel));
        }
    }
    out
}

/// The smallest PNG: the report's images are committed (docs/validation/).
pub(super) fn write_png(path: &Path, picture: &Rgb) -> Result<()> {
    gather::image_io::write_png(
        path,
        picture.width,
        picture.height,
        3,
        &picture.data,
        gather::PngCompression::Best,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_colours_are_signed_and_saturate() {
        assert_eq!(error_colour(0.0), [255, 255, 255]);
        assert_eq!(error_colour(-1.0), [0, 0, 255]);
        assert_eq!(error_colour(ERROR_MAP_SCALE), [255, 0, 0]);
        let half = error_colour(0.5 * ERROR_MAP_SCALE);
        assert!(half[0] == 255 && half[1] > 100 && half[1] < 150);
    }
}
