//! `volrad bench albedo`: iteration counts of every solve method against a uniform albedo
//! (and a σt scale), on one operator per σ-scale built at albedo 1 and scaled: `K_a = a·K_1`.
//! Writes a CSV and PNG plots (plotters, text drawn with a font shipped in the `dejavu` crate).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{bail, Context, Result};
use formfactor::ordinates::{DirectionBins, OrdinatesOperator};
use formfactor::{ExactOptions, FormFactorMatrix, HierarchicalOperator, HierarchicalOptions};
use medium::light_pass::LightPass;
use medium::optical::CellValues;
use medium::ChannelMedium;
use plotters::coord::Shift;
use plotters::prelude::*;
use scene::Scene;
use scene::SolveMethod;
use solver::{Method, RowAccess, SolveControl, SolveOptions, TransportOperator};

use crate::cli::BenchAlbedoArgs;
use crate::engine::methods::HIERARCHY_TOLERANCE;

/// Power-iteration steps at most, and the relative agreement that stops it.
const SPECTRAL_MAX_ITERATIONS: usize = 500;
const SPECTRAL_TOLERANCE: f64 = 1e-7;

/// `a · K` for an operator `K` built at albedo 1. Exact for a uniform albedo: every form of
/// `K` (zonal `diag(a) F`, discrete-ordinates `T · a σt P`) is linear in the albedo.
pub struct AlbedoScaled<'a> {
    inner: &'a dyn TransportOperator,
    albedo: f64,
}

impl<'a> AlbedoScaled<'a> {
    /// `albedo` must lie in (0, 1]; callers check (see [`parse_albedos`]).
    pub fn new(inner: &'a dyn TransportOperator, albedo: f64) -> Self {
        AlbedoScaled { inner, albedo }
    }
}

impl TransportOperator for AlbedoScaled<'_> {
    fn len(&self) -> usize {
        self.inner.len()
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.inner.apply(x, y);
        if self.albedo != 1.0 {
            y.iter_mut().for_each(|v| *v *= self.albedo);
        }
    }

    fn rows(&self) -> Option<&dyn RowAccess> {
        self.inner.rows().map(|_| self as &dyn RowAccess)
    }

    /// With rows: the plain Gauss–Seidel loop on `a K`. Without (hierarchical near field,
    /// transport sweeps): the inner operator's own pointwise sweep with `ω' = ω a` and
    /// `E'_i = E_i / a + (1 − 1/a) g_i`, which gives exactly
    /// `g_i ← (1 − ω) g_i + ω (E_i + a (K g)_i)` because each unknown is updated once per sweep
    /// from its own pre-sweep value.
    fn sweep_in_place(&self, g: &mut [f64], source: &[f64], omega: f64) -> bool {
        if self.albedo == 1.0 {
            return self.inner.sweep_in_place(g, source, omega);
        }
        if let Some(rows) = self.inner.rows() {
            for i in 0..g.len() {
                let kg = self.albedo * rows.row_dot(i, g);
                g[i] = (1.0 - omega) * g[i] + omega * (source[i] + kg);
            }
            return true;
        }
        let a = self.albedo;
        let shifted: Vec<f64> = source
            .iter()
            .zip(g.iter())
            .map(|(e, gi)| e / a + (1.0 - 1.0 / a) * gi)
            .collect();
        self.inner.sweep_in_place(g, &shifted, omega * a)
    }

    /// `diag(w) K` symmetric implies `diag(w) a K` symmetric: the same weights serve.
    fn symmetrizer(&self) -> Option<&[f64]> {
        self.inner.symmetrizer()
    }

    fn coarse_aggregates(&self) -> Option<&[u32]> {
        self.inner.coarse_aggregates()
    }

    fn coarse_operator(
        &self,
        aggregates: &[u32],
        n_coarse: usize,
        row_weights: Option<&[f64]>,
    ) -> Option<Vec<f64>> {
        let mut k = self
            .inner
            .coarse_operator(aggregates, n_coarse, row_weights)?;
        k.iter_mut().for_each(|v| *v *= self.albedo);
        Some(k)
    }

    /// `σs` scales with the albedo; `σt` and the leakage do not. (With the albedo in (0, 1]
    /// the scaled approximation stays valid; `None` if it were not.)
    fn diffusion(&self) -> Option<solver::Diffusion> {
        let (sigma_t, mut sigma_s, row_ptr, col, val) = self.inner.diffusion()?.into_parts();
        sigma_s.iter_mut().for_each(|s| *s *= self.albedo);
        solver::Diffusion::new(sigma_t, sigma_s, row_ptr, col, val).ok()
    }
}

