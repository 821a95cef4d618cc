//! The commands behind the command line: each validates its inputs, does the work through
//! [`crate::engine::pipeline`], and reports what it wrote.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use montecarlo::path_trace::Surroundings;
use scene::{CameraSpec, Scene};

pub use crate::cli::SolveOverrides;
use crate::cli::{CompareArgs, ExportArgs, InfoArgs, RenderArgs, SolveArgs};
use crate::engine::pipeline::{render_view, render_view_through, solve_scene, view_medium};
use crate::engine::solution::Solution;
use crate::engine::SolveHooks;
use crate::progress::SolveProgress;
use crate::views::{orbit_cameras, view_outputs, CameraRequest};

/// The built-in default scene ([`Scene::builtin_default`]).
pub fn default_scene() -> Result<Scene> {
    Scene::builtin_default().context("the built-in scene")
}

/// `volrad` with no command: the built-in cloud, solved with its default method, rendered.
pub fn run_default(output: &Path, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    let scene = default_scene()?;
    let started = Instant::now();
    let solution = solve_with_progress(&scene, &scene.solve, quiet, max_memory)?;
    let camera = scene
        .cameras
        .first()
        .context("the built-in scene has a camera")?;
    let image = render_view(&solution, camera, None)?;
    let exposure = solution
        .render
        .exposure
        .unwrap_or_else(|| gather::auto_exposure(&image));
    image
        .save(output, exposure)
        .with_context(|| format!("writing {}", output.display()))?;
    if !quiet {
        eprintln!(
            "volrad: built-in cloud {:?} solved by {} and rendered in {:.1} s",
            scene.medium.grid().dims,
            scene.solve.method.name(),
            started.elapsed().as_secs_f64()
        );
    }
    println!("wrote {}", output.display());
    Ok(())
}

/// Solves with a progress bar and Ctrl-C cancellation.
/// `max_memory` is `--max-memory`; without it the solve must fit in the memory the machine
/// has available.
pub fn solve_with_progress(
    scene: &Scene,
    settings: &scene::SolveSettings,
    quiet: bool,
    max_memory: Option<u64>,
) -> Result<Solution> {
    let progress = SolveProgress::start(settings, quiet);
    // solve_scene checks the memory budget before any work.
    let hooks = SolveHooks {
        control: Arc::new(progress.control()),
        memory_limit: crate::engine::budget::MemoryLimit::given_or_available(max_memory),
        on_prediction: Some(progress.prediction()),
    };
    crate::progress::cancel_on_ctrl_c(hooks.control.clone());
    let solution = solve_scene(scene, settings, &hooks);
    progress.finish();
    let solution = solution?;
    crate::engine::methods::refuse_cancelled(&solution)?;
    if !quiet {
        for warning in crate::engine::methods::convergence_warnings(&solution) {
            eprintln!("warning: {warning}");
        }
    }
    Ok(solution)
}

