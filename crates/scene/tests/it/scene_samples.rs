//! The sample scenes in data/ load and say what their comments promise.

use std::path::PathBuf;

use medium::PhaseFunction;
use scene::Scene;
use scene::{OpticalModel, SolveMethod, VolumeSource};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(name)
}

#[test]
fn cloud_sample_is_an_optically_thick_generated_cloud() {
    let s = Scene::from_file(&data("cloud.toml")).unwrap();
    assert!(matches!(s.source, VolumeSource::Generator(_)));
    assert_eq!(s.medium.grid().dims, [64, 64, 48]);
    let depth = s.medium.max_axis_optical_depth();
    assert!((depth - 10.0).abs() < 0.5, "optical depth {depth}");
    assert_eq!(s.solve.method, SolveMethod::ZonalHierarchical);
    assert_eq!(s.cameras.len(), 2);
}

#[test]
fn dipole_sample_uses_blasi_two_lobe_phase_and_a_sigma_table() {
    let s = Scene::from_file(&data("dipole.toml")).unwrap();
    assert_eq!(
        s.medium.phase(),
        PhaseFunction::TwoLobe {
            r: 0.12,
            g1: -0.5,
            g2: 0.7
        }
    );
    assert_eq!(s.solve.method, SolveMethod::DiscreteOrdinates);
    // The table makes a haze: a good part of the grid has some extinction, none is negative.
    let sigma = &s.medium.channels()[0].sigma_t;
    let hazy = sigma.iter().filter(|&&x| x > 0.0).count() as f64 / sigma.len() as f64;
    assert!((0.1..0.9).contains(&hazy), "{hazy}");
}

#[test]
fn smoke_sample_is_rgb_particle_emission_without_lights() {
    let path = data("smoke-emission.toml");
    let s = Scene::from_file(&path).unwrap();
    assert!(s.lights.is_empty());
    assert_eq!(s.medium.channels().len(), 3);
    assert_eq!(s.render.model, OpticalModel::EmissionAbsorption);
    assert_eq!(s.solve.method, SolveMethod::None);
    let ch = &s.medium.channels()[1];
    let cell = ch.sigma_t.iter().position(|&x| x > 0.1).unwrap();
    assert!((ch.emission.get(cell) - 0.55 * ch.sigma_t[cell]).abs() < 1e-6);
    let size = std::fs::metadata(data("smoke32.nrrd")).unwrap().len();
    assert!(size < 200_000, "{size}");
}

/// cloud24.vdb holds cloud24.f32's values: the grid is their non-zero box, value for value.
#[test]
fn vdb_sample_is_cloud24_over_its_active_box() {
    let s = Scene::from_file(&data("cloud-vdb.toml")).unwrap();
    let p = s.volume_placement().unwrap().clone();
    assert_eq!((p.grid.as_str(), p.bbox_min), ("density", [0, 4, 2]));
    let [nx, ny, nz] = s.medium.grid().dims;
    assert_eq!([nx, ny, nz], [22, 16, 14]);
    let raw = medium::volume_io::read_raw_f32(&data("cloud24.f32"), [24, 24, 18]).unwrap();
    let got = s.medium.data().unwrap();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let [x, y, z] = [i, j + 4, k + 2];
                let want = raw.values[x + 24 * (y + 24 * z)];
                assert_eq!(got[i + nx * (j + ny * k)], want, "({x}, {y}, {z})");
            }
        }
    }
    // Nothing non-zero is left outside the box.
    let inside = raw.values.iter().filter(|&&v| v != 0.0).count();
    assert_eq!(got.iter().filter(|&&v| v != 0.0).count(), inside);
    let size = std::fs::metadata(data("cloud24.vdb")).unwrap().len();
    assert!(size < 200_000, "{size}");
}

/// fire.toml: three-channel blackbody emission, hot (yellow-white) in the dense core and
/// red and far dimmer at the edges.
#[test]
fn fire_sample_glows_hotter_in_its_core() {
    let s = Scene::from_file(&data("fire.toml")).unwrap();
    assert!(s.lights.is_empty());
    let ch = s.medium.channels();
    assert_eq!(ch.len(), 3);
    let data = s.volume_data().unwrap().values;
    let core = (0..data.len())
        .max_by(|&a, &b| data[a].total_cmp(&data[b]))
        .unwrap();
    let edge = (0..data.len())
        .filter(|&i| data[i] > 0.05 && data[i] < 0.2)
        .min_by(|&a, &b| data[a].total_cmp(&data[b]))
        .unwrap();
    let per_sigma = |c: usize, i: usize| ch[c].emission.get(i) / ch[c].sigma_t[i];
    // Red over green: redder at the cool edge than in the hot core; both red-dominated.
    let core_rg = per_sigma(0, core) / per_sigma(1, core);
    let edge_rg = per_sigma(0, edge) / per_sigma(1, edge);
    assert!(core_rg > 1.0 && edge_rg > core_rg, "{core_rg} {edge_rg}");
    // 1800 K against 1230–1320 K: Planck luminance falls 140- to 520-fold (green a bit more).
    assert!(per_sigma(1, core) > 100.0 * per_sigma(1, edge));
}
