//! Image files: PFM round trip and layout, malformed PFMs refused, PNG tone mapping, EXR
//! contents, atomic writes, unknown extensions, and the Mitsuba reference PFM read correctly.

use std::path::{Path, PathBuf};

use gather::image_io::{encode_png, parse_pfm, srgb_encode, tone_map, write_png};
use gather::{read_pfm, GatherError, Image, PngCompression, ToneMap};

/// A fresh empty directory for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gather-images-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Every pixel distinct, so any flip or transposition shows.
fn ramp(width: u32, height: u32, channels: u32) -> Image {
    let n = (width * height * channels) as usize;
    let pixels = (0..n).map(|i| 0.25 + i as f32 * 1.5).collect();
    Image::new(width, height, channels, pixels).unwrap()
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn pfm_round_trip_grey_and_colour() {
    let dir = scratch("pfm");
    for channels in [1, 3] {
        let img = ramp(5, 3, channels);
        let path = dir.join(format!("c{channels}.pfm"));
        img.save(&path, 1.0).unwrap();
        assert_eq!(read_pfm(&path).unwrap(), img);
    }
    assert_eq!(
        entries(&dir),
        vec!["c1.pfm", "c3.pfm"],
        "no temporary files left"
    );
}

#[test]
fn pfm_layout_is_little_endian_bottom_row_first() {
    let dir = scratch("layout");
    let img = ramp(3, 2, 1);
    let path = dir.join("a.pfm");
    img.save(&path, 1.0).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = b"Pf\n3 2\n-1.0\n";
    assert_eq!(&bytes[..header.len()], header);
    let first = f32::from_le_bytes(bytes[header.len()..header.len() + 4].try_into().unwrap());
    assert_eq!(
        first,
        img.get(0, 1, 0),
        "the file starts with the bottom-left pixel"
    );
    assert_eq!(bytes.len(), header.len() + 6 * 4);
    let colour = ramp(2, 2, 3);
    colour.save(&dir.join("b.pfm"), 1.0).unwrap();
    assert!(std::fs::read(dir.join("b.pfm"))
        .unwrap()
        .starts_with(b"PF\n2 2\n"));
}

#[test]
fn big_endian_pfm_is_read() {
    let mut bytes = b"Pf\n2 1\n1.0\n".to_vec();
    for v in [1.5f32, -2.25] {
        bytes.extend_from_slice(&v.to_be_bytes());
    }
    let img = parse_pfm(&bytes).unwrap();
    assert_eq!((img.width, img.height, img.channels), (2, 1, 1));
    assert_eq!(img.pixels, vec![1.5, -2.25]);
}

#[test]
fn malformed_pfms_are_refused() {
    let data = |n: usize| vec![0u8; n * 4];
    let with = |header: &str, body: Vec<u8>| {
        let mut b = header.as_bytes().to_vec();
        b.extend(body);
        b
    };
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty", vec![], "magic"),
        ("PPM magic", with("P6\n2 2\n255\n", data(4)), "magic"),
        ("no height", with("Pf\n2 ", vec![]), "height"),
        ("zero width", with("Pf\n0 2\n-1.0\n", vec![]), "width"),
        (
            "negative height",
            with("Pf\n2 -2\n-1.0\n", data(4)),
            "height",
        ),
        ("text width", with("Pf\nabc 2\n-1.0\n", data(4)), "width"),
        ("zero scale", with("Pf\n2 2\n0.0\n", data(4)), "scale"),
        ("NaN scale", with("Pf\n2 2\nNaN\n", data(4)), "scale"),
        ("text scale", with("Pf\n2 2\nx\n", data(4)), "scale"),
        ("short data", with("Pf\n2 2\n-1.0\n", data(3)), "data bytes"),
        ("long data", with("Pf\n2 2\n-1.0\n", data(5)), "data bytes"),
        (
            "grey size for colour",
            with("PF\n2 2\n-1.0\n", data(4)),
            "data bytes",
        ),
        (
            "huge dims",
            with("Pf\n99999999 99999999\n-1.0\n", data(1)),
            "data bytes",
        ),
    ];
    let dir = scratch("bad");
    for (what, bytes, needle) in cases {
        let path = dir.join("bad.pfm");
        std::fs::write(&path, &bytes).unwrap();
        match read_pfm(&path) {
            Err(GatherError::Format { file, message }) => {
                assert_eq!(file, path);
                assert!(
                    message.contains(needle),
                    "{what}: message `{message}` lacks `{needle}`"
                );
            }
            other => panic!("{what}: expected a format error, got {other:?}"),
        }
    }
    assert!(matches!(
        read_pfm(&dir.join("missing.pfm")),
        Err(GatherError::Io { .. })
    ));
}