pub fn render(args: &RenderArgs, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    if args.path_trace {
        if args.extinction_scale.is_some() {
            bail!("--extinction-scale changes a render from a solution; the path tracer has none");
        }
        return render_path_traced(args, quiet, max_memory);
    }
    // Everything that can be refused is refused before the solve: the scene, whether the
    // solution belongs to it, the cameras and every output path.
    let scene = args.scene.as_deref().map(load_scene).transpose()?;
    let stored = match &args.solution {
        Some(path) => Some(Solution::read(path)?),
        None => None,
    };
    if let (Some(scene), Some(solution), Some(scene_path), Some(solution_path)) =
        (&scene, &stored, &args.scene, &args.solution)
    {
        refuse_foreign_solution(scene, scene_path, solution, solution_path)?;
    }
    // A scene given together with its solution supplies the cameras.
    let (cameras, grid) = match (&scene, &stored) {
        (Some(s), _) => (s.cameras.clone(), *s.medium.grid()),
        (None, Some(s)) => (s.cameras.clone(), *s.medium.grid()),
        (None, None) => bail!("render needs a scene file or --solution FILE"),
    };
    let plan = plan_views(args, &cameras, &grid)?;
    let channels = match (&scene, &stored) {
        (Some(s), _) => s.medium.channels().len(),
        (None, Some(s)) => s.channels.len(),
        (None, None) => unreachable!("refused above"),
    };
    let limit = crate::engine::budget::MemoryLimit::given_or_available(max_memory);
    for view in &plan.views {
        crate::engine::budget::check_image(view.width, view.height, channels, limit)?;
    }
    let solution = match (stored, &scene) {
        (Some(s), _) => s,
        (None, Some(scene)) => solve_with_progress(scene, &scene.solve, quiet, max_memory)?,
        (None, None) => unreachable!("refused above"),
    };
    // The flag, else the scene's, else automatic from the first view (kept for the rest, so
    // an orbit does not flicker).
    let mut exposure = args.exposure.or(solution.render.exposure);
    // One rescaled copy of the whole grid for every view, not one per view.
    let medium = view_medium(&solution, args.extinction_scale)?;
    let started = Instant::now();
    for (view, out) in plan.views.iter().zip(&plan.outputs) {
        let view_started = Instant::now();
        let image = render_view_through(&solution, &medium, view, args.spp)?;
        let exposure = *exposure.get_or_insert_with(|| gather::auto_exposure(&image));
        image
            .save(out, exposure)
            .with_context(|| format!("writing {}", out.display()))?;
        tracing::debug!(camera = %view.name, seconds = view_started.elapsed().as_secs_f64(), "rendered");
    }
    match plan.outputs.as_slice() {
        [one] => println!("wrote {}", one.display()),
        [first, .., last] => println!(
            "wrote {} views, {} … {} ({:.1} s)",
            plan.outputs.len(),
            first.display(),
            last.display(),
            started.elapsed().as_secs_f64()
        ),
        [] => {}
    }
    Ok(())
}

/// Refuses a solution that was solved from another scene than the one given with it, naming
/// both (the solution stores its scene's content hash).
fn refuse_foreign_solution(
    scene: &Scene,
    scene_path: &Path,
    solution: &Solution,
    solution_path: &Path,
) -> Result<()> {
    let hash = crate::engine::pipeline::scene_hash(scene);
    if hash != solution.scene_hash {
        bail!(
            "{} was solved from {} (scene hash {}), not from {} (scene hash {}): solve {} \
             again, or render the solution alone with `volrad render --solution {}`",
            solution_path.display(),
            solution.scene_origin,
            solution.scene_hash,
            scene_path.display(),
            hash,
            scene_path.display(),
            solution_path.display()
        );
    }
    Ok(())
}

/// The views of a render and the file each goes to, checked before any work.
struct ViewPlan {
    views: Vec<CameraSpec>,
    outputs: Vec<PathBuf>,
}

fn plan_views(args: &RenderArgs, cameras: &[CameraSpec], grid: &medium::Grid) -> Result<ViewPlan> {
    let into_directory = is_directory_target(&args.output);
    let all_cameras = args.camera.is_none() && args.orbit.is_none() && into_directory;
    let request = CameraRequest::from_args(args.camera.as_deref(), &args.view);
    let views: Vec<CameraSpec> = if all_cameras && !cameras.is_empty() {
        let mut views = Vec::with_capacity(cameras.len());
        for c in cameras {
            let named = CameraRequest {
                name: Some(c.name.clone()),
                ..request.clone()
            };
            // Each view keeps its camera's name (a moved eye would rename them all alike, and
            // their files would overwrite each other).
            let mut view = named.camera(cameras, grid)?;
            view.name = c.name.clone();
            views.push(view);
        }
        views
    } else {
        let base = request.camera(cameras, grid)?;
        match args.orbit {
            Some(0) => bail!("--orbit needs at least one view"),
            Some(n) => orbit_cameras(&base, n),
            None => vec![base],
        }
    };
    let outputs = if views.len() == 1 && !into_directory {
        vec![args.output.clone()]
    } else {
        let names: Vec<String> = views.iter().map(|v| v.name.clone()).collect();
        view_outputs(&args.output, &names, into_directory)
    };
    for out in &outputs {
        check_image_output(out)?;
    }
    Ok(ViewPlan { views, outputs })
}

