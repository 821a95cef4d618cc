//! Images and their files: PNG (tone-mapped 8-bit), PFM and EXR (linear float radiance).
//!
//! Every write goes to a temporary file beside the target and is renamed into place, so a
//! reader never sees a half-written image. [`encode_png`] and [`write_png`] are volrad's one
//! PNG encoder: renders, the service's images, validation composites and plots all go
//! through them.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::GatherError;

/// Radiance per pixel: `channels` (1 grey, 3 RGB) interleaved floats, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub pixels: Vec<f32>,
}

/// Output formats, chosen by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    Png,
    Pfm,
    Exr,
}

impl ImageFormat {
    /// The format named by a path's extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<ImageFormat, GatherError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        match ext.as_str() {
            "png" => Ok(ImageFormat::Png),
            "pfm" => Ok(ImageFormat::Pfm),
            "exr" => Ok(ImageFormat::Exr),
            _ => Err(GatherError::UnknownExtension {
                file: path.to_path_buf(),
                extension: ext,
            }),
        }
    }
}

impl Image {
    /// Checks that the sizes agree, so files are never written from inconsistent images.
    pub fn new(
        width: u32,
        height: u32,
        channels: u32,
        pixels: Vec<f32>,
    ) -> Result<Image, GatherError> {
        if !(channels == 1 || channels == 3) {
            return Err(GatherError::Render(format!(
                "{channels} image channels (expected 1 or 3)"
            )));
        }
        let expected = width as usize * height as usize * channels as usize;
        if pixels.len() != expected || width == 0 || height == 0 {
            return Err(GatherError::Render(format!(
                "{} values for a {width}×{height}×{channels} image",
                pixels.len()
            )));
        }
        Ok(Image {
            width,
            height,
            channels,
            pixels,
        })
    }

    /// Value of channel `c` at pixel `(x, y)`, `(0, 0)` top-left.
    #[inline]
    pub fn get(&self, x: u32, y: u32, c: u32) -> f32 {
        self.pixels[((y * self.width + x) * self.channels + c) as usize]
    }

    /// Writes the image in the format its extension names: `.png` tone-mapped with
    /// `exposure` (pixel = 1 − exp(−exposure · L), then sRGB), `.pfm` and `.exr` linear.
    pub fn save(&self, path: &Path, exposure: f64) -> Result<(), GatherError> {
        let format = ImageFormat::from_path(path)?;
        self.check()?;
        match format {
            ImageFormat::Png => write_png(
                path,
                self.width,
                self.height,
                self.channels,
                &self.tone_mapped(exposure),
                PngCompression::Default,
            ),
            ImageFormat::Pfm => write_atomic(path, |tmp| {
                let file = fs::File::create(tmp).map_err(|e| GatherError::io(tmp, e))?;
                let mut out = BufWriter::new(file);
                self.write_pfm_to(&mut out)
                    .and_then(|_| out.flush())
                    .map_err(|e| GatherError::io(tmp, e))
            }),
            ImageFormat::Exr => write_atomic(path, |tmp| self.write_exr(path, tmp)),
        }
    }

    fn check(&self) -> Result<(), GatherError> {
        let expected = self.width as usize * self.height as usize * self.channels as usize;
        if (self.channels == 1 || self.channels == 3)
            && self.pixels.len() == expected
            && expected > 0
        {
            Ok(())
        } else {
            Err(GatherError::Render(format!(
                "inconsistent image: {} values for {}×{}×{}",
                self.pixels.len(),
                self.width,
                self.height,
                self.channels
            )))
        }
    }

    /// PFM: "Pf" (grey) or "PF" (RGB), scale −1 (little-endian), rows bottom first.
    pub fn write_pfm_to(&self, out: &mut impl Write) -> std::io::Result<()> {
        let magic = if self.channels == 1 { "Pf" } else { "PF" };
        write!(out, "{magic}\n{} {}\n-1.0\n", self.width, self.height)?;
        let row_len = (self.width * self.channels) as usize;
        let mut bytes = Vec::with_capacity(row_len * 4);
        for row in self.pixels.chunks_exact(row_len).rev() {
            bytes.clear();
            for v in row {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
            out.write_all(&bytes)?;
        }
        Ok(())
    }

    /// 8-bit display values of every pixel: [`tone_map`]'s bytes, through a [`ToneMap`].
    pub fn tone_mapped(&self, exposure: f64) -> Vec<u8> {
        let map = ToneMap::new(exposure);
        self.pixels.iter().map(|&l| map.apply(l)).collect()
    }

    fn write_exr(&self, target: &Path, tmp: &Path) -> Result<(), GatherError> {
        use exr::prelude::*;
        let (w, h) = (self.width as usize, self.height as usize);
        let result = if self.channels == 1 {
            let channels = SpecificChannels::build()
                .with_channel("Y")
                .with_pixel_fn(|Vec2(x, y)| (self.pixels[y * w + x],));
            Image::from_channels((w, h), channels).write().to_file(tmp)
        } else {
            let px = |x: usize, y: usize, c: usize| self.pixels[(y * w + x) * 3 + c];
            write_rgb_file(tmp, w, h, |x, y| (px(x, y, 0), px(x, y, 1), px(x, y, 2)))
        };
        result.map_err(|e| GatherError::Encode {
            file: target.to_path_buf(),
            message: e.to_string(),
        })
    }
}

/// How hard a PNG is compressed; the pixels are the same at every level, only the file's size
/// and the time to write it differ.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PngCompression {
    /// Fast compression with the `Sub` filter: images that are viewed once, not kept (the
    /// service's responses).
    Fast,
    /// The encoder's default (adaptive filters): renders and plots.
    #[default]
    Default,
    /// The smallest files (adaptive filters): images committed to the repository.
    Best,
}

