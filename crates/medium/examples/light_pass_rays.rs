//! How the directional light pass's cell averages depend on the rays per cell face `m`:
//! extinction-weighted relative L1 and worst-cell error of `cell_irradiance` against m = 16.
//! `cargo run --release -p medium --example light_pass_rays [sigma_scale]`
use glam::DVec3;
use medium::generators::cloud;
use medium::light_pass::{LightPass, LightPassOptions};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};

fn main() {
    let scale: f32 = std::env::args().nth(1).map_or(0.6, |s| s.parse().unwrap());
    let dims = [64, 64, 48];
    let grid = Grid::new(dims, 1.0).unwrap();
    let medium = Medium::new(
        grid,
        vec![ChannelMedium {
            sigma_t: cloud(dims, 7).iter().map(|d| d * scale).collect(),
            albedo: CellValues::Uniform(0.99),
            emission: CellValues::Uniform(0.0),
        }],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let channel = &medium.channels()[0];
    let light = [Light::Directional {
        direction: DVec3::new(0.5, -1.0, 0.35),
        irradiance: 1.0,
    }];
    let pass = |m: usize| {
        let opts = LightPassOptions {
            rays_per_cell: m,
            ..Default::default()
        };
        LightPass::compute_with(&medium, 0, &light, &opts).unwrap()
    };
    let reference = pass(16);
    for m in [1, 2, 3, 4, 8] {
        let p = pass(m);
        let (mut err, mut total, mut worst) = (0.0f64, 0.0f64, 0.0f64);
        for (c, &s) in channel.sigma_t.iter().enumerate() {
            if s <= 0.0 {
                continue;
            }
            let r = reference.fields[0].cell_irradiance[c] as f64;
            let v = p.fields[0].cell_irradiance[c] as f64;
            err += s as f64 * (v - r).abs();
            total += s as f64 * r;
            if r > 1e-3 {
                worst = worst.max((v / r - 1.0).abs());
            }
        }
        println!(
            "sigma scale {scale}: m = {m}: extinction-weighted L1 {:.2e}, worst cell (E > 1e-3) {:.2e}",
            err / total,
            worst
        );
    }
}
