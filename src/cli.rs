//! Command-line arguments, stage one: what the user typed, parsed by clap. Stage two
//! (`app.rs`) validates them against the scene and turns them into work.

use std::path::PathBuf;

use crate::engine::methods::ExportField;
use clap::builder::TypedValueParser;
use clap::{Args, Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "volrad",
    version,
    about = "Volume radiosity: solve multiple scattering in a participating medium once, render many views.",
    long_about = "Volume radiosity: solve multiple scattering in a participating medium once, render many views.\n\n\
With no command, volrad solves the built-in procedural cloud and renders it to volrad-default.png.\n\
Scene files are TOML (see docs/scene-format.md); solutions are binary files that `render --solution` reads."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,

    /// More log output (-v: debug, -vv: trace). RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,

    /// No progress bars or summaries on stderr.
    #[arg(short, long, global = true)]
    pub quiet: bool,

    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    pub threads: Option<usize>,

    /// Largest memory a solve or an image may use, e.g. 4G or 512M (default: what the
    /// machine has available); a solve predicted to need more is refused before it starts,
    /// saying what would fit. For `serve`, the limit of each solve.
    #[arg(long, global = true, value_name = "SIZE", value_parser = crate::engine::budget::parse_size)]
    pub max_memory: Option<u64>,

    /// Output file for the default run (no command).
    #[arg(short = 'o', long = "output", default_value = "volrad-default.png")]
    pub default_output: PathBuf,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render one camera (or all, when OUT is a directory) to PNG, EXR or PFM.
    Render(RenderArgs),
    /// Solve the scene's light transport and write the solution file.
    Solve(SolveArgs),
    /// Describe a scene: dims, σt range, optical depth, memory estimate.
    Info(InfoArgs),
    /// Write a solved per-cell field (fluence, source, sigma-t) as raw f32 or NRRD.
    Export(ExportArgs),
    /// Serve solves and renders over HTTP, with a viewer page at `/`.
    Serve(ServeArgs),
    /// Benchmarks of the solver.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Every method on the sample scenes against a path-traced reference: a Markdown report
    /// with errors, times, memory and side-by-side images.
    Validate(ValidateArgs),
    /// How far one render is from another: relative RMS, mean and largest difference of two
    /// PFM or EXR images over the pixels above a share of the first one's peak.
    Compare(CompareArgs),
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The image compared against (PFM or EXR), e.g. the render of the build before a change.
    pub before: PathBuf,
    /// The image compared with it (PFM or EXR), of the same size.
    pub after: PathBuf,
    /// Compare the pixels whose value in BEFORE (the mean of its channels) is above this share
    /// of BEFORE's peak, in (0, 1).
    #[arg(long, default_value_t = 0.01, value_parser = share_of_peak)]
    pub above: f64,
}

fn share_of_peak(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x > 0.0 && x < 1.0 => Ok(x),
        _ => Err(format!("`{s}` is not a share of the peak in (0, 1)")),
    }
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Scene file (TOML), repeatable (default: tests/data/cloud24-isotropic/scene.toml and
    /// tests/data/cloud24-anisotropic/scene.toml, relative to the working directory).
    #[arg(long = "scene")]
    pub scenes: Vec<PathBuf>,
    /// Methods, comma-separated (single-scatter, zonal, zonal-hierarchical,
    /// discrete-ordinates, two-pass, path-trace; default: all).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Directory for report.md, report.json and the images (images an earlier report there
    /// showed and this one does not are removed).
    #[arg(short = 'o', long = "output", default_value = "docs/validation")]
    pub output: PathBuf,
    /// Few samples (64-spp reference, 4 spp renders, 16-spp path tracing): CI-sized runs.
    #[arg(long)]
    pub quick: bool,
    /// Paths per pixel of the path-traced reference (default 1024, quick 64).
    #[arg(long)]
    pub reference_spp: Option<u32>,
    /// Samples per pixel of renders from a solution (default 16, quick 4).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Views per scene: its first camera and the rest turned about the camera's up axis
    /// through its target in equal steps (default 8, quick 2).
    #[arg(long)]
    pub views: Option<usize>,
    /// Validate every scene once per value: KEY=v1,v2,… with KEY albedo, g (Henyey–Greenstein),
    /// sigma-t-factor (times the scene's sigma_t_scale), bins, forward-peak-cone or
    /// transport-refinement (the [solve] keys); repeatable, the cases are every combination (e.g. --vary
    /// albedo=0.5,0.9,0.99,1 --vary g=0,0.6,0.85,0.95).
    #[arg(long = "vary", value_name = "KEY=VALUES")]
    pub vary: Vec<String>,
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Iterations against albedo (and density) for several solve methods: CSV and PNG plots.
    Albedo(BenchAlbedoArgs),
}