/// Whether `-o` names a directory: an existing one, or a path ending in a separator.
fn is_directory_target(out: &Path) -> bool {
    out.is_dir()
        || out
            .as_os_str()
            .to_string_lossy()
            .ends_with(['/', std::path::MAIN_SEPARATOR])
}

/// Refuses an image path whose extension names no format volrad writes, and creates its
/// folder, so that a render never fails after the work.
fn check_image_output(out: &Path) -> Result<()> {
    gather::ImageFormat::from_path(out).map_err(|_| {
        anyhow::anyhow!(
            "-o {}: expected an image file ending in .png, .pfm or .exr, or a folder ending in /",
            out.display()
        )
    })?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    Ok(())
}

/// `render --path-trace`: unbiased Monte Carlo of the scene, no solve.
fn render_path_traced(args: &RenderArgs, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    let (medium, lights, surroundings, cameras, exposure) = match (&args.scene, &args.solution) {
        (Some(path), _) => {
            let scene = load_scene(path)?;
            (
                scene.medium,
                scene.lights,
                Surroundings {
                    background: scene.background,
                    environment: scene.environment,
                    ground: scene.ground,
                },
                scene.cameras,
                scene.render.exposure,
            )
        }
        (None, Some(path)) => {
            let s = Solution::read(path)?;
            (
                s.medium,
                s.lights,
                Surroundings {
                    background: s.background,
                    environment: s.environment,
                    ground: s.ground.as_ref().map(|g| *g.ground()),
                },
                s.cameras,
                s.render.exposure,
            )
        }
        (None, None) => bail!("render needs a scene file or --solution FILE"),
    };
    if args.orbit.is_some() {
        bail!("--orbit is for renders from a solution; path tracing renders one camera");
    }
    let spec = CameraRequest::from_args(args.camera.as_deref(), &args.view)
        .camera(&cameras, medium.grid())?;
    let camera = gather::Camera::from_spec(&spec)?;
    crate::engine::budget::check_image(
        camera.width,
        camera.height,
        medium.channels().len(),
        crate::engine::budget::MemoryLimit::given_or_available(max_memory),
    )?;
    check_image_output(&args.output)?;
    let options = montecarlo::path_trace::PathTraceOptions {
        spp: args.spp.unwrap_or(64),
        seed: args.seed,
        ..Default::default()
    };
    let started = Instant::now();
    let rows = u64::from(camera.height) * medium.channels().len() as u64;
    let progress = crate::progress::RowsProgress::start(
        rows,
        &format!("path tracing {} spp", options.spp),
        quiet,
    );
    let traced = montecarlo::path_trace::path_trace_image_with_progress(
        &medium,
        &lights,
        surroundings,
        &camera,
        &options,
        &|done| progress.update(done),
    );
    progress.finish();
    let image = match traced {
        Err(montecarlo::MonteCarloError::Cancelled) => {
            bail!("path tracing cancelled; nothing written")
        }
        other => other?,
    };
    let seconds = started.elapsed().as_secs_f64();
    let paths = camera.width as f64
        * camera.height as f64
        * options.spp as f64
        * medium.channels().len() as f64;
    tracing::info!(seconds, paths_per_second = paths / seconds, "path traced");
    let exposure = args
        .exposure
        .or(exposure)
        .unwrap_or_else(|| gather::auto_exposure(&image));
    image
        .save(&args.output, exposure)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!("wrote {}", args.output.display());
    Ok(())
}