impl RowAccess for AlbedoScaled<'_> {
    fn row_dot(&self, row: usize, x: &[f64]) -> f64 {
        let rows = self
            .inner
            .rows()
            .expect("rows() only offers rows the inner operator has");
        self.albedo * rows.row_dot(row, x)
    }

    fn for_each_in_row(&self, row: usize, visit: &mut dyn FnMut(usize, f64)) -> bool {
        let Some(rows) = self.inner.rows() else {
            return false;
        };
        let a = self.albedo;
        rows.for_each_in_row(row, &mut |j, k| visit(j, a * k))
    }
}

/// What to sweep.
#[derive(Clone, Debug)]
pub struct AlbedoBenchOptions {
    pub albedos: Vec<f64>,
    /// The iterations to compare.
    pub iterations: Vec<Method>,
    pub sigma_scales: Vec<f64>,
    pub tolerance: f64,
    pub max_iterations: usize,
}

/// One solve of the sweep: a row of `albedo.csv`.
#[derive(Clone, Debug)]
pub struct AlbedoRun {
    pub albedo: f64,
    pub sigma_scale: f64,
    pub method: String,
    pub iterations: usize,
    pub converged: bool,
    pub stop_reason: String,
    pub final_residual: f64,
    pub seconds: f64,
    pub seconds_per_iteration: f64,
    /// Power-iteration estimate of `ρ(a K_1)`.
    pub spectral_radius: f64,
    /// `ceil(ln tol / ln ρ)`, `None` when `ρ ≥ 1`.
    pub predicted_jacobi_iterations: Option<usize>,
    pub residual_history: Vec<f64>,
}

/// The CSV header, in column order.
pub const CSV_HEADER: &str = "albedo,sigma_scale,method,iterations,converged,final_residual,seconds,seconds_per_iteration,spectral_radius,predicted_jacobi_iterations";

/// Checks the albedos: finite, in (0, 1].
pub fn check_albedos(albedos: &[f64]) -> Result<()> {
    if albedos.is_empty() {
        bail!("--albedo: give at least one value");
    }
    for &a in albedos {
        if !(a > 0.0 && a <= 1.0) {
            bail!("--albedo {a}: an albedo must lie in (0, 1]");
        }
    }
    Ok(())
}

/// The scene's single uniform albedo of channel 0, or an error for a per-cell table (the
/// scaling `K_a = a K_1` then changes the albedo's shape, not just its level).
fn uniform_albedo(channel: &ChannelMedium) -> Result<f32> {
    match &channel.albedo {
        CellValues::Uniform(a) => Ok(*a),
        CellValues::PerCell(values) => {
            let first = values.first().copied().unwrap_or(1.0);
            if values.iter().all(|&v| v == first) {
                Ok(first)
            } else {
                bail!(
                    "the scene has a per-cell albedo table: `bench albedo` sweeps a uniform albedo \
                     (K_a = a·K_1 holds only then); give the scene a uniform [medium] albedo"
                )
            }
        }
    }
}

/// A built operator at albedo 1 with the two parts of its source: `E(a) = e + a · s1`.
struct Family {
    op: Box<dyn TransportOperator>,
    emission_part: Vec<f64>,
    first_bounce: Vec<f64>,
}

