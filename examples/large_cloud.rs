//! Real-size clouds: the sample cloud (`data/cloud.toml`'s generator, σt up to 0.6 over the
//! same 64 × 64 × 48 world) generated at `n × n × 3n/4` cells, a = 0.99, Henyey–Greenstein
//! g = 0.85, solved on its transport grid (`[solve] transport_scale`, `auto` unless given),
//! then rendered from an orbit of views around it and compared with the path tracer on each
//! (its noise removed). Prints the solve's time and the process's peak memory after it, the
//! time of one 1024 × 768 view from the solution, and per view the relative RMS and mean
//! difference over pixels above 1 % of the reference's peak (`montecarlo::compare`: the
//! reference's noise taken out; 0 where the difference is within it).
//!
//! ```text
//! cargo run --release --example large_cloud -- [--dims N] [--method M] [--transport-scale S]
//!     [--bins B] [--views V] [--width W] [--spp S] [--no-reference]
//! ```
//! Defaults: `--dims 192` (192 × 192 × 144), discrete ordinates with the bins volrad chooses,
//! 8 views of 96 × 72 pixels, 256 paths per pixel.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::DVec3;
use montecarlo::compare::compare_images;
use scene::{CameraSpec, Projection, Scene};
use volrad::engine::pipeline::{render_view, solve_scene};
use volrad::engine::SolveHooks;
use volrad::validate::path_traced;

struct Args {
    dims: usize,
    method: String,
    transport_scale: String,
    bins: String,
    views: usize,
    width: u32,
    spp: u32,
    reference: bool,
}

fn args() -> Result<Args> {
    let mut a = Args {
        dims: 192,
        method: "discrete-ordinates".into(),
        transport_scale: "\"auto\"".into(),
        bins: "\"auto\"".into(),
        views: 8,
        width: 96,
        spp: 256,
        reference: true,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--dims" => a.dims = value()?.parse()?,
            "--method" => a.method = value()?,
            "--transport-scale" => a.transport_scale = value()?,
            "--bins" => a.bins = value()?,
            "--views" => a.views = value()?.parse()?,
            "--width" => a.width = value()?.parse()?,
            "--spp" => a.spp = value()?.parse()?,
            "--no-reference" => a.reference = false,
            other => bail!("unknown argument {other}"),
        }
    }
    if a.dims < 8 || !a.dims.is_multiple_of(4) {
        bail!("--dims must be a multiple of 4, at least 8");
    }
    Ok(a)
}

fn peak_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|k| k.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |k| k / 1024.0)
}

/// A view on a circle around the cloud's centre, `angle` radians from the front (the light
/// comes from behind the front camera's right shoulder; half way round the views are
/// back-lit).
fn orbit_view(angle: f64, width: u32) -> CameraSpec {
    let centre = DVec3::new(32.0, 30.0, 24.0);
    let radius = 96.0;
    let eye = centre + DVec3::new(radius * angle.sin(), 10.0, -radius * angle.cos());
    CameraSpec {
        name: format!("orbit{:03.0}", angle.to_degrees()),
        eye,
        target: centre,
        up: DVec3::Y,
        projection: Projection::Perspective {
            fov_y_degrees: 40.0,
        },
        width,
        height: width * 3 / 4,
    }
}

fn main() -> Result<()> {
    let a = args()?;
    let (nx, nz) = (a.dims, a.dims * 3 / 4);
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 7 }}
dims = [{nx}, {nx}, {nz}]
sigma_t_scale = 0.6
cell_size = {h}

[medium]
albedo = 0.99
phase = {{ kind = "henyey-greenstein", g = 0.85 }}

[[light]]
kind = "directional"
direction = [-0.45, -1.0, 0.35]
irradiance = 1.0

[solve]
method = "{method}"
transport_scale = {scale}
bins = {bins}
"#,
        h = 64.0 / nx as f64,
        method = a.method,
        scale = a.transport_scale,
        bins = a.bins,
    );
    let scene = Scene::from_toml_str(&text, Path::new("."), Path::new("large_cloud.toml"))?;
    let start = Instant::now();
    let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default())?;
    let solve_seconds = start.elapsed().as_secs_f64();
    let peak = peak_mib();
    let t = solution.transport;
    let bins = solution
        .bins
        .as_ref()
        .map_or_else(|| "no".into(), |b| b.directions.len().to_string());
    println!(
        "{nx}×{nx}×{nz} = {} cells, {} method, transport grid {:?} (scale {}), {bins} bins: solve {solve_seconds:.1} s, peak {peak:.0} MiB",
        scene.medium.grid().cell_count(),
        a.method,
        t.transport().dims,
        t.scale(),
    );
    let big = orbit_view(0.0, 1024);
    render_view(&solution, &big, None)?; // builds the render caches
    let start = Instant::now();
    render_view(&solution, &big, None)?;
    println!(
        "1024×768 view from the solution: {:.2} s",
        start.elapsed().as_secs_f64()
    );
    if !a.reference {
        return Ok(());
    }
    println!("view      RMS     mean     (path tracer: {} spp)", a.spp);
    let (mut worst_rms, mut worst_mean) = (0.0f64, 0.0f64);
    for v in 0..a.views {
        let camera = orbit_view(v as f64 * std::f64::consts::TAU / a.views as f64, a.width);
        let image = render_view(&solution, &camera, None)?;
        let (mean, std_error) =
            path_traced(&scene, &gather::Camera::from_spec(&camera)?, a.spp, 0)?;
        let c = compare_images(&image, None, &mean, Some(&std_error), 0.01, 1)
            .map_err(anyhow::Error::msg)?;
        let (rms, mean) = (c.relative_rms_error, c.relative_mean_difference);
        worst_rms = worst_rms.max(rms);
        worst_mean = if mean.abs() > worst_mean.abs() {
            mean
        } else {
            worst_mean
        };
        println!(
            "{:<9} {:5.1} %  {:+5.1} %   (reference noise {:.1} %)",
            camera.name,
            100.0 * rms,
            100.0 * mean,
            100.0 * c.relative_rms_noise
        );
    }
    println!(
        "worst     {:5.1} %  {:+5.1} %",
        100.0 * worst_rms,
        100.0 * worst_mean
    );
    Ok(())
}
