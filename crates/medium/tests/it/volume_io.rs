//! Volume files: round trips through every reader and writer, and bad files refused clearly.

use std::io::Write;
use std::path::PathBuf;

use medium::volume_io::{
    load_volume, read_mitsuba_vol, read_nrrd, read_raw_f32, write_mitsuba_vol, write_nrrd,
    write_raw_f32, NrrdWriteOptions, VolumeData,
};
use medium::MediumError;

/// A fresh directory per test (tests run in parallel).
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("volrad-volume-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Distinct values so any index mix-up shows: value = i + 10 j + 100 k + 0.25.
fn sample() -> VolumeData {
    let dims = [3, 4, 5];
    let mut values = Vec::new();
    for k in 0..5 {
        for j in 0..4 {
            for i in 0..3 {
                values.push(i as f32 + 10.0 * j as f32 + 100.0 * k as f32 + 0.25);
            }
        }
    }
    VolumeData::new(dims, values).unwrap()
}

fn message(e: MediumError) -> String {
    e.to_string()
}

#[test]
fn raw_round_trip_and_x_fastest_layout() {
    let dir = scratch("raw");
    let path = dir.join("v.f32");
    let v = sample();
    write_raw_f32(&path, &v).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes.len(), 3 * 4 * 5 * 4);
    // Second value in the file is cell (1, 0, 0).
    assert_eq!(f32::from_le_bytes(bytes[4..8].try_into().unwrap()), 1.25);
    assert_eq!(read_raw_f32(&path, [3, 4, 5]).unwrap(), v);
    assert_eq!(load_volume(&path, Some([3, 4, 5])).unwrap(), v);
    // No temp file left behind by the atomic write.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
}

#[test]
fn raw_of_wrong_size_is_refused_naming_file_and_sizes() {
    let dir = scratch("rawsize");
    let path = dir.join("short.f32");
    std::fs::write(&path, vec![0u8; 100]).unwrap();
    let msg = message(read_raw_f32(&path, [3, 4, 5]).unwrap_err());
    assert!(msg.contains("short.f32"), "{msg}");
    assert!(msg.contains("100"), "{msg}");
    assert!(msg.contains("240"), "{msg}");
    // A raw file without dims cannot be read.
    assert!(load_volume(&path, None).is_err());
}

#[test]
fn mitsuba_vol_round_trip_and_header() {
    let dir = scratch("vol");
    let path = dir.join("v.vol");
    let v = sample();
    write_mitsuba_vol(&path, &v, 0.5).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..4], b"VOL\x03");
    assert_eq!(bytes.len(), 48 + 60 * 4);
    // Bounding box max x = 3 cells × 0.5.
    assert_eq!(f32::from_le_bytes(bytes[36..40].try_into().unwrap()), 1.5);
    assert_eq!(read_mitsuba_vol(&path).unwrap(), v);
    assert_eq!(load_volume(&path, None).unwrap(), v);
    assert_eq!(load_volume(&path, Some([3, 4, 5])).unwrap(), v);
    let msg = message(load_volume(&path, Some([5, 4, 3])).unwrap_err());
    assert!(
        msg.contains("[3, 4, 5]") && msg.contains("[5, 4, 3]"),
        "{msg}"
    );
}