fn build_family(scene: &Scene, sigma_scale: f64) -> Result<Family> {
    let mut channel = scene.medium.channels()[0].clone();
    channel.albedo = CellValues::Uniform(1.0);
    if sigma_scale != 1.0 {
        channel
            .sigma_t
            .iter_mut()
            .for_each(|s| *s = (*s as f64 * sigma_scale) as f32);
    }
    // The operators take a medium (valid by construction): channel 0 changed, checked again.
    let medium = scene
        .medium
        .clone()
        .with_channel(0, channel)
        .with_context(|| format!("σ-scale {sigma_scale}: the scaled medium"))?;
    let light_pass =
        LightPass::compute(&medium, 0, &scene.lights).context("computing the light pass")?;
    // The operator a solve of this scene iterates: on its transport grid when that is not
    // the data grid.
    let transport = crate::engine::budget::transport_grid(scene, &scene.solve)?;
    let (medium, light_pass) = if !transport.is_data_grid() {
        let coarse = transport.medium(&medium)?;
        let pass = transport.light_pass(&medium, 0, &light_pass, &coarse)?;
        (coarse, pass)
    } else {
        (medium, light_pass)
    };
    let channel = &medium.channels()[0];
    match scene.solve.method {
        SolveMethod::DiscreteOrdinates => {
            let bins = DirectionBins::with_count(
                scene
                    .solve
                    .bins
                    .count(&medium.phase(), medium.grid().cell_count()),
            )?;
            let options =
                crate::engine::methods::ordinates_options(&scene.solve, &bins, &medium.phase());
            let op = OrdinatesOperator::new(&medium, 0, bins, options)?;
            // The source is the scattered light pass transported plus the emission
            // transported: the two parts, kept apart.
            let scattered = op.first_bounce_density_from_pass(&light_pass)?;
            let mut first_bounce = vec![0.0; op.len()];
            op.transport(&scattered, &mut first_bounce);
            let emitted: Vec<f64> = (0..medium.grid().cell_count())
                .map(|i| channel.emission.get(i) as f64)
                .collect();
            let mut emission_part = vec![0.0; op.len()];
            op.transport_emission(&emitted, &mut emission_part)?;
            Ok(Family {
                op: Box::new(op),
                emission_part,
                first_bounce,
            })
        }
        SolveMethod::Zonal | SolveMethod::ZonalHierarchical => {
            let full = light_pass
                .zonal_source(&medium, 0)
                .context("the zonal source")?;
            let emission_part: Vec<f64> = (0..full.len())
                .map(|i| channel.emission.get(i) as f64)
                .collect();
            let first_bounce = full
                .iter()
                .zip(&emission_part)
                .map(|(f, e)| f - e)
                .collect();
            let op: Box<dyn TransportOperator> = if scene.solve.method == SolveMethod::Zonal {
                Box::new(
                    FormFactorMatrix::build(&medium, 0, &ExactOptions::default(), None)
                        .context("building the exact form factors")?,
                )
            } else {
                Box::new(
                    // As the solve's operator: error control relative to every cell's light,
                    // estimated by its source (`solve_zonal`'s importance when no emitter
                    // pass runs; the bench carries the emission through the operator).
                    HierarchicalOperator::build_with_importance(
                        &medium,
                        0,
                        &HierarchicalOptions {
                            tolerance: HIERARCHY_TOLERANCE,
                            ..HierarchicalOptions::default()
                        },
                        Some(&full),
                    )
                    .context("building the hierarchical form factors")?,
                )
            };
            Ok(Family {
                op,
                emission_part,
                first_bounce,
            })
        }
        other => bail!(
            "[solve] method `{}` has no linear solve to benchmark (use zonal, zonal-hierarchical \
             or discrete-ordinates)",
            other.name()
        ),
    }
}