/// 8-bit pixels as a PNG file's bytes: `channels` 1 (grey) or 3 (RGB) interleaved values a
/// pixel, rows top first. Errs when the sizes do not agree or the encoder fails.
pub fn encode_png(
    width: u32,
    height: u32,
    channels: u32,
    pixels: &[u8],
    compression: PngCompression,
) -> Result<Vec<u8>, String> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let color = match channels {
        1 => image::ExtendedColorType::L8,
        3 => image::ExtendedColorType::Rgb8,
        _ => return Err(format!("{channels} channels (expected 1 or 3)")),
    };
    let expected = width as u64 * height as u64 * channels as u64;
    if pixels.len() as u64 != expected || expected == 0 {
        return Err(format!(
            "{} bytes for a {width}×{height} image with {channels} channel(s)",
            pixels.len()
        ));
    }
    let mut out = Vec::new();
    let encoder = match compression {
        PngCompression::Fast => {
            PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub)
        }
        PngCompression::Default => PngEncoder::new(&mut out),
        PngCompression::Best => {
            PngEncoder::new_with_quality(&mut out, CompressionType::Best, FilterType::Adaptive)
        }
    };
    encoder
        .write_image(pixels, width, height, color)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// [`encode_png`] written to `path` atomically ([`medium::atomic_file`]): a reader sees the
/// old file or the whole new one.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    channels: u32,
    pixels: &[u8],
    compression: PngCompression,
) -> Result<(), GatherError> {
    let bytes = encode_png(width, height, channels, pixels, compression).map_err(|message| {
        GatherError::Encode {
            file: path.to_path_buf(),
            message,
        }
    })?;
    medium::atomic_file::write_bytes(path, &bytes).map_err(|e| GatherError::io(path, e))
}

