//! OpenVDB input against files written by the OpenVDB library itself
//! (`tests/data/vdb/make_vdb.py`): every value bit for bit, the active box and the transform;
//! and bad input (arbitrary bytes, mutated files) refused without a panic.

use std::path::{Path, PathBuf};
use std::process::Command;

use medium::vdb::{read_vdb, read_vdb_bytes, read_vdb_bytes_capped, VdbVolume};
use medium::volume_io::{load_volume, load_volume_with, VolumeFormat, VolumeRequest};
use proptest::prelude::*;
use serde_json::Value;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/vdb")
}

/// Checks every grid a manifest (`NAME.json`) lists; returns how many values were compared.
fn check_manifest(dir: &Path, manifest: &Path) -> usize {
    let m: Value = serde_json::from_slice(&std::fs::read(manifest).unwrap()).unwrap();
    let file = dir.join(m["file"].as_str().unwrap());
    let mut compared = 0;
    for g in m["grids"].as_array().unwrap() {
        let name = g["name"].as_str().unwrap();
        let v: VdbVolume =
            read_vdb(&file, Some(name)).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let ints = |k: &str| -> Vec<i64> {
            g[k].as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_i64().unwrap())
                .collect()
        };
        let floats = |k: &str| -> Vec<f64> {
            g[k].as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        let ctx = format!("{} grid {name}", file.display());
        let p = &v.placement;
        assert_eq!(p.grid, name);
        assert_eq!(
            v.data.dims.map(|d| d as i64).to_vec(),
            ints("dims"),
            "{ctx}"
        );
        assert_eq!(
            p.bbox_min.map(i64::from).to_vec(),
            ints("bbox_min"),
            "{ctx}"
        );
        assert_eq!(
            p.bbox_max.map(i64::from).to_vec(),
            ints("bbox_max"),
            "{ctx}"
        );
        assert_eq!(p.voxel_size.to_vec(), floats("voxel_size"), "{ctx}");
        assert_eq!(p.translation.to_vec(), floats("translation"), "{ctx}");
        let raw = std::fs::read(dir.join(g["values"].as_str().unwrap())).unwrap();
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
        compared += expected.len();
    }
    compared
}

fn manifests(dir: &Path) -> Vec<PathBuf> {
    let mut m: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    m.sort();
    m
}

/// The committed files: float, half, double, zip, Blosc, uncompressed; tiles; two grids;
/// negative coordinates; every transform the script writes; every mask-compression mode.
#[test]
fn files_written_by_openvdb_read_exactly() {
    let dir = data_dir();
    let all = manifests(&dir);
    let names: Vec<String> = all
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    for want in [
        "float_negative",
        "half",
        "scale_translate",
        "nonuniform",
        "tiles",
        "multi",
        "mask_modes",
        "zip",
        "uncompressed",
        "double",
        "double_zip",
        "blosc",
        "instance",
    ] {
        assert!(names.iter().any(|n| n == want), "missing case {want}");
    }
    let mut total = 0;
    for m in &all {
        total += check_manifest(&dir, m);
    }
    assert!(total > 20_000, "{total} values compared");
}