/// Runs every (σ-scale, albedo, method) combination. `progress` gets one line per step.
pub fn run_albedo_bench(
    scene: &Scene,
    options: &AlbedoBenchOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<AlbedoRun>> {
    check_albedos(&options.albedos)?;
    let methods = &options.iterations;
    if methods.is_empty() {
        bail!("--iteration: give at least one iteration");
    }
    for &s in &options.sigma_scales {
        if !(s.is_finite() && s > 0.0) {
            bail!("--sigma-scale {s}: must be positive and finite");
        }
    }
    let scene_albedo = uniform_albedo(&scene.medium.channels()[0])?;
    if scene.medium.channels().len() > 1 {
        progress("note: colour scene; benchmarking channel 0 only");
    }
    progress(&format!(
        "scene albedo {scene_albedo} is replaced by the swept values"
    ));
    let mut runs = Vec::new();
    for &sigma_scale in &options.sigma_scales {
        progress(&format!(
            "σ-scale {sigma_scale}: building the operator at albedo 1"
        ));
        let family = build_family(scene, sigma_scale)?;
        let rho_1 = solver::spectral_radius(
            family.op.as_ref(),
            SPECTRAL_MAX_ITERATIONS,
            SPECTRAL_TOLERANCE,
        );
        progress(&format!(
            "σ-scale {sigma_scale}: ρ(K_1) ≈ {:.6} ({} power steps{})",
            rho_1.rho,
            rho_1.iterations,
            if rho_1.converged { "" } else { ", not settled" }
        ));
        for &albedo in &options.albedos {
            let op = AlbedoScaled::new(family.op.as_ref(), albedo);
            let rho = albedo * rho_1.rho;
            let predicted = solver::predicted_iterations(rho, options.tolerance);
            let source: Vec<f64> = family
                .emission_part
                .iter()
                .zip(&family.first_bounce)
                .map(|(e, s)| e + albedo * s)
                .collect();
            for method in methods {
                let solve_options = SolveOptions {
                    method: *method,
                    tolerance: options.tolerance,
                    max_iterations: options.max_iterations,
                    record_history: true,
                };
                match solver::solve(&op, &source, None, &solve_options, &SolveControl::new()) {
                    Ok((_, report)) => {
                        progress(&format!(
                            "σ×{sigma_scale} a={albedo} {}: {} iterations, residual {:.2e}, {} ({:.3} s)",
                            report.method,
                            report.iterations,
                            report.final_residual,
                            if report.converged { "converged" } else { "NOT converged" },
                            report.seconds
                        ));
                        runs.push(AlbedoRun {
                            albedo,
                            sigma_scale,
                            method: report.method,
                            iterations: report.iterations,
                            converged: report.converged,
                            stop_reason: report.stop_reason.name().to_string(),
                            final_residual: report.final_residual,
                            seconds: report.seconds,
                            seconds_per_iteration: report.seconds_per_iteration,
                            spectral_radius: rho,
                            predicted_jacobi_iterations: predicted,
                            residual_history: report.residual_history,
                        });
                    }
                    Err(e) => progress(&format!(
                        "σ×{sigma_scale} a={albedo} {method}: skipped: {e}"
                    )),
                }
            }
        }
    }
    Ok(runs)
}

/// `albedo.csv`, one row per run.
pub fn csv_text(runs: &[AlbedoRun]) -> String {
    let mut out = String::from(CSV_HEADER);
    out.push('\n');
    for r in runs {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{:e},{:.6},{:e},{:.8},{}",
            r.albedo,
            r.sigma_scale,
            r.method,
            r.iterations,
            r.converged,
            r.final_residual,
            r.seconds,
            r.seconds_per_iteration,
            r.spectral_radius,
            r.predicted_jacobi_iterations
                .map_or_else(String::new, |n| n.to_string())
        );
    }
    out
}

/// The table printed on stdout.
pub fn table_text(runs: &[AlbedoRun]) -> String {
    let mut out = format!(
        "{:>7} {:>6} {:<14} {:>7} {:>9} {:>9} {:>9} {:>9} {:>8} {:>9}\n",
        "albedo",
        "σ×",
        "method",
        "iters",
        "converged",
        "residual",
        "seconds",
        "s/iter",
        "ρ(aK)",
        "predicted"
    );
    for r in runs {
        let _ = writeln!(
            out,
            "{:>7} {:>6} {:<14} {:>7} {:>9} {:>9.2e} {:>9.3} {:>9.2e} {:>8.5} {:>9}",
            r.albedo,
            r.sigma_scale,
            r.method,
            r.iterations,
            if r.converged { "yes" } else { "NO" },
            r.final_residual,
            r.seconds,
            r.seconds_per_iteration,
            r.spectral_radius,
            r.predicted_jacobi_iterations
                .map_or_else(|| "-".to_string(), |n| n.to_string())
        );
    }
    out
}

const FONT: &str = "sans-serif";

/// Registers the shipped DejaVu Sans as plotters' sans-serif (no system fonts needed).
fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut failed = false;
    ONCE.call_once(|| {
        failed = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
            .is_err();
    });
    if failed {
        bail!("the embedded DejaVu Sans font did not load");
    }
    Ok(())
}

fn plot_error(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("plotting: {e}")
}

/// Width and height of every plot, in pixels.
const PLOT_SIZE: (u32, u32) = (960, 640);

/// Draws a plot in memory with `draw` (which fills the whole area) and replaces `path` with
/// it as a PNG ([`gather::image_io::write_png`], atomic), so no half-drawn plot is ever left.
fn write_plot(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    let (width, height) = PLOT_SIZE;
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, PLOT_SIZE).into_drawing_area();
        draw(&root)?;
        root.present().map_err(plot_error)?;
    }
    gather::image_io::write_png(
        path,
        width,
        height,
        3,
        &pixels,
        gather::PngCompression::Default,
    )?;
    Ok(())
}

/// Series label: the method, plus the σ-scale when several are swept.
fn series_label(method: &str, sigma_scale: f64, several_scales: bool) -> String {
    if several_scales {
        format!("{method} σ×{sigma_scale}")
    } else {
        method.to_string()
    }
}