pub fn solve(args: &SolveArgs, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    let scene = load_scene(&args.scene)?;
    let settings = args.overrides.apply(&scene.solve)?;
    // Refused before the solve, not after it: a folder as output, or a folder that cannot be made.
    if is_directory_target(&args.output) {
        bail!(
            "-o {}: expected a solution file name (e.g. cloud.volrad), not a folder",
            args.output.display()
        );
    }
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let started = Instant::now();
    let solution = solve_with_progress(&scene, &settings, quiet || args.json, max_memory)?;
    solution
        .write(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    let summary =
        crate::engine::methods::SolveSummary::of(&solution, started.elapsed().as_secs_f64());
    // `-o /dev/stdout | …` carries the solution itself: the summary goes beside it, to
    // standard error, not into it.
    let mut report: Box<dyn std::io::Write> = if is_standard_output(&args.output) {
        Box::new(std::io::stderr())
    } else {
        Box::new(std::io::stdout())
    };
    if args.json {
        writeln!(report, "{}", serde_json::to_string(&summary)?)?;
    } else {
        write!(report, "{summary}")?;
        writeln!(report, "wrote {}", args.output.display())?;
    }
    Ok(())
}

/// Whether `path` names this process's standard output (`/dev/stdout`, `/proc/self/fd/1`, or
/// the FIFO or file standard output was redirected to): the same file, by device and inode.
fn is_standard_output(path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::fd::AsFd;
        use std::os::unix::fs::MetadataExt;
        let Ok(target) = std::fs::metadata(path) else {
            return false;
        };
        let Ok(stdout) = std::io::stdout().as_fd().try_clone_to_owned() else {
            return false;
        };
        std::fs::File::from(stdout)
            .metadata()
            .is_ok_and(|out| out.dev() == target.dev() && out.ino() == target.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        false
    }
}

pub fn export(args: &ExportArgs) -> Result<()> {
    let solution = Solution::read(&args.solution)?;
    let (values, units) =
        crate::engine::methods::export_field(&solution, args.channel, args.field)?;
    let dims = solution.medium.grid().dims;
    let field_name = args.field.name();
    let volume = medium::volume_io::VolumeData::new(dims, values)?;
    let ext = args
        .output
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let comments = vec![
        ("field".to_string(), field_name.to_string()),
        ("units".to_string(), units.to_string()),
        ("channel".to_string(), args.channel.to_string()),
        ("solution".to_string(), args.solution.display().to_string()),
        (
            "cell_size".to_string(),
            solution.medium.grid().cell_size.to_string(),
        ),
    ];
    match ext.as_str() {
        "nrrd" => medium::volume_io::write_nrrd(
            &args.output,
            &volume,
            &medium::volume_io::NrrdWriteOptions {
                comments,
                units: Some("length".into()),
                spacings: Some([solution.medium.grid().cell_size; 3]),
                gzip: false,
            },
        )?,
        "raw" => {
            medium::volume_io::write_raw_f32(&args.output, &volume)?;
            let sidecar = args.output.with_extension("json");
            let meta = serde_json::json!({
                "field": field_name,
                "units": units,
                "dims": dims,
                "order": "x fastest: index = i + nx * (j + ny * k)",
                "dtype": "float32 little-endian",
                "cell_size": solution.medium.grid().cell_size,
                "channel": args.channel,
            });
            medium::atomic_file::write_bytes(
                &sidecar,
                serde_json::to_string_pretty(&meta)?.as_bytes(),
            )
            .with_context(|| format!("writing {}", sidecar.display()))?;
            println!("wrote {}", sidecar.display());
        }
        _ => bail!(
            "{}: unknown extension `{ext}` (expected .raw or .nrrd)",
            args.output.display()
        ),
    }
    println!("wrote {}", args.output.display());
    Ok(())
}

/// `volrad validate`: every method on the sample scenes, written as a report.
pub fn validate(args: &crate::cli::ValidateArgs, quiet: bool) -> Result<()> {
    use crate::validate::{parse_methods, ValidateMethod, ValidateOptions, ValidateSettings};
    let methods = if args.methods.is_empty() {
        ValidateMethod::ALL.to_vec()
    } else {
        parse_methods(&args.methods)?
    };
    let scenes = if args.scenes.is_empty() {
        let defaults: Vec<std::path::PathBuf> = crate::validate::DEFAULT_SCENES
            .iter()
            .map(std::path::PathBuf::from)
            .collect();
        if let Some(missing) = defaults.iter().find(|p| !p.is_file()) {
            bail!(
                "default scene {} not found: run from the repository root or give --scene FILE",
                missing.display()
            );
        }
        defaults
    } else {
        args.scenes.clone()
    };
    let mut settings = ValidateSettings::new(args.quick);
    if args.spp == Some(0) {
        bail!("--spp must be at least 1");
    }
    if let Some(n) = args.reference_spp {
        if n < 2 {
            bail!(
                "--reference-spp {n}: at least 2 paths per pixel are needed for a standard error"
            );
        }
        settings.reference_spp = n;
    }
    if let Some(n) = args.spp {
        settings.render_spp = n;
    }
    match args.views {
        Some(0) => bail!("--views must be at least 1"),
        Some(n) if n > 360 => bail!("--views {n}: at most 360 views per scene"),
        Some(n) => settings.views = n,
        None => {}
    }
    let variations = args
        .vary
        .iter()
        .map(|v| crate::validate::parse_variation(v))
        .collect::<Result<Vec<_>>>()?;
    let command = std::iter::once("volrad".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    let options = ValidateOptions {
        scenes,
        variations,
        methods,
        out: args.output.clone(),
        settings,
        quiet,
    };
    let started = Instant::now();
    let report = crate::validate::run(&options, &command)?;
    if !quiet {
        for scene in &report.scenes {
            for m in &scene.methods {
                let worst = m.worst_view();
                eprintln!(
                    "{:<24} {:<20} {:>6.2} % vs path tracer (worst of {} views: {})",
                    scene.name,
                    m.method.name(),
                    100.0 * worst.vs_path_tracer.relative_rms,
                    m.views.len(),
                    worst.camera
                );
            }
        }
        eprintln!("validated in {:.1} s", started.elapsed().as_secs_f64());
    }
    println!("wrote {}", options.out.join("report.md").display());
    Ok(())
}

/// `volrad compare BEFORE AFTER`: how far AFTER is from BEFORE over the pixels whose grey
/// value (the mean of the channels) in BEFORE is above `--above` times BEFORE's peak — the
/// relative RMS difference and mean difference ([`montecarlo::compare::compare_images`]) and the
/// largest difference as a share of the peak ([`montecarlo::compare::largest_difference`]).
/// Either image may be PFM or EXR ([`gather::image_io::read_image`]). What docs/performance.md quotes
/// when a change to the renderer moves the images by so much.
pub fn compare(args: &CompareArgs) -> Result<()> {
    // The error names the file (its source, an io::Error, only once).
    let read = |p: &Path| {
        gather::image_io::read_image(p)
            .map(grey)
            .map_err(|e| anyhow::anyhow!("{e}"))
    };
    let (before, after) = (read(&args.before)?, read(&args.after)?);
    // The comparison checks the sizes; the context names the files.
    let context = || {
        format!(
            "comparing {} (image) with {} (reference)",
            args.after.display(),
            args.before.display()
        )
    };
    let c = montecarlo::compare::compare_images(&after, None, &before, None, args.above, 1)
        .map_err(anyhow::Error::msg)
        .with_context(context)?;
    let largest = montecarlo::compare::largest_difference(&after, &before, args.above)
        .map_err(anyhow::Error::msg)
        .with_context(context)?;
    println!(
        "{} pixels above {} of the peak: RMS {:.3} %, mean {:+.3} %, largest {:.3} % of the peak",
        c.pixels,
        args.above,
        100.0 * c.relative_rms_raw,
        100.0 * c.relative_mean_difference,
        100.0 * largest
    );
    Ok(())
}

/// The mean of `image`'s channels at each pixel, as a one-channel image.
fn grey(image: gather::Image) -> gather::Image {
    if image.channels == 1 {
        return image;
    }
    let n = image.channels as usize;
    let pixels = image
        .pixels
        .chunks_exact(n)
        .map(|p| (p.iter().map(|&v| v as f64).sum::<f64>() / n as f64) as f32)
        .collect();
    gather::Image {
        channels: 1,
        pixels,
        ..image
    }
}

pub fn load_scene(path: &Path) -> Result<Scene> {
    Ok(Scene::from_file(path)?)
}

/// `volrad info`.
pub fn info(args: &InfoArgs) -> Result<()> {
    let mut scene = load_scene(&args.scene)?;
    scene.solve = args.overrides.apply(&scene.solve)?;
    let report = crate::info::SceneInfo::of(&scene);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{report}");
    }
    Ok(())
}