/// The same script on a fresh seed, through the library installed on this machine (CI
/// installs python3-openvdb first), plus a 128³ active tile of an internal node (too large to
/// commit): fails, naming what is missing, when it cannot run.
#[test]
fn fresh_files_from_the_openvdb_library_round_trip() {
    let python = std::env::var("VOLRAD_PYTHON").unwrap_or_else(|_| {
        // Debian's binding is built for Debian's interpreter, which may not be the first
        // python3 on PATH (pyenv, venvs).
        if Path::new("/usr/bin/python3").exists() {
            "/usr/bin/python3".into()
        } else {
            "python3".into()
        }
    });
    let out = tempfile::tempdir().unwrap();
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos()
        % 1_000_000;
    let run = Command::new(&python)
        .arg(data_dir().join("make_vdb.py"))
        .arg(out.path())
        .args(["--quick", "--large", "--seed", &seed.to_string()])
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run {python} (install python3-openvdb python3-numpy, as .ci/run does): {e}"
            )
        });
    assert!(
        run.status.success(),
        "make_vdb.py --seed {seed} failed (install python3-openvdb python3-numpy, as .ci/run does; VOLRAD_PYTHON picks the interpreter):\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let all = manifests(out.path());
    assert!(all.len() >= 9, "{} manifests", all.len());
    assert!(all.iter().any(|m| m.ends_with("node5_tile.json")));
    for m in &all {
        assert!(
            check_manifest(out.path(), m) > 0,
            "seed {seed}: {}",
            m.display()
        );
    }
    // Files other programs wrote (too large, or not ours, to commit), when given:
    // `VOLRAD_REAL_VDB=smoke.vdb:sphere.vdb` (docs/reliability.md lists the ones checked).
    let real = std::env::var("VOLRAD_REAL_VDB").unwrap_or_default();
    for file in real.split(':').filter(|f| !f.is_empty()) {
        let dir = tempfile::tempdir().unwrap();
        let run = Command::new(&python)
            .arg(data_dir().join("make_vdb.py"))
            .args(["--describe", file])
            .arg(dir.path())
            .output()
            .unwrap();
        assert!(
            run.status.success(),
            "make_vdb.py --describe {file}:\n{}",
            String::from_utf8_lossy(&run.stderr)
        );
        for m in manifests(dir.path()) {
            let compared = check_manifest(dir.path(), &m);
            assert!(compared > 0, "{file}");
            eprintln!("{file}: {compared} values agree bit for bit");
        }
    }
}

#[test]
fn grid_choice_and_its_errors() {
    let multi = data_dir().join("multi.vdb");
    assert_eq!(VolumeFormat::from_path(&multi), VolumeFormat::OpenVdb);
    // Default: the first float grid.
    let first = load_volume_with(&multi, &VolumeRequest::default()).unwrap();
    assert_eq!(first.placement.unwrap().grid, "density");
    let t = load_volume_with(
        &multi,
        &VolumeRequest {
            dims: Some([8, 8, 16]),
            grid: Some("temperature"),
        },
    )
    .unwrap();
    assert_eq!(t.data.dims, [8, 8, 16]);
    let err = read_vdb(&multi, Some("flames")).unwrap_err().to_string();
    assert!(
        err.contains("multi.vdb") && err.contains("no grid named `flames`"),
        "{err}"
    );
    assert!(
        err.contains("`density`") && err.contains("`temperature`"),
        "{err}"
    );
    let err = load_volume(&multi, Some([1, 2, 3]))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("[12, 10, 9]") && err.contains("[1, 2, 3]"),
        "{err}"
    );
    let nrrd = data_dir().join("x.nrrd");
    let err = load_volume_with(
        &nrrd,
        &VolumeRequest {
            dims: None,
            grid: Some("density"),
        },
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("OpenVDB"), "{err}");
}

#[test]
fn placement_of_a_translated_grid() {
    let v = read_vdb(&data_dir().join("scale_translate.vdb"), None).unwrap();
    let p = &v.placement;
    assert_eq!(p.uniform_voxel_size(), Some(0.5));
    // Voxel bbox_min's centre is translation + 0.5 · bbox_min; its corner half a voxel lower.
    for (a, corner) in p.world_corner().into_iter().enumerate() {
        let centre = p.translation[a] + 0.5 * p.bbox_min[a] as f64;
        assert_eq!(corner, centre - 0.25);
    }
    let n = read_vdb(&data_dir().join("nonuniform.vdb"), None).unwrap();
    assert_eq!(n.placement.uniform_voxel_size(), None);
}