#[test]
fn mitsuba_vol_other_encodings_and_channels_are_refused() {
    let dir = scratch("volbad");
    let v = sample();
    let good = dir.join("good.vol");
    write_mitsuba_vol(&good, &v, 1.0).unwrap();
    let bytes = std::fs::read(&good).unwrap();

    let mut half = bytes.clone();
    half[4..8].copy_from_slice(&2i32.to_le_bytes()); // float16
    let p = dir.join("half.vol");
    std::fs::write(&p, &half).unwrap();
    let msg = message(read_mitsuba_vol(&p).unwrap_err());
    assert!(
        msg.contains("encoding 2") && msg.contains("half.vol"),
        "{msg}"
    );

    let mut rgb = bytes.clone();
    rgb[20..24].copy_from_slice(&3i32.to_le_bytes());
    let p = dir.join("rgb.vol");
    std::fs::write(&p, &rgb).unwrap();
    assert!(message(read_mitsuba_vol(&p).unwrap_err()).contains("3 channels"));

    let mut v2 = bytes.clone();
    v2[3] = 2;
    let p = dir.join("v2.vol");
    std::fs::write(&p, &v2).unwrap();
    assert!(message(read_mitsuba_vol(&p).unwrap_err()).contains("version 2"));

    let p = dir.join("trunc.vol");
    std::fs::write(&p, &bytes[..bytes.len() - 4]).unwrap();
    assert!(message(read_mitsuba_vol(&p).unwrap_err()).contains("bytes"));

    let p = dir.join("magic.vol");
    std::fs::write(
        &p,
        b"NOTAVOLUMEFILE-------------------------------------------",
    )
    .unwrap();
    assert!(message(read_mitsuba_vol(&p).unwrap_err()).contains("VOL"));
}

#[test]
fn nrrd_round_trip_raw_and_gzip_with_header_lines() {
    let dir = scratch("nrrd");
    let v = sample();
    for gzip in [false, true] {
        let path = dir.join(if gzip { "g.nrrd" } else { "r.nrrd" });
        let opts = NrrdWriteOptions {
            comments: vec![("scene".into(), "cloud.toml".into())],
            units: Some("m".into()),
            spacings: Some([0.5, 0.5, 0.5]),
            gzip,
        };
        write_nrrd(&path, &v, &opts).unwrap();
        let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).into_owned();
        assert!(text.starts_with("NRRD0004\n"));
        assert!(text.contains("# scene: cloud.toml\n"));
        assert!(text.contains("spacings: 0.5 0.5 0.5\n"));
        assert!(text.contains("units: \"m\" \"m\" \"m\"\n"));
        assert!(text.contains(if gzip {
            "encoding: gzip"
        } else {
            "encoding: raw"
        }));
        assert_eq!(read_nrrd(&path).unwrap(), v);
        assert_eq!(load_volume(&path, Some([3, 4, 5])).unwrap(), v);
    }
}

fn nrrd_with(dir: &std::path::Path, name: &str, header: &str, data: &[u8]) -> PathBuf {
    let path = dir.join(name);
    let mut f = std::fs::File::create(&path).unwrap();
    f.write_all(header.as_bytes()).unwrap();
    f.write_all(data).unwrap();
    path
}

#[test]
fn nrrd_integer_types_big_endian_and_detached_data() {
    let dir = scratch("nrrdtypes");
    // ushort, big endian, 2×1×2.
    let vals: [u16; 4] = [1, 300, 65535, 7];
    let data: Vec<u8> = vals.iter().flat_map(|v| v.to_be_bytes()).collect();
    let p = nrrd_with(
        &dir,
        "u16.nrrd",
        "NRRD0004\n# comment\ntype: unsigned short\ndimension: 3\nsizes: 2 1 2\nendian: big\nencoding: raw\nkey:=value\n\n",
        &data,
    );
    assert_eq!(
        read_nrrd(&p).unwrap().values,
        vec![1.0, 300.0, 65535.0, 7.0]
    );

    // uchar needs no endian.
    let p = nrrd_with(
        &dir,
        "u8.nrrd",
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 1\nencoding: raw\n\n",
        &[0, 1, 2, 255],
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![0.0, 1.0, 2.0, 255.0]);

    // short and int, little endian.
    let data: Vec<u8> = [-5i16, 6].iter().flat_map(|v| v.to_le_bytes()).collect();
    let p = nrrd_with(
        &dir,
        "s16.nrrd",
        "NRRD0004\ntype: short\ndimension: 3\nsizes: 1 1 2\nendian: little\nencoding: raw\n\n",
        &data,
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![-5.0, 6.0]);
    let data: Vec<u8> = [-70000i32, 3]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let p = nrrd_with(
        &dir,
        "i32.nrrd",
        "NRRD0004\ntype: int\ndimension: 3\nsizes: 1 2 1\nendian: little\nencoding: raw\n\n",
        &data,
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![-70000.0, 3.0]);

    // double, detached data file next to the header.
    let data: Vec<u8> = [0.5f64, 2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("payload.raw"), &data).unwrap();
    let p = nrrd_with(&dir, "d.nhdr", "NRRD0004\ntype: double\ndimension: 3\nsizes: 2 1 1\nendian: little\nencoding: raw\ndata file: payload.raw\n", &[]);
    assert_eq!(read_nrrd(&p).unwrap().values, vec![0.5, 2.0]);
    assert_eq!(load_volume(&p, None).unwrap().dims, [2, 1, 1]);
}