/// 8-bit display value of radiance `l`: `1 − exp(−exposure · L)`, sRGB-encoded (non-finite
/// and negative values show as black).
pub fn tone_map(l: f32, exposure: f64) -> u8 {
    let l = if l.is_finite() {
        (l as f64).max(0.0)
    } else {
        0.0
    };
    (srgb_encode(1.0 - (-exposure * l).exp()) * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// [`tone_map`] at one exposure as the 255 radiances where its byte steps up, found once:
/// each value then costs a branch-free search of that table instead of an `exp` and a `powf`
/// (the service tone-maps every image it sends). The bytes are [`tone_map`]'s exactly: each
/// step is the smallest `f32` that `tone_map` itself takes to that byte.
#[derive(Clone, Debug)]
pub struct ToneMap {
    exposure: f64,
    /// `steps[k]` (`k ≥ 1`): the least radiance whose byte is `≥ k` (`+∞` if none);
    /// `steps[0] = 0`. `None`: an exposure without steps (not finite and positive), where
    /// every value goes through [`tone_map`].
    steps: Option<Box<[f32; 256]>>,
}

impl ToneMap {
    pub fn new(exposure: f64) -> Self {
        let steps = (exposure.is_finite() && exposure > 0.0).then(|| {
            let mut steps = Box::new([0.0f32; 256]);
            let tone = |bits: u32| tone_map(f32::from_bits(bits), exposure);
            // Non-negative finite floats order as their bit patterns.
            let top = f32::MAX.to_bits();
            let mut below = 0u32;
            for k in 1..=255u8 {
                let Some(at) = first_reaching(k, below, top, guess_bits(k, exposure), &tone) else {
                    steps[k as usize..].fill(f32::INFINITY);
                    break;
                };
                steps[k as usize] = f32::from_bits(at);
                below = at;
            }
            steps
        });
        ToneMap { exposure, steps }
    }

    /// [`tone_map`]`(l, exposure)`.
    #[inline]
    pub fn apply(&self, l: f32) -> u8 {
        let Some(steps) = &self.steps else {
            return tone_map(l, self.exposure);
        };
        if !(l.is_finite() && l > 0.0) {
            return 0;
        }
        // The last k with steps[k] ≤ l (steps[0] = 0 < l), in eight selects.
        let mut k = 0;
        for half in [128, 64, 32, 16, 8, 4, 2, 1] {
            if steps[k + half] <= l {
                k += half;
            }
        }
        k as u8
    }
}

/// Where `tone_map` should first reach byte `k`, from the inverse of its curve (a guess: the
/// search confirms it bit by bit).
fn guess_bits(k: u8, exposure: f64) -> u32 {
    let encoded = (k as f64 - 0.5) / 255.0;
    let linear = if encoded <= 0.040_45 {
        encoded / 12.92
    } else {
        ((encoded + 0.055) / 1.055).powf(2.4)
    };
    let l = -(-linear).ln_1p() / exposure;
    if l.is_finite() && l >= 0.0 {
        (l as f32).to_bits()
    } else {
        f32::MAX.to_bits()
    }
}

/// The least bit pattern in `[below, top]` whose `tone` is `≥ k`, `None` if even `top`'s is
/// not; `tone` must not decrease. Gallops from `guess` to bracket it, then bisects.
fn first_reaching(
    k: u8,
    below: u32,
    top: u32,
    guess: u32,
    tone: &impl Fn(u32) -> u8,
) -> Option<u32> {
    if tone(top) < k {
        return None;
    }
    if tone(below) >= k {
        return Some(below);
    }
    // Invariant: tone(lo) < k ≤ tone(hi).
    let guess = guess.clamp(below, top);
    let (mut lo, mut hi) = if tone(guess) >= k {
        let (mut hi, mut step) = (guess, 1u32);
        loop {
            let probe = hi.saturating_sub(step).max(below);
            if tone(probe) < k {
                break (probe, hi);
            }
            hi = probe;
            step = step.saturating_mul(2);
        }
    } else {
        let (mut lo, mut step) = (guess, 1u32);
        loop {
            let probe = lo.saturating_add(step).min(top);
            if tone(probe) >= k {
                break (lo, probe);
            }
            lo = probe;
            step = step.saturating_mul(2);
        }
    };
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if tone(mid) >= k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(hi)
}

/// The sRGB transfer curve for a linear value in [0, 1].
#[inline]
pub fn srgb_encode(linear: f64) -> f64 {
    let v = linear.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Runs `write` on a temporary path beside `path`, then syncs it and renames it into place
/// ([`medium::atomic_file`]); the temporary file is removed if anything fails.
fn write_atomic(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), GatherError>,
) -> Result<(), GatherError> {
    medium::atomic_file::write_with(path, write, |e| GatherError::io(path, e))
}

/// Reads a linear image by its extension: `.pfm` ([`read_pfm`]) or `.exr` ([`read_exr`]);
/// only regular files are opened (a FIFO or a device is refused, never waited on).
pub fn read_image(path: &Path) -> Result<Image, GatherError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("pfm") => read_pfm(path),
        Some("exr") => read_exr(path),
        _ => Err(GatherError::format(
            path,
            "unknown image extension (expected .exr or .pfm, linear radiance)",
        )),
    }
}

/// Reads an OpenEXR file's first layer: its R, G and B channels (A ignored), or its Y
/// channel alone (grey), as f32, top row first.
pub fn read_exr(path: &Path) -> Result<Image, GatherError> {
    let bytes = medium::regular_file::read(path).map_err(|e| GatherError::io(path, e))?;
    parse_exr(&bytes).map_err(|m| GatherError::format(path, m))
}

/// Parses OpenEXR bytes (see [`read_exr`]); the error says what was wrong.
pub fn parse_exr(bytes: &[u8]) -> Result<Image, String> {
    // The decoder is a dependency's: should it panic on a malformed file, that is this file's
    // error, not the program's end.
    std::panic::catch_unwind(|| decode_exr(bytes))
        .unwrap_or_else(|_| Err("not a readable EXR (the decoder failed on it)".into()))
}