/// Iterations against `1 − a` (log–log); albedo 1 sits one decade left of the smallest
/// positive `1 − a` and its tick reads "a=1". Hollow markers: not converged.
pub fn plot_iterations(path: &Path, runs: &[AlbedoRun], title: &str) -> Result<()> {
    register_font()?;
    write_plot(path, |root| draw_iterations(root, runs, title))
}

fn draw_iterations(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    runs: &[AlbedoRun],
    title: &str,
) -> Result<()> {
    let min_gap = runs
        .iter()
        .map(|r| 1.0 - r.albedo)
        .filter(|g| *g > 0.0)
        .fold(f64::INFINITY, f64::min);
    let min_gap = if min_gap.is_finite() { min_gap } else { 1e-3 };
    let one_position = 10f64.powf((min_gap.log10() - 1.0).floor());
    let x_of = |a: f64| if a >= 1.0 { one_position } else { 1.0 - a };
    let max_gap = runs.iter().map(|r| x_of(r.albedo)).fold(min_gap, f64::max);
    let max_iter = runs.iter().map(|r| r.iterations).max().unwrap_or(1).max(1) as f64;

    root.fill(&WHITE).map_err(plot_error)?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 22))
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(72)
        .build_cartesian_2d(
            (one_position * 0.7..max_gap * 1.5).log_scale(),
            (0.8..max_iter * 4.0).log_scale(),
        )
        .map_err(plot_error)?;
    chart
        .configure_mesh()
        .x_desc("1 − albedo (log scale; leftmost: albedo = 1, no absorption)")
        .y_desc("iterations to relative residual tolerance (log scale)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 17))
        .x_label_formatter(&|x| {
            if (x / one_position - 1.0).abs() < 1e-6 {
                "a=1".to_string()
            } else {
                format!("{x:.0e}")
            }
        })
        .y_label_formatter(&|y| format!("{y:.0}"))
        .draw()
        .map_err(plot_error)?;

    let several_scales = distinct(runs.iter().map(|r| r.sigma_scale)).len() > 1;
    for (k, (method, scale)) in series(runs).into_iter().enumerate() {
        let colour = Palette99::pick(k).to_rgba();
        let mut points: Vec<(f64, f64, bool)> = runs
            .iter()
            .filter(|r| r.method == method && r.sigma_scale == scale)
            .map(|r| (x_of(r.albedo), r.iterations.max(1) as f64, r.converged))
            .collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (p.0, p.1)),
                colour.stroke_width(2),
            ))
            .map_err(plot_error)?
            .label(series_label(&method, scale, several_scales))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart
            .draw_series(points.iter().map(|&(x, y, converged)| {
                let style = if converged {
                    colour.filled()
                } else {
                    colour.stroke_width(2)
                };
                Circle::new((x, y), 4, style)
            }))
            .map_err(plot_error)?;
    }
    // The Jacobi count that the power-iteration ρ(aK) predicts, dashed, per σ-scale.
    for scale in distinct(runs.iter().map(|r| r.sigma_scale)) {
        let mut predicted: Vec<(f64, f64)> = Vec::new();
        for r in runs.iter().filter(|r| r.sigma_scale == scale) {
            let x = x_of(r.albedo);
            if let Some(n) = r.predicted_jacobi_iterations {
                if !predicted.iter().any(|p| p.0 == x) {
                    predicted.push((x, n.max(1) as f64));
                }
            }
        }
        predicted.sort_by(|a, b| a.0.total_cmp(&b.0));
        if predicted.is_empty() {
            continue;
        }
        chart
            .draw_series(DashedLineSeries::new(
                predicted,
                6,
                4,
                BLACK.stroke_width(1),
            ))
            .map_err(plot_error)?
            .label(series_label(
                "jacobi predicted by ρ(aK)",
                scale,
                several_scales,
            ))
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 15))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(plot_error)?;
    Ok(())
}

/// Relative residual against iteration, one line per method (and σ-scale), for one albedo.
pub fn plot_residuals(path: &Path, runs: &[&AlbedoRun], title: &str) -> Result<()> {
    register_font()?;
    write_plot(path, |root| draw_residuals(root, runs, title))
}