#[test]
fn nrrd_unsupported_or_inconsistent_headers_are_refused() {
    let dir = scratch("nrrdbad");
    let cases: [(&str, &str, &[u8], &str); 6] = [
        ("dim.nrrd", "NRRD0004\ntype: float\ndimension: 2\nsizes: 2 2\nendian: little\nencoding: raw\n\n", &[0; 16], "dimension 2"),
        ("enc.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nendian: little\nencoding: ascii\n\n", b"1.0", "encoding `ascii`"),
        ("type.nrrd", "NRRD0004\ntype: block\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n", &[0; 4], "type `block`"),
        ("endian.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n", &[0; 4], "endian"),
        ("short.nrrd", "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 1 1\nendian: little\nencoding: raw\n\n", &[0; 4], "need 8"),
        ("magic.nrrd", "P6\n", &[], "NRRD000"),
    ];
    for (name, header, data, expected) in cases {
        let p = nrrd_with(&dir, name, header, data);
        let msg = message(read_nrrd(&p).unwrap_err());
        assert!(msg.contains(expected), "{name}: {msg}");
        assert!(msg.contains(name), "{name}: {msg}");
    }
}

#[test]
fn failed_write_leaves_no_partial_file() {
    let dir = scratch("atomic");
    let missing = dir.join("no-such-dir").join("v.f32");
    assert!(write_raw_f32(&missing, &sample()).is_err());
    // A value count that does not match the dims is refused before anything is written.
    let bad = VolumeData {
        dims: [2, 2, 2],
        values: vec![0.0; 3],
    };
    let p = dir.join("bad.nrrd");
    assert!(write_nrrd(&p, &bad, &NrrdWriteOptions::default()).is_err());
    assert!(!p.exists());
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
}

