//! NIfTI input against files written by nibabel (`tests/data/nifti/make_nifti.py`): every
//! value bit for bit after scl_slope/scl_inter, dims, pixdim, byte order and version; and bad
//! input (arbitrary bytes, mutated and truncated files) refused without a panic.

use std::path::{Path, PathBuf};

use medium::nifti::{read_nifti, read_nifti_bytes, read_nifti_bytes_capped, NiftiVolume};
use medium::volume_io::{load_volume_with, VolumeFormat, VolumeRequest};
use proptest::prelude::*;
use serde_json::Value;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/nifti")
}

fn manifests() -> Vec<PathBuf> {
    let mut m: Vec<PathBuf> = std::fs::read_dir(data_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    m.sort();
    m
}

fn manifest(path: &Path) -> (Value, PathBuf) {
    let m: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let file = data_dir().join(m["file"].as_str().unwrap());
    (m, file)
}

/// Checks one file against nibabel's reading of it; returns how many values were compared.
fn check(json: &Path) -> usize {
    let (m, file) = manifest(json);
    let v: NiftiVolume = read_nifti(&file).unwrap_or_else(|e| panic!("{e}"));
    let ctx = file.display().to_string();
    let h = &v.header;
    let dims: Vec<u64> = m["dims"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect();
    assert_eq!(v.data.dims.map(|d| d as u64).to_vec(), dims, "{ctx}");
    let pixdim: Vec<f64> = m["pixdim"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(h.pixdim.to_vec(), pixdim, "{ctx}");
    assert_eq!(h.big_endian, m["big_endian"].as_bool().unwrap(), "{ctx}");
    assert_eq!(
        u64::from(h.version),
        m["nifti_version"].as_u64().unwrap(),
        "{ctx}"
    );
    assert_eq!(h.vox_offset, m["vox_offset"].as_u64().unwrap(), "{ctx}");
    assert_eq!(h.scl_slope, m["scl_slope"].as_f64().unwrap(), "{ctx}");
    assert_eq!(h.scl_inter, m["scl_inter"].as_f64().unwrap(), "{ctx}");
    let stem = json.file_stem().unwrap().to_string_lossy();
    let raw = std::fs::read(data_dir().join(format!("{stem}.f32"))).unwrap();
    let expected: Vec<u32> = raw
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    assert_eq!(v.data.values.len(), expected.len(), "{ctx}");
    for (i, (a, &e)) in v.data.values.iter().zip(&expected).enumerate() {
        assert_eq!(
            a.to_bits(),
            e,
            "{ctx}: value {i}: {a} vs {}",
            f32::from_bits(e)
        );
    }
    expected.len()
}

/// Every committed case, each value exactly as nibabel reads it.
#[test]
fn files_written_by_nibabel_read_exactly() {
    let all = manifests();
    let names: Vec<String> = all
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    for want in [
        "float32",
        "int16_scaled",
        "uint8",
        "float64",
        "float32_big",
        "uint16_big_scaled",
        "float32_gz",
        "nonuniform",
        "int8_4d",
        "int32_nifti2",
        "uint32_nifti2_big_gz",
    ] {
        assert!(names.iter().any(|n| n == want), "missing case {want}");
    }
    let total: usize = all.iter().map(|m| check(m)).sum();
    assert_eq!(total, 11 * 7 * 5 * 4);
}

/// The scaled cases really are scaled (a reader ignoring scl_slope would fail the exact
/// comparison above, and this guards against the script silently writing slope 1).
#[test]
fn scaled_cases_carry_a_slope_and_intercept() {
    for stem in ["int16_scaled", "uint16_big_scaled"] {
        let (_, file) = manifest(&data_dir().join(format!("{stem}.json")));
        let h = read_nifti(&file).unwrap().header;
        assert!(h.scl_slope != 0.0 && h.scl_slope != 1.0, "{stem}: {h:?}");
        assert!(h.scl_inter != 0.0, "{stem}: {h:?}");
    }
}

/// `load_volume_with` picks NIfTI by name (`.nii`, `.nii.gz`, any case) and returns pixdim.
#[test]
fn load_volume_returns_the_voxel_spacing() {
    assert_eq!(
        VolumeFormat::from_path(Path::new("a/B.NII.GZ")),
        VolumeFormat::Nifti
    );
    assert_eq!(
        VolumeFormat::from_path(Path::new("b.nii")),
        VolumeFormat::Nifti
    );
    assert_eq!(
        VolumeFormat::from_path(Path::new("b.gz")),
        VolumeFormat::RawF32
    );
    let req = VolumeRequest::default();
    let v = load_volume_with(&data_dir().join("float32_gz.nii.gz"), &req).unwrap();
    assert_eq!(v.voxel_size, Some([0.5; 3]));
    assert_eq!(v.data.dims, [7, 5, 4]);
    assert!(v.placement.is_none());
    let n = load_volume_with(&data_dir().join("nonuniform.nii"), &req).unwrap();
    assert_eq!(n.voxel_size, Some([0.7f32 as f64, 0.7f32 as f64, 2.5]));
    let wrong = VolumeRequest {
        dims: Some([5, 7, 4]),
        grid: None,
    };
    let e = load_volume_with(&data_dir().join("uint8.nii"), &wrong).unwrap_err();
    assert!(e.to_string().contains("[7, 5, 4]"), "{e}");
    let grid = VolumeRequest {
        dims: None,
        grid: Some("density"),
    };
    assert!(load_volume_with(&data_dir().join("uint8.nii"), &grid).is_err());
}

fn valid_files() -> Vec<Vec<u8>> {
    manifests()
        .iter()
        .map(|m| std::fs::read(manifest(m).1).unwrap())
        .collect()
}

/// Every strict prefix of every file (compressed or not) is refused, with the file named.
#[test]
fn truncated_files_are_refused() {
    for bytes in valid_files() {
        for len in 0..bytes.len() {
            let e = read_nifti_bytes(&bytes[..len], Path::new("cut.nii"))
                .expect_err(&format!("{len} of {} bytes accepted", bytes.len()));
            let text = e.to_string();
            assert!(text.starts_with("cut.nii: "), "{text}");
            assert!(!text.contains('\n'), "{text}");
        }
    }
}

/// A header that asks for far more data than a small gzip stream can hold is refused
/// without inflating it; the same for an uncompressed file.
#[test]
fn oversized_headers_are_refused_before_reading() {
    let mut bytes = std::fs::read(data_dir().join("uint8.nii")).unwrap();
    // dim[1..=3] = 2000 × 2000 × 1000: 4·10^9 cells, under volrad's 2^32 limit.
    for (i, d) in [2000i16, 2000, 1000].iter().enumerate() {
        bytes[42 + 2 * i..44 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    let e = read_nifti_bytes(&bytes, Path::new("big.nii")).unwrap_err();
    assert!(e.to_string().contains("truncated"), "{e}");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut gz, &bytes).unwrap();
    let gz = gz.finish().unwrap();
    let e = read_nifti_bytes(&gz, Path::new("big.nii.gz")).unwrap_err();
    assert!(e.to_string().contains("cannot hold"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Arbitrary bytes, bare or behind a valid sizeof_hdr in either order: never a panic.
    #[test]
    fn arbitrary_bytes_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..1200),
                                   big in any::<bool>(), v2 in any::<bool>()) {
        let size: i32 = if v2 { 540 } else { 348 };
        let mut bytes = if big { size.to_be_bytes() } else { size.to_le_bytes() }.to_vec();
        bytes.extend_from_slice(&tail);
        prop_assert!(read_nifti_bytes_capped(&bytes, Path::new("fuzz.nii"), 1 << 22).is_err()
            || bytes.len() >= 348);
        let _ = read_nifti_bytes_capped(&tail, Path::new("fuzz.nii"), 1 << 22);
    }

    /// Valid files (gzip ones too) with a few bytes changed: Ok with consistent sizes, or
    /// Err, never a panic, abort or hang.
    #[test]
    fn mutated_files_never_panic(which in 0usize..11,
                                 edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let mut bytes = valid_files().swap_remove(which);
        for (at, b) in &edits {
            let i = at.index(bytes.len());
            bytes[i] = *b;
        }
        if let Ok(v) = read_nifti_bytes_capped(&bytes, Path::new("mutated.nii"), 1 << 22) {
            let cells: usize = v.data.dims.iter().product();
            prop_assert_eq!(cells, v.data.values.len());
        }
    }
}