#[derive(Debug, Args)]
pub struct BenchAlbedoArgs {
    /// Scene file (TOML); its `[solve] method` picks the operator family.
    pub scene: PathBuf,
    /// Uniform single-scattering albedos, comma-separated, each in (0, 1].
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.5,0.8,0.9,0.95,0.99,0.999,1.0"
    )]
    pub albedo: Vec<f64>,
    /// Iterations to compare, comma-separated (jacobi, gauss-seidel, sor:1.5, gmres:30,
    /// bicgstab, cg, coarse-cg, two-level-cg[:N], dsa-cg, coarse-jacobi, coarse-gs,
    /// coarse-sor:OMEGA), as `solve --iteration` reads them.
    #[arg(long, value_delimiter = ',', default_value = "jacobi,gauss-seidel")]
    pub iteration: Vec<solver::Method>,
    /// Multipliers of the scene's σt, comma-separated (the operator is rebuilt for each).
    #[arg(long, value_delimiter = ',', default_value = "1")]
    pub sigma_scale: Vec<f64>,
    /// Relative residual to stop at.
    #[arg(long, default_value_t = 1e-5)]
    pub tolerance: f64,
    /// Iteration cap per solve.
    #[arg(long, default_value_t = 2000)]
    pub max_iterations: usize,
    /// Directory for albedo.csv, albedo.png and residuals_a*.png.
    #[arg(short = 'o', long = "output", default_value = "bench-albedo")]
    pub output: PathBuf,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene file (TOML). Optional with --solution, which carries the medium.
    pub scene: Option<PathBuf>,
    /// Output image (.png, .exr, .pfm) or a directory (all cameras, PNG).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Camera name from the scene (default: the first).
    #[arg(long)]
    pub camera: Option<String>,
    /// Render from a stored solution instead of solving.
    #[arg(long)]
    pub solution: Option<PathBuf>,
    /// Stratified samples per pixel (default: the scene's, else 1).
    #[arg(long)]
    pub spp: Option<u32>,
    /// PNG exposure (default: the scene's, else automatic: the 99.5th-percentile radiance at 85 % of white).
    #[arg(long)]
    pub exposure: Option<f64>,
    #[command(flatten)]
    pub view: ViewArgs,
    /// Render by unbiased Monte Carlo path tracing of the scene instead of from a solution
    /// (no solve; `--spp` paths per pixel, next-event estimation, unlimited depth).
    #[arg(long)]
    pub path_trace: bool,
    /// Seed of the path tracer's random streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Render N views on a circle around the camera's target (one solve or solution read for
    /// all). OUT names a folder (FOLDER/CAMERA_000.png, …) or a file (STEM_CAMERA_000.EXT, …).
    #[arg(long)]
    pub orbit: Option<u32>,
    /// Separate absorption for rendering (Blasi & Wuethrich §4.3): σt times S along the view
    /// rays only; the solved light stays as it was (a thinner or denser look, same lighting).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub extinction_scale: Option<f32>,
}

/// A camera given on the command line; overrides parts of the scene's camera.
#[derive(Debug, Args, Default, Clone)]
pub struct ViewArgs {
    /// Eye position "x,y,z".
    #[arg(long, value_parser = parse_vec3)]
    pub eye: Option<[f64; 3]>,
    /// Look-at point "x,y,z" (default: the scene camera's; the volume's centre when the
    /// scene has no camera).
    #[arg(long, value_parser = parse_vec3)]
    pub target: Option<[f64; 3]>,
    /// Up vector "x,y,z" (default: the scene camera's; 0,0,1 when the scene has no camera).
    /// It must not be parallel to the view direction.
    #[arg(long, value_parser = parse_vec3)]
    pub up: Option<[f64; 3]>,
    /// Vertical field of view in degrees (default: the scene camera's; 40 without one).
    #[arg(long)]
    pub fov: Option<f64>,
    /// Image width in pixels (default: the scene camera's; 512 without one).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene camera's; 384 without one).
    #[arg(long)]
    pub height: Option<u32>,
}

#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// Where to write the solution.
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Print the report as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub overrides: SolveOverrides,
}