fn draw_residuals(
    root: &DrawingArea<BitMapBackend<'_>, Shift>,
    runs: &[&AlbedoRun],
    title: &str,
) -> Result<()> {
    let positive = |v: &f64| *v > 0.0 && v.is_finite();
    let max_len = runs
        .iter()
        .map(|r| r.residual_history.len().saturating_sub(1))
        .max()
        .unwrap_or(1)
        .max(1);
    let values = runs
        .iter()
        .flat_map(|r| r.residual_history.iter().copied())
        .filter(positive);
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let (lo, hi) = if lo.is_finite() {
        (lo, hi)
    } else {
        (1e-6, 1.0)
    };

    root.fill(&WHITE).map_err(plot_error)?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 22))
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(80)
        .build_cartesian_2d(0.0..max_len as f64, (lo * 0.5..hi * 2.0).log_scale())
        .map_err(plot_error)?;
    chart
        .configure_mesh()
        .x_desc("iteration (0: the starting guess g = 0)")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_desc("relative residual ‖E + K g − g‖ / ‖E‖ (log scale)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 17))
        .y_label_formatter(&|y| format!("{y:.0e}"))
        .draw()
        .map_err(plot_error)?;
    let several_scales = distinct(runs.iter().map(|r| r.sigma_scale)).len() > 1;
    for (k, r) in runs.iter().enumerate() {
        let colour = Palette99::pick(k).to_rgba();
        chart
            .draw_series(LineSeries::new(
                r.residual_history
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| positive(v))
                    .map(|(i, v)| (i as f64, *v)),
                colour.stroke_width(2),
            ))
            .map_err(plot_error)?
            .label(series_label(&r.method, r.sigma_scale, several_scales))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 15))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(plot_error)?;
    Ok(())
}

fn distinct(values: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for v in values {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    out
}

/// (method, σ-scale) pairs in first-seen order.
fn series(runs: &[AlbedoRun]) -> Vec<(String, f64)> {
    let mut out: Vec<(String, f64)> = Vec::new();
    for r in runs {
        if !out
            .iter()
            .any(|(m, s)| *m == r.method && *s == r.sigma_scale)
        {
            out.push((r.method.clone(), r.sigma_scale));
        }
    }
    out
}

/// The residual plot's file for one albedo: `residuals_a0.99.png`.
pub fn residual_plot_path(dir: &Path, albedo: f64) -> PathBuf {
    dir.join(format!("residuals_a{albedo}.png"))
}

/// Writes `albedo.csv`, `albedo.png` and one `residuals_a{albedo}.png` per albedo into `dir`.
pub fn write_outputs(
    dir: &Path,
    runs: &[AlbedoRun],
    scene_name: &str,
    tolerance: f64,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let csv = dir.join("albedo.csv");
    medium::atomic_file::write_bytes(&csv, csv_text(runs).as_bytes())
        .with_context(|| format!("writing {}", csv.display()))?;
    plot_iterations(
        &dir.join("albedo.png"),
        runs,
        &format!("{scene_name}: iterations to {tolerance:e} against albedo"),
    )?;
    for albedo in distinct(runs.iter().map(|r| r.albedo)) {
        let subset: Vec<&AlbedoRun> = runs.iter().filter(|r| r.albedo == albedo).collect();
        plot_residuals(
            &residual_plot_path(dir, albedo),
            &subset,
            &format!("{scene_name}: residual history at albedo {albedo}"),
        )?;
    }
    Ok(())
}

/// `volrad bench albedo`. `max_memory` is `--max-memory`: an operator predicted not to fit
/// (by default, in the memory the machine has available) is refused before it is built.
pub fn run(args: &BenchAlbedoArgs, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    let scene = Scene::from_file(&args.scene)
        .with_context(|| format!("reading {}", args.scene.display()))?;
    crate::engine::budget::check_solve(
        &scene,
        &scene.solve,
        crate::engine::budget::MemoryLimit::given_or_available(max_memory),
    )?;
    let options = AlbedoBenchOptions {
        albedos: args.albedo.clone(),
        iterations: args.iteration.clone(),
        sigma_scales: args.sigma_scale.clone(),
        tolerance: args.tolerance,
        max_iterations: args.max_iterations,
    };
    let mut progress = |line: &str| {
        if !quiet {
            eprintln!("{line}");
        }
    };
    let runs = run_albedo_bench(&scene, &options, &mut progress)?;
    let name = args
        .scene
        .file_name()
        .map_or_else(|| "scene".to_string(), |n| n.to_string_lossy().into_owned());
    write_outputs(&args.output, &runs, &name, args.tolerance)?;
    print!("{}", table_text(&runs));
    if !quiet {
        eprintln!(
            "wrote {}/albedo.csv, albedo.png, residuals_a*.png",
            args.output.display()
        );
    }
    Ok(())
}