mod round_trip_property {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Any dims and any finite values survive every writer/reader pair bit for bit.
        #[test]
        fn every_format_round_trips(
            nx in 1usize..7, ny in 1usize..7, nz in 1usize..7,
            seed in any::<u32>(),
        ) {
            let n = nx * ny * nz;
            let values: Vec<f32> = (0..n)
                .map(|i| f32::from_bits((seed as u64 * 2654435761 + i as u64 * 40503) as u32 & 0x7f7f_ffff) * if i % 3 == 0 { -1.0 } else { 1.0 })
                .collect();
            let v = VolumeData::new([nx, ny, nz], values).unwrap();
            let dir = scratch(&format!("prop-{nx}-{ny}-{nz}-{seed}"));
            let raw = dir.join("v.raw");
            write_raw_f32(&raw, &v).unwrap();
            prop_assert_eq!(&load_volume(&raw, Some([nx, ny, nz])).unwrap(), &v);
            let vol = dir.join("v.vol");
            write_mitsuba_vol(&vol, &v, 1.0).unwrap();
            prop_assert_eq!(&load_volume(&vol, None).unwrap(), &v);
            for gzip in [false, true] {
                let p = dir.join(format!("v{gzip}.nrrd"));
                write_nrrd(&p, &v, &NrrdWriteOptions { gzip, ..Default::default() }).unwrap();
                prop_assert_eq!(&load_volume(&p, None).unwrap(), &v);
            }
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
}

#[test]
fn nrrd_byte_skip_counts_decoded_bytes() {
    let dir = scratch("skip");
    let floats: Vec<u8> = [1.5f32, -2.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 1 1\nendian: little\n";
    // Raw: skip 3 junk bytes, or take the last 8 bytes.
    let mut junk = vec![9u8, 9, 9];
    junk.extend_from_slice(&floats);
    let p = nrrd_with(
        &dir,
        "s3.nrrd",
        &format!("{head}encoding: raw\nbyte skip: 3\n\n"),
        &junk,
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![1.5, -2.0]);
    let p = nrrd_with(
        &dir,
        "tail.nrrd",
        &format!("{head}encoding: raw\nbyte skip: -1\n\n"),
        &junk,
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![1.5, -2.0]);
    // Gzip: the skip applies after decompression.
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    enc.write_all(&junk).unwrap();
    let gz = enc.finish().unwrap();
    let p = nrrd_with(
        &dir,
        "gz.nrrd",
        &format!("{head}encoding: gzip\nbyte skip: 3\n\n"),
        &gz,
    );
    assert_eq!(read_nrrd(&p).unwrap().values, vec![1.5, -2.0]);
    let p = nrrd_with(
        &dir,
        "gzneg.nrrd",
        &format!("{head}encoding: gzip\nbyte skip: -1\n\n"),
        &gz,
    );
    assert!(read_nrrd(&p)
        .unwrap_err()
        .to_string()
        .contains("byte skip -1"));
}

/// A gzip NRRD is inflated only as far as its header's sizes: sizes no stream of its length
/// could hold are refused before inflating (a header claiming 2³¹ floats used to be read to
/// the end of its stream into a buffer of that capacity), and a stream longer than the sizes
/// is refused, naming what they need.
#[test]
fn gzip_nrrd_is_inflated_only_as_far_as_its_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let gz = |data: &[u8]| {
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        enc.write_all(data).unwrap();
        enc.finish().unwrap()
    };
    let head = |sizes: &str| {
        format!("NRRD0004\ntype: float\ndimension: 3\nsizes: {sizes}\nendian: little\nencoding: gzip\n\n")
    };
    let p = nrrd_with(
        dir.path(),
        "huge.nrrd",
        &head("2048 1024 1024"),
        &gz(&[0u8; 64]),
    );
    let err = read_nrrd(&p).unwrap_err().to_string();
    assert!(err.contains("more than a gzip stream"), "{err}");
    // 8 MB of zeros (about 8 KB compressed) behind sizes of 2 floats.
    let p = nrrd_with(
        dir.path(),
        "long.nrrd",
        &head("2 1 1"),
        &gz(&vec![0u8; 8 << 20]),
    );
    let err = read_nrrd(&p).unwrap_err().to_string();
    assert!(err.contains("more than the 8 bytes"), "{err}");
    let p = nrrd_with(dir.path(), "ok.nrrd", &head("2 1 1"), &gz(&[0u8; 8]));
    assert_eq!(read_nrrd(&p).unwrap().values, vec![0.0, 0.0]);
}

/// A FIFO, a directory or a device named as a volume — in every format, and as the detached
/// data file of an `.nhdr` — is refused at once, naming the path and what it is; reading a
/// FIFO would otherwise block forever (the reads run on a thread the test stops waiting for).
#[cfg(unix)]
#[test]
fn only_regular_files_are_read_as_volumes() {
    use std::sync::mpsc;
    use std::time::Duration;
    let dir = scratch("fifo");
    let mkfifo = |p: &std::path::Path| {
        let made = std::process::Command::new("mkfifo")
            .arg(p)
            .status()
            .unwrap();
        assert!(made.success(), "mkfifo {}", p.display());
    };
    let names = [
        "density.f32",
        "density.vol",
        "density.nrrd",
        "density.nii",
        "density.nii.gz",
        "density.vdb",
    ];
    // (path to load, path the error must name, what it is)
    let mut cases = Vec::new();
    for name in names {
        let fifo = dir.join(format!("fifo-{name}"));
        mkfifo(&fifo);
        cases.push((fifo.clone(), fifo, "is a FIFO, not a regular file"));
        let folder = dir.join(format!("folder-{name}"));
        std::fs::create_dir(&folder).unwrap();
        cases.push((folder.clone(), folder, "is a directory, not a regular file"));
    }
    // A detached NRRD header whose data file is a FIFO, then one whose data file is a folder.
    for (data, what) in [
        ("data-fifo.raw", "is a FIFO, not a regular file"),
        ("data-folder.raw", "is a directory, not a regular file"),
    ] {
        let target = dir.join(data);
        if data.contains("fifo") {
            mkfifo(&target);
        } else {
            std::fs::create_dir(&target).unwrap();
        }
        let header = dir.join(format!("{data}.nhdr"));
        std::fs::write(
            &header,
            format!(
                "NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nendian: little\n\
                 encoding: raw\ndata file: {data}\n"
            ),
        )
        .unwrap();
        cases.push((header, target, what));
    }
    cases.push((
        "/dev/null".into(),
        "/dev/null".into(),
        "is a character device, not a regular file",
    ));
    let count = cases.len();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for (load, named, what) in cases {
            let result = load_volume(&load, Some([1, 1, 1])).map(|_| ());
            let _ = tx.send((load, named, what, result));
        }
    });
    for _ in 0..count {
        let (load, named, what, result) = rx
            .recv_timeout(Duration::from_secs(10))
            .expect("refused at once, not blocked reading a FIFO");
        let err = result
            .expect_err(&format!("{} is not a volume", load.display()))
            .to_string();
        assert_eq!(
            err,
            format!("{}: {what}", named.display()),
            "{}",
            load.display()
        );
    }
}