/// [`parse_exr`] without the guard.
fn decode_exr(bytes: &[u8]) -> Result<Image, String> {
    use exr::prelude::*;
    let bad = |e: exr::error::Error| format!("not a readable EXR: {e}");
    // The size a header declares is checked before anything that large is allocated.
    let fits = |size: Vec2<usize>| {
        size.width()
            .checked_mul(size.height())
            .is_some_and(|n| n <= MAX_READ_PIXELS)
    };
    let rgb = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |size, _| {
                let n = if fits(size) {
                    size.width() * size.height()
                } else {
                    0
                };
                (size.width(), vec![0.0f32; n * 3])
            },
            |(w, px): &mut (usize, Vec<f32>), Vec2(x, y), (r, g, b, _a): (f32, f32, f32, f32)| {
                let i = (y * *w + x) * 3;
                if let Some(p) = px.get_mut(i..i + 3) {
                    p.copy_from_slice(&[r, g, b]);
                }
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes));
    let (size, channels, pixels) = match rgb {
        Ok(image) => {
            let layer = image.layer_data;
            (layer.size, 3, layer.channel_data.pixels.1)
        }
        Err(_) => {
            let grey = read()
                .no_deep_data()
                .largest_resolution_level()
                .specific_channels()
                .required("Y")
                .collect_pixels(
                    |size, _| {
                        let n = if fits(size) {
                            size.width() * size.height()
                        } else {
                            0
                        };
                        (size.width(), vec![0.0f32; n])
                    },
                    |(w, px): &mut (usize, Vec<f32>), Vec2(x, y), (v,): (f32,)| {
                        if let Some(p) = px.get_mut(y * *w + x) {
                            *p = v;
                        }
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .from_buffered(std::io::Cursor::new(bytes))
                .map_err(bad)?;
            let layer = grey.layer_data;
            (layer.size, 1, layer.channel_data.pixels.1)
        }
    };
    if !fits(size) {
        return Err(format!(
            "{} × {} pixels: at most {MAX_READ_PIXELS}",
            size.width(),
            size.height()
        ));
    }
    self::Image::new(size.width() as u32, size.height() as u32, channels, pixels)
        .map_err(|e| e.to_string())
}

/// Most pixels [`read_exr`] reads (a 16k × 8k panorama), checked against the header before
/// the pixels are allocated.
pub const MAX_READ_PIXELS: usize = 1 << 27;

/// Reads a PFM file ("Pf" grey or "PF" RGB, either byte order) into an [`Image`] with the top
/// row first. Refuses malformed headers, non-positive sizes, a zero or non-finite scale and
/// data of the wrong length, saying which.
pub fn read_pfm(path: &Path) -> Result<Image, GatherError> {
    let bytes = medium::regular_file::read(path).map_err(|e| GatherError::io(path, e))?;
    parse_pfm(&bytes).map_err(|m| GatherError::format(path, format!("not a valid PFM: {m}")))
}

/// Parses PFM bytes (see [`read_pfm`]); the error says what was wrong.
pub fn parse_pfm(bytes: &[u8]) -> Result<Image, String> {
    let mut pos = 0usize;
    // The header is three whitespace-separated tokens; a single whitespace byte follows the
    // last one and the binary data starts right after it.
    let mut token = |what: &str| -> Result<String, String> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
            if pos - start > 32 {
                return Err(format!("header {what} is not a short token"));
            }
        }
        if pos == start {
            return Err(format!("header ends before the {what}"));
        }
        let s = std::str::from_utf8(&bytes[start..pos])
            .map_err(|_| format!("header {what} is not text"))?
            .to_string();
        Ok(s)
    };
    let magic = token("magic")?;
    let channels = match magic.as_str() {
        "Pf" => 1u32,
        "PF" => 3u32,
        other => return Err(format!("magic `{other}` (expected `Pf` or `PF`)")),
    };
    let mut dim = |what: &str| -> Result<u32, String> {
        let t = token(what)?;
        match t.parse::<u32>() {
            Ok(v) if v > 0 => Ok(v),
            _ => Err(format!("{what} `{t}` is not a positive integer")),
        }
    };
    let width = dim("width")?;
    let height = dim("height")?;
    let scale_token = token("scale")?;
    let scale: f64 = scale_token
        .parse()
        .map_err(|_| format!("scale `{scale_token}` is not a number"))?;
    if !(scale.is_finite() && scale != 0.0) {
        return Err(format!("scale {scale} must be finite and non-zero"));
    }
    let little_endian = scale < 0.0;
    let data_start = pos + 1; // the single whitespace byte after the scale
                              // In u128: the byte count of any header's sizes (< 2⁶⁸) fits, where in u64 it may not.
    let count = width as u128 * height as u128 * channels as u128;
    let data = &bytes[data_start.min(bytes.len())..];
    if data.len() as u128 != count * 4 {
        return Err(format!(
            "{} data bytes for a {width}×{height} image with {channels} channel(s) (expected {})",
            data.len(),
            count * 4
        ));
    }
    // (The data are there, so these counts fit in memory.)
    let row_len = width as usize * channels as usize;
    let mut pixels = vec![0.0f32; count as usize];
    // File rows are bottom first; the image is top first.
    for (file_row, chunk) in data.chunks_exact(row_len * 4).enumerate() {
        let row = height as usize - 1 - file_row;
        for (i, b) in chunk.chunks_exact(4).enumerate() {
            let b = [b[0], b[1], b[2], b[3]];
            pixels[row * row_len + i] = if little_endian {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(Image {
        width,
        height,
        channels,
        pixels,
    })
}