#[test]
fn unknown_extension_is_refused_and_writes_nothing() {
    let dir = scratch("ext");
    for name in ["out.jpg", "out", "out.pfm.bak"] {
        match ramp(2, 2, 1).save(&dir.join(name), 1.0) {
            Err(GatherError::UnknownExtension { .. }) => {}
            other => panic!("{name}: expected UnknownExtension, got {other:?}"),
        }
    }
    assert!(entries(&dir).is_empty());
    // Extensions are case-insensitive.
    ramp(2, 2, 1).save(&dir.join("UP.PFM"), 1.0).unwrap();
}

#[test]
fn write_into_a_missing_directory_fails_cleanly() {
    let dir = scratch("missing");
    let err = ramp(2, 2, 1).save(&dir.join("nope").join("a.pfm"), 1.0);
    assert!(matches!(err, Err(GatherError::Io { .. })), "{err:?}");
    assert_eq!(entries(&dir), vec!["nope"; 0]);
}

#[test]
fn png_is_tone_mapped_and_srgb_encoded() {
    let dir = scratch("png");
    let ln2 = std::f32::consts::LN_2;
    // With exposure 2: L = ln2/2 maps to 1 − e^{−ln 2} = 0.5 before sRGB.
    let img = Image::new(4, 1, 1, vec![0.0, ln2 / 2.0, 50.0, f32::NAN]).unwrap();
    let path = dir.join("g.png");
    img.save(&path, 2.0).unwrap();
    let decoded = image::open(&path).unwrap();
    assert_eq!(decoded.color(), image::ColorType::L8);
    let luma = decoded.to_luma8();
    let half = (srgb_encode(0.5) * 255.0).round() as u8;
    assert_eq!(half, 188);
    assert_eq!(luma.as_raw(), &vec![0, half, 255, 0]);

    let rgb = Image::new(1, 2, 3, vec![0.0, ln2 / 2.0, 50.0, 0.0, 0.0, 0.0]).unwrap();
    let path = dir.join("c.png");
    rgb.save(&path, 2.0).unwrap();
    let decoded = image::open(&path).unwrap();
    assert_eq!(decoded.color(), image::ColorType::Rgb8);
    assert_eq!(decoded.to_rgb8().as_raw(), &vec![0, half, 255, 0, 0, 0]);
}

/// Every compression level encodes the same pixels; the file is written whole, and a
/// channel count other than 1 or 3 is refused.
#[test]
fn png_encoder_keeps_the_pixels_at_every_compression() {
    let dir = scratch("png-levels");
    let (width, height) = (7, 5);
    let rgb: Vec<u8> = (0..width * height * 3)
        .map(|i| (i * 37 % 256) as u8)
        .collect();
    for compression in [
        PngCompression::Fast,
        PngCompression::Default,
        PngCompression::Best,
    ] {
        let bytes = encode_png(width, height, 3, &rgb, compression).unwrap();
        let decoded = image::load_from_memory(&bytes).unwrap().to_rgb8();
        assert_eq!(decoded.dimensions(), (width, height));
        assert_eq!(decoded.as_raw(), &rgb, "{compression:?}");
    }
    let grey = &rgb[..(width * height) as usize];
    let path = dir.join("grey.png");
    write_png(&path, width, height, 1, grey, PngCompression::Default).unwrap();
    let decoded = image::open(&path).unwrap();
    assert_eq!(decoded.color(), image::ColorType::L8);
    assert_eq!(decoded.to_luma8().as_raw(), grey);
    assert_eq!(entries(&dir), vec!["grey.png"]);
    assert!(encode_png(width, height, 2, &rgb, PngCompression::Default).is_err());
    assert!(encode_png(width, height + 1, 3, &rgb, PngCompression::Default).is_err());
}

