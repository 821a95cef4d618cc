//! `[volume] interpolation` (issue 24, "images are blocky"): a scene that does not say is drawn
//! `trilinear` — the solved field reconstructed smoothly between cell centres — and only a
//! scene that asks for `nearest` shows its cells. The solve is the same either way.

use std::path::Path;

use gather::Image;
use medium::volume_io::VolumeData;
use medium::Interpolation;
use scene::Scene;
use volrad::engine::pipeline::{render_view, scene_hash, solve_scene};
use volrad::engine::solution::Solution;
use volrad::engine::SolveHooks;

/// 4×4×4 cells of smooth data — σt a linear ramp, 0.1 to 0.55 along x and gentler along y
/// and z, optically thin — with albedo 0.9, lit from above, solved by the zonal method; `line`
/// goes into `[volume]`. The camera looks along +z at the middle of the grid from close by:
/// 2×2 cells fill the frame, 32 pixels per cell, with cell faces at the middle row and column.
fn ramp(line: &str) -> Scene {
    let dims = [4, 4, 4];
    let values = (0..64)
        .map(|c| {
            let (i, j, k) = (c % 4, (c / 4) % 4, c / 16);
            0.1 + 0.15 * i as f32 + 0.03 * j as f32 + 0.02 * k as f32
        })
        .collect();
    let text = format!(
        r#"
[volume]
cell_size = 1.0
{line}

[medium]
albedo = 0.9
phase = {{ kind = "isotropic" }}

[[light]]
kind = "directional"
direction = [0.2, -1.0, 0.1]
irradiance = 1.0

[solve]
method = "zonal"
tolerance = 1e-6

[[camera]]
name = "close"
projection = "orthographic"
ortho_height = 2.0
eye = [2.0, 2.0, -10.0]
target = [2.0, 2.0, 2.0]
up = [0.0, 1.0, 0.0]
width = 64
height = 64
"#
    );
    Scene::with_volume_data(
        &text,
        VolumeData::new(dims, values).unwrap(),
        Path::new("."),
        Path::new("ramp.toml"),
    )
    .unwrap()
}

fn solve(scene: &Scene) -> Solution {
    solve_scene(scene, &scene.solve, &SolveHooks::default()).unwrap()
}

fn render(solution: &Solution) -> Image {
    render_view(solution, &solution.cameras[0], None).unwrap()
}

/// Largest jump between horizontally neighbouring pixels of row `y` across the cell face at
/// the middle column, and the largest anywhere else in the row, both over the row's range.
fn jumps(image: &Image, y: u32) -> (f64, f64) {
    let row: Vec<f64> = (0..image.width)
        .map(|x| image.get(x, y, 0) as f64)
        .collect();
    let range =
        row.iter().cloned().fold(f64::MIN, f64::max) - row.iter().cloned().fold(f64::MAX, f64::min);
    assert!(range > 0.0, "row {y} is flat");
    let face = image.width as usize / 2 - 1;
    let (mut at_face, mut elsewhere) = (0.0f64, 0.0f64);
    for x in 0..row.len() - 1 {
        let jump = (row[x + 1] - row[x]).abs() / range;
        if x == face {
            at_face = at_face.max(jump);
        } else {
            elsewhere = elsewhere.max(jump);
        }
    }
    (at_face, elsewhere)
}

/// A scene without the key renders bit for bit as one that says `trilinear`, is the same
/// scene (hash) and not the `nearest` one, whose picture differs; the solved field is the
/// same for all three (the solvers see the piecewise-constant medium whatever the look).
#[test]
fn a_scene_that_does_not_say_is_drawn_trilinear() {
    let default = ramp("");
    let trilinear = ramp(r#"interpolation = "trilinear""#);
    let nearest = ramp(r#"interpolation = "nearest""#);
    assert_eq!(default.medium.interpolation(), Interpolation::Trilinear);
    assert_eq!(nearest.medium.interpolation(), Interpolation::Nearest);
    assert_eq!(scene_hash(&default), scene_hash(&trilinear));
    assert_ne!(scene_hash(&default), scene_hash(&nearest));

    let (d, t, n) = (solve(&default), solve(&trilinear), solve(&nearest));
    assert_eq!(d.channels[0].scattered, n.channels[0].scattered);
    assert_eq!(d.channels[0].light_pass, n.channels[0].light_pass);
    assert_eq!(d.channels[0].scattered, t.channels[0].scattered);

    let (di, ti, ni) = (render(&d), render(&t), render(&n));
    assert_eq!(di.pixels, ti.pixels, "default vs explicit trilinear");
    let differ = di
        .pixels
        .iter()
        .zip(&ni.pixels)
        .filter(|(a, b)| a != b)
        .count();
    println!(
        "default vs nearest: {differ} of {} pixels differ",
        di.pixels.len()
    );
    assert!(differ > di.pixels.len() / 2, "{differ} pixels differ");
}

/// A close-up of smooth data on coarse cells: with `nearest` the cell face at the middle column
/// is a step (measured: the whole of the row's range, 14× any other neighbour-pixel jump); with
/// the default the picture is continuous there (0.1–0.4 % of the range, below the slope's
/// 5–7 % elsewhere in the row).
#[test]
fn a_close_up_of_blocky_cells_is_smooth_unless_the_scene_asks_for_nearest() {
    let smooth = render(&solve(&ramp("")));
    let blocky = render(&solve(&ramp(r#"interpolation = "nearest""#)));
    // Rows a quarter and three quarters of the way down: the middle of a cell's footprint.
    for y in [16, 48] {
        let (face_n, else_n) = jumps(&blocky, y);
        let (face_t, else_t) = jumps(&smooth, y);
        println!(
            "row {y}: nearest face {face_n:.4} elsewhere {else_n:.4}; \
             default face {face_t:.4} elsewhere {else_t:.4}"
        );
        assert!(face_n > 0.5, "nearest: the face is a step ({face_n})");
        assert!(face_n > 5.0 * else_n, "nearest: {face_n} vs {else_n}");
        assert!(face_t < 0.1, "default: no step at the face ({face_t})");
        assert!(face_t <= 2.0 * else_t.max(1e-3), "{face_t} vs {else_t}");
    }
}