/// Bytes received without a file name (an upload) are told apart by their magic numbers, as
/// the extension tells files apart: every format's sample sniffs as the format its name says,
/// with the suffix that name ends in, and reads back within a cell cap; a cap below the
/// volume's cells is refused.
#[test]
fn bytes_are_recognised_by_magic_number_and_read_under_a_cap() {
    use medium::volume_io::{read_volume_bytes_capped, VolumeFormat};
    let dir = scratch("sniff");
    let data = sample();
    write_nrrd(&dir.join("v.nrrd"), &data, &NrrdWriteOptions::default()).unwrap();
    write_mitsuba_vol(&dir.join("v.vol"), &data, 1.0).unwrap();
    write_raw_f32(&dir.join("v.f32"), &data).unwrap();
    let tests = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let files = [
        dir.join("v.nrrd"),
        dir.join("v.vol"),
        tests.join("vdb/blosc.vdb"),
        tests.join("nifti/float32.nii"),
        tests.join("nifti/float32_gz.nii.gz"),
    ];
    for path in &files {
        let bytes = std::fs::read(path).unwrap();
        let format = VolumeFormat::sniff(&bytes).unwrap_or_else(|| panic!("{path:?}"));
        assert_eq!(format, VolumeFormat::from_path(path), "{path:?}");
        let name = path.file_name().unwrap().to_str().unwrap();
        assert!(
            name.ends_with(&format!(".{}", format.extension(&bytes))),
            "{name}"
        );
        let read = read_volume_bytes_capped(&bytes, format, path, 1 << 20).unwrap();
        let cells: usize = read.dims.iter().product();
        assert_eq!(read.values.len(), cells);
        let err = read_volume_bytes_capped(&bytes, format, path, cells as u64 - 1).unwrap_err();
        // The message names the cap.
        assert!(
            err.to_string().contains(&(cells - 1).to_string()),
            "{name}: {err}"
        );
    }
    // Raw f32 has no magic number.
    assert_eq!(
        VolumeFormat::sniff(&std::fs::read(dir.join("v.f32")).unwrap()),
        None
    );
}