/// The table gives `tone_map`'s bytes exactly: at every step and the floats around it (where an
/// off-by-one-ulp step would show), at many radiances over 18 decades, at special values, and at
/// exposures without a table (which fall back to `tone_map`).
#[test]
fn tone_map_table_gives_the_same_bytes_as_the_curve() {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let special = [
        0.0,
        -0.0,
        -1.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN_POSITIVE,
        f32::from_bits(1),
        1e-30,
    ];
    for exposure in [
        1e-3,
        0.37,
        1.0,
        4.0,
        250.0,
        0.0,
        -2.0,
        f64::NAN,
        f64::INFINITY,
    ] {
        let map = ToneMap::new(exposure);
        let check = |l: f32| {
            assert_eq!(
                map.apply(l),
                tone_map(l, exposure),
                "radiance {l:e} (bits {:#x}) at exposure {exposure}",
                l.to_bits()
            )
        };
        special.iter().for_each(|&l| check(l));
        for _ in 0..20_000 {
            check(10f64.powf(-12.0 + 18.0 * uniform()) as f32);
        }
        // Around each place the byte changes, found by scanning the curve.
        let mut steps_seen = 0;
        let mut l = 1e-9f32;
        while l < 1e9 {
            let next = l * 1.001;
            if tone_map(l, exposure) != tone_map(next, exposure) {
                steps_seen += 1;
                let (mut lo, mut hi) = (l.to_bits(), next.to_bits());
                while hi - lo > 1 {
                    let mid = lo + (hi - lo) / 2;
                    if tone_map(f32::from_bits(mid), exposure) == tone_map(l, exposure) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                for bits in hi.saturating_sub(3)..=hi + 3 {
                    check(f32::from_bits(bits));
                }
            }
            l = next;
        }
        if exposure.is_finite() && exposure > 0.0 {
            assert!(
                steps_seen >= 200,
                "{steps_seen} steps at exposure {exposure}"
            );
        }
    }
}

#[test]
fn exr_holds_linear_floats_top_row_first() {
    use exr::prelude::*;
    let dir = scratch("exr");
    for channels in [1u32, 3] {
        let img = ramp(4, 3, channels);
        let path = dir.join(format!("c{channels}.exr"));
        img.save(&path, 1.0).unwrap();
        let read = read_all_flat_layers_from_file(&path).unwrap();
        let layer = &read.layer_data[0];
        assert_eq!(layer.size, Vec2(4, 3));
        let names: Vec<String> = layer
            .channel_data
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        let want_names: &[&str] = if channels == 1 {
            &["Y"]
        } else {
            &["B", "G", "R"]
        };
        assert_eq!(names, want_names);
        for ch in &layer.channel_data.list {
            let c = match ch.name.to_string().as_str() {
                "R" | "Y" => 0,
                "G" => 1,
                _ => 2,
            };
            let FlatSamples::F32(values) = &ch.sample_data else {
                panic!("EXR samples are not f32");
            };
            for y in 0..3u32 {
                for x in 0..4u32 {
                    assert_eq!(values[(y * 4 + x) as usize], img.get(x, y, c));
                }
            }
        }
    }
    assert_eq!(entries(&dir), vec!["c1.exr", "c3.exr"]);
}

#[test]
fn inconsistent_images_are_refused() {
    assert!(Image::new(2, 2, 2, vec![0.0; 8]).is_err());
    assert!(Image::new(2, 2, 1, vec![0.0; 3]).is_err());
    assert!(Image::new(0, 2, 1, vec![]).is_err());
    let broken = Image {
        width: 3,
        height: 3,
        channels: 1,
        pixels: vec![0.0; 4],
    };
    let dir = scratch("broken");
    assert!(broken.save(&dir.join("b.pfm"), 1.0).is_err());
    assert!(entries(&dir).is_empty());
}

#[test]
fn mitsuba_reference_pfm_reads_with_its_documented_statistics() {
    // tests/data/cloud24-isotropic/README.md (project root): mean 0.008558, maximum 0.136978.
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/cloud24-isotropic/front.pfm");
    let img = read_pfm(&path).unwrap();
    assert_eq!((img.width, img.height, img.channels), (256, 192, 1));
    let mean = img.pixels.iter().map(|&v| v as f64).sum::<f64>() / img.pixels.len() as f64;
    let max = img.pixels.iter().copied().fold(0.0f32, f32::max) as f64;
    assert!((mean - 0.008558).abs() < 1e-6, "mean {mean}");
    assert!((max - 0.136978).abs() < 1e-6, "max {max}");
}