/// Changes to a scene's `[solve]` settings for one solve: `volrad solve` solves with them,
/// `volrad info` predicts what that solve would choose, need and take, and the Python
/// package's `Scene.solve(method=…)` builds them too ([`SolveOverrides::apply`]).
#[derive(Clone, Debug, Args, Default)]
pub struct SolveOverrides {
    /// Override `[solve] method` (discrete-ordinates, zonal, zonal-hierarchical,
    /// single-scatter, two-pass, none); a new method brings its default iteration.
    #[arg(long)]
    pub method: Option<scene::SolveMethod>,
    /// Override `[solve] iteration` (jacobi, gauss-seidel, sor:1.5, gmres:30, bicgstab, cg,
    /// coarse-cg, two-level-cg[:N], dsa-cg, coarse-jacobi, coarse-gs, coarse-sor:OMEGA).
    #[arg(long)]
    pub iteration: Option<solver::Method>,
    /// Override `[solve] tolerance`.
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// Override `[solve] max_iterations`.
    #[arg(long)]
    pub max_iterations: Option<usize>,
    /// Override `[solve] transport_scale`: solve the multiple scattering on blocks of N³ data
    /// cells (1..=16), or `auto` (the data grid up to 64³ cells, coarser beyond).
    #[arg(long, value_name = "auto|N")]
    pub transport_scale: Option<scene::TransportScale>,
}

impl SolveOverrides {
    /// `settings` with the overrides applied; a bad tolerance is refused.
    pub fn apply(&self, settings: &scene::SolveSettings) -> anyhow::Result<scene::SolveSettings> {
        let mut settings = settings.clone();
        if let Some(method) = self.method {
            settings.method = method;
            // A new method brings its own default iteration unless an iteration is given.
            settings.iteration = method.default_iteration();
        }
        if let Some(iteration) = self.iteration {
            settings.iteration = iteration;
        }
        if let Some(t) = self.tolerance {
            if !(t.is_finite() && t > 0.0) {
                anyhow::bail!("tolerance {t}: must be a positive number");
            }
            settings.tolerance = t;
        }
        if let Some(n) = self.max_iterations {
            settings.max_iterations = n;
        }
        if let Some(scale) = self.transport_scale {
            settings.transport_scale = scale;
        }
        Ok(settings)
    }
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Scene files to load at start, named by their file names (solved unless the cache
    /// holds their solutions); the viewer opens on one of them.
    pub scenes: Vec<PathBuf>,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    /// Directory of cached solutions (created when missing).
    #[arg(long, default_value = "volrad-cache")]
    pub cache: PathBuf,
    /// Largest request body in bytes.
    #[arg(long, default_value_t = 64 << 20)]
    pub max_body_bytes: usize,
    /// Largest grid (nx·ny·nz) a scene may have.
    #[arg(long, default_value_t = 4_000_000)]
    pub max_cells: usize,
    /// Largest image side in pixels.
    #[arg(long, default_value_t = 4096)]
    pub max_image_side: u32,
    /// Largest samples per pixel of a render.
    #[arg(long, default_value_t = 64)]
    pub max_spp: u32,
    /// Largest `[solve] max_iterations`.
    #[arg(long, default_value_t = 10_000)]
    pub max_iterations: usize,
    /// Cache size limit in MiB (least recently used solutions are evicted beyond it).
    #[arg(long, default_value_t = 2048)]
    pub max_cache_mib: u64,
    /// Renders at once (default: the core count).
    #[arg(long)]
    pub render_slots: Option<usize>,
    /// Seconds a client may take to send a request's headers, and again its body; slower
    /// clients are cut off (headers) or answered 408 (body).
    #[arg(long, default_value_t = 30.0, value_parser = positive_seconds)]
    pub request_timeout_secs: f64,
}

fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x > 0.0 && x <= 86_400.0 => Ok(x),
        _ => Err(format!("`{s}` is not a number of seconds in (0, 86400]")),
    }
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    pub scene: PathBuf,
    /// Print as JSON.
    #[arg(long)]
    pub json: bool,
    /// What a `volrad solve` with these overrides would choose, need and take.
    #[command(flatten)]
    pub overrides: SolveOverrides,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    pub solution: PathBuf,
    /// fluence (∫ I dω at each cell: the lights' unscattered light, the emitters' uncollided
    /// light and the scattered light), source (the solved source per cell, radiance per unit
    /// length) or sigma-t (extinction per cell).
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(ExportField::NAMES)
        .map(|s| s.parse::<ExportField>().expect("a listed name parses")))]
    pub field: ExportField,
    /// Output .raw (with a .json sidecar) or .nrrd.
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Colour channel (0 for grey scenes).
    #[arg(long, default_value_t = 0)]
    pub channel: usize,
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected three comma-separated numbers, got `{s}`"));
    }
    let mut v = [0.0; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("`{p}` is not a finite number"))?;
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors_parse_and_bad_ones_are_refused() {
        assert_eq!(parse_vec3("1, 2.5,-3").unwrap(), [1.0, 2.5, -3.0]);
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,x").is_err());
        assert!(parse_vec3("1,2,inf").is_err());
    }

    #[test]
    fn command_line_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