/// OpenVDB simplifies an axis-aligned affine matrix to a scale map when it builds a transform,
/// so its writer never stores one; other writers may. The rotated file's AffineMap is
/// refused; with its matrix replaced by a scale and translation it is read.
#[test]
fn affine_maps_axis_aligned_or_refused() {
    let path = data_dir().join("rotated.vdb");
    let err = read_vdb(&path, None).unwrap_err().to_string();
    assert!(err.contains("rotated.vdb: the AffineMap rotates"), "{err}");
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes
        .windows(9)
        .position(|w| w == b"AffineMap")
        .expect("the map type is stored")
        + 9;
    let m = [
        0.5, 0.0, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 1.5, -3.0, 0.0, 1.0f64,
    ];
    for (n, v) in m.iter().enumerate() {
        bytes[at + 8 * n..at + 8 * n + 8].copy_from_slice(&v.to_le_bytes());
    }
    let v = read_vdb_bytes(&bytes, &path, None).unwrap();
    assert_eq!(v.placement.map, "AffineMap");
    assert_eq!(v.placement.voxel_size, [0.5, 0.25, 2.0]);
    assert_eq!(v.placement.translation, [1.5, -3.0, 0.0]);
    assert_eq!(v.data.dims, [2, 2, 2]);
    assert!(v.data.values.iter().all(|&x| x == 1.0));
    // A negative scale mirrors the grid: refused.
    bytes[at..at + 8].copy_from_slice(&(-0.5f64).to_le_bytes());
    let err = read_vdb_bytes(&bytes, &path, None).unwrap_err().to_string();
    assert!(err.contains("no mirroring"), "{err}");
}

fn valid_files() -> Vec<Vec<u8>> {
    ["multi", "half", "double_zip", "uncompressed", "tiles"]
        .iter()
        .map(|n| std::fs::read(data_dir().join(format!("{n}.vdb"))).unwrap())
        .collect()
}

/// A box beyond the cap is refused before anything is allocated for it.
#[test]
fn oversized_boxes_are_refused() {
    let bytes = std::fs::read(data_dir().join("tiles.vdb")).unwrap();
    let err = read_vdb_bytes_capped(&bytes, Path::new("t.vdb"), None, 1000)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("t.vdb: grid `density`") && err.contains("at most 1000"),
        "{err}"
    );
}

#[test]
fn truncated_files_are_refused_naming_the_file() {
    let path = Path::new("cut.vdb");
    for bytes in valid_files() {
        for cut in [0, 7, 8, 12, 30, 100, bytes.len() / 3, bytes.len() - 1] {
            let err = read_vdb_bytes(&bytes[..cut], path, None)
                .unwrap_err()
                .to_string();
            assert!(err.starts_with("cut.vdb: "), "{err}");
        }
    }
    let mut old = valid_files().remove(0);
    old[8..12].copy_from_slice(&221u32.to_le_bytes());
    let err = read_vdb_bytes(&old, path, None).unwrap_err().to_string();
    assert!(err.contains("version 221"), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// Arbitrary bytes behind a valid magic and version: an error, never a panic.
    #[test]
    fn arbitrary_bytes_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..2048),
                                   version in 220u32..227) {
        let mut bytes = 0x5644_4220i64.to_le_bytes().to_vec();
        bytes.extend_from_slice(&version.to_le_bytes());
        bytes.extend_from_slice(&tail);
        let _ = read_vdb_bytes_capped(&bytes, Path::new("fuzz.vdb"), None, 1 << 22);
        let _ = read_vdb_bytes_capped(&tail, Path::new("fuzz.vdb"), Some("density"), 1 << 22);
    }

    /// Valid files with a few bytes changed: Ok or Err, never a panic, abort or hang. (The
    /// dense box is capped lower than in use, so a mutated coordinate cannot ask for GiBs.)
    #[test]
    fn mutated_files_never_panic(which in 0usize..5,
                                 edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let mut bytes = valid_files().swap_remove(which);
        for (at, b) in &edits {
            let i = at.index(bytes.len());
            bytes[i] = *b;
        }
        if let Ok(v) = read_vdb_bytes_capped(&bytes, Path::new("mutated.vdb"), None, 1 << 22) {
            let cells: usize = v.data.dims.iter().product();
            prop_assert_eq!(cells, v.data.values.len());
        }
    }
}
