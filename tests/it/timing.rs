//! The predicted solve time (`engine::timing`): its iteration counts against the iterations
//! solves take, on media the model was not fitted to — thin and thick, grey and white,
//! isotropic and forward-scattering, a cloud (larger than the probe's coarse copy) and a
//! wide slab, stationary and Krylov iterations.

use std::path::Path;

use scene::Scene;
use volrad::engine::budget::Occupancy;
use volrad::engine::methods::SolveSummary;
use volrad::engine::pipeline::solve_scene;
use volrad::engine::timing::solve_time;
use volrad::engine::SolveHooks;

/// A scene of a generated cloud (`slab: false`) or a uniform slab 4 cells thick spanning the
/// grid (`slab: true`) solved by `method` with `extra` `[solve]` lines.
fn scene(slab: bool, sigma_t: f64, albedo: f64, g: f64, method: &str, extra: &str) -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let volume = if slab {
        let cells = 40 * 40 * 4;
        let bytes: Vec<u8> = (0..cells)
            .flat_map(|_| (sigma_t as f32).to_le_bytes())
            .collect();
        std::fs::write(dir.path().join("slab.f32"), bytes).unwrap();
        "file = \"slab.f32\"\ndims = [40, 40, 4]".to_string()
    } else {
        // Larger than the probe's copy (`engine::timing::probe`), so it is measured on a
        // coarser one.
        format!(
            "generator = {{ kind = \"cloud\", seed = 3 }}\ndims = [48, 48, 36]\nsigma_t_scale = {sigma_t}"
        )
    };
    let text = format!(
        r#"
[volume]
{volume}

[medium]
albedo = {albedo}
phase = {{ kind = "henyey-greenstein", g = {g} }}

[[light]]
kind = "directional"
direction = [-0.3, -0.4, -1.0]
irradiance = 1.0

[solve]
method = "{method}"
{extra}
"#
    );
    Scene::from_toml_str(&text, dir.path(), Path::new("timing-test.toml")).unwrap()
}

/// The iterations a solve took (the first channel's) and those the model predicted.
fn iterations(scene: &Scene) -> (usize, usize) {
    let occupancy = Occupancy::of(&scene.medium);
    let predicted = solve_time(scene, &scene.solve, &occupancy, 2)
        .iterations()
        .expect("an iterative method");
    let solution = solve_scene(scene, &scene.solve, &SolveHooks::default()).unwrap();
    let summary = SolveSummary::of(&solution, 0.0);
    (summary.channels[0].iterations, predicted)
}

#[test]
fn predicted_iterations_follow_the_solves() {
    // (slab, σt scale, albedo, g, method, [solve] lines)
    let cases = [
        (false, 0.3, 0.99, 0.0, "discrete-ordinates", "bins = 24"),
        (false, 0.75, 0.9, 0.6, "discrete-ordinates", "bins = 24"),
        (false, 0.15, 0.5, 0.0, "discrete-ordinates", "bins = 24"),
        (true, 1.0, 0.99, 0.0, "discrete-ordinates", "bins = 24"),
        (false, 0.3, 0.99, 0.85, "discrete-ordinates", "bins = 96"),
        (
            false,
            0.5,
            0.9,
            0.6,
            "discrete-ordinates",
            "bins = 24\niteration = \"gmres:8\"\ntolerance = 1e-9",
        ),
        (
            false,
            0.5,
            0.95,
            0.0,
            "zonal-hierarchical",
            r#"iteration = "jacobi""#,
        ),
        (
            false,
            0.5,
            0.95,
            0.0,
            "zonal-hierarchical",
            r#"iteration = "gauss-seidel""#,
        ),
        (
            true,
            2.0,
            0.9,
            0.0,
            "zonal-hierarchical",
            r#"iteration = "jacobi""#,
        ),
    ];
    let mut report = Vec::new();
    let mut ratios = Vec::new();
    for (slab, sigma_t, albedo, g, method, extra) in cases {
        let (taken, predicted) = iterations(&scene(slab, sigma_t, albedo, g, method, extra));
        let ratio = predicted as f64 / taken.max(1) as f64;
        report.push(format!(
            "slab {slab} σt {sigma_t} a {albedo} g {g} {method} {extra}: {taken} taken, \
             {predicted} predicted"
        ));
        ratios.push(ratio);
    }
    eprintln!("{}", report.join("\n"));
    // Within 20 % either way, #19's figure for the time: the iterations are what the time
    // follows (the diffusion estimate before the probe was 0.71–1.53 × on these).
    assert!(
        ratios.iter().all(|r| (1.0 / 1.2..=1.2).contains(r)),
        "{}",
        report.join("\n")
    );
}

#[test]
fn the_prediction_runs_on_the_machines_measured_clock() {
    use volrad::engine::timing::solve_time_at_speed;
    let scene = scene(false, 0.3, 0.9, 0.6, "discrete-ordinates", "bins = 24");
    let occupancy = Occupancy::of(&scene.medium);
    let at = |machine| solve_time_at_speed(&scene, &scene.solve, &occupancy, 2, machine);
    let (reference, slower) = (at(Some(1.0)), at(Some(2.5)));
    // Every part is on the machine's clock: the whole scales by the factor, the iterations
    // (measured on the probe's copy) do not.
    let ratio = slower.total().as_secs_f64() / reference.total().as_secs_f64();
    assert!((ratio - 2.5).abs() < 1e-3, "{ratio}");
    assert_eq!(slower.iterations(), reference.iterations());
    assert!(
        slower.to_string().contains("2.50× the model's time"),
        "{slower}"
    );
    assert!(!at(None).to_string().contains("the model's time"));
}

#[test]
fn the_machines_factor_is_given_measured_or_one() {
    use volrad::engine::timing::{kernel_seconds, machine_factor_from};
    // The kernel runs and takes time (how much depends on the machine and its load).
    let seconds = kernel_seconds().expect("the kernel's operator builds");
    assert!(seconds > 0.0 && seconds < 1.0, "{seconds}");
    // A factor given is taken as it is, and not measured; one that is not a positive number
    // is not taken.
    let never = || -> Option<f64> { panic!("measured although a factor was given") };
    assert_eq!(machine_factor_from(Some("1.5"), never), 1.5);
    assert_eq!(machine_factor_from(Some(" 0.8 "), never), 0.8);
    // A measurement (2 and 4 ms: this machine's kernel takes about 2.5 ms) scales by the
    // reference.
    let measured = machine_factor_from(None, || Some(0.002));
    let twice = machine_factor_from(None, || Some(0.004));
    assert!(measured > 0.25 && measured < 4.0, "{measured}");
    assert!((twice / measured - 2.0).abs() < 1e-12, "{twice} {measured}");
    for bad in ["fast", "-1", "0", "NaN", "inf"] {
        assert_eq!(machine_factor_from(Some(bad), || Some(0.002)), measured);
    }
    // One far outside the bounds (a disturbed window), or none, gives 1.
    assert_eq!(machine_factor_from(None, || Some(100.0)), 1.0);
    assert_eq!(machine_factor_from(None, || Some(1e-9)), 1.0);
    assert_eq!(machine_factor_from(None, || None), 1.0);
}

/// A solve cancelled while its time is predicted stops there: the probe's iterations on the
/// coarse copy (seconds on a grid of many distinct σt, where Python's Ctrl-C waited for them)
/// see the cancellation, and the solve fails as cancelled before it starts.
#[test]
fn a_solve_cancelled_in_its_prediction_stops_there() {
    // Every cell its own σt (1 … 3 per cell, thick): the probe's copy is the grid itself, and
    // its iterations take seconds (the test prints how many).
    let cells = 24 * 24 * 20;
    let bytes: Vec<u8> = (0..cells)
        .flat_map(|i: u32| {
            (1.0 + 2.0 * ((i.wrapping_mul(2_654_435_761) >> 8) as f32 / 16_777_216.0)).to_le_bytes()
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("thick.f32"), bytes).unwrap();
    let text = r#"
[volume]
file = "thick.f32"
dims = [24, 24, 20]

[medium]
albedo = 0.999

[[light]]
kind = "directional"
direction = [0.0, 0.0, -1.0]
irradiance = 1.0

[solve]
method = "discrete-ordinates"
tolerance = 1e-12
max_iterations = 100000
"#;
    let scene = Scene::from_toml_str(text, dir.path(), Path::new("thick.toml")).unwrap();
    let occupancy = Occupancy::of(&scene.medium);
    let control = solver::SolveControl::default();
    control.cancel();
    let started = std::time::Instant::now();
    let predicted = volrad::engine::timing::solve_time_cancellable(
        &scene,
        &scene.solve,
        &occupancy,
        2,
        &control,
    );
    let seconds = started.elapsed().as_secs_f64();
    assert!(
        !predicted.probed(),
        "a cancelled prediction probed the medium"
    );
    assert!(
        seconds < 1.0,
        "the cancelled prediction took {seconds:.1} s"
    );
    let probe = |control| volrad::engine::timing::probe(&scene, &scene.solve, control);
    assert_eq!(probe(&control), None);
    // Cancelled while it runs (Ctrl-C half a second in), the probe stops within about a
    // second (its power iteration checks before each of its up to 60 applications; it took
    // no cancellation before, and the probe stopped 3.1 s in beside the other tests); not
    // cancelled it runs on for seconds (11 s beside other tests) and measures the medium.
    let running = solver::SolveControl::default();
    let flag = running.flag();
    let started = std::time::Instant::now();
    let probed = std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(std::time::Duration::from_millis(500));
            flag.store(true, std::sync::atomic::Ordering::Relaxed);
        });
        probe(&running)
    });
    let seconds = started.elapsed().as_secs_f64();
    assert_eq!(probed, None);
    assert!(
        seconds < 3.0,
        "the probe stopped {seconds:.1} s after it started"
    );

    let hooks = SolveHooks {
        control: std::sync::Arc::new(control),
        on_prediction: Some(std::sync::Arc::new(
            |_: &volrad::engine::timing::TimeEstimate| {},
        )),
        ..SolveHooks::default()
    };
    let started = std::time::Instant::now();
    let error = solve_scene(&scene, &scene.solve, &hooks).unwrap_err();
    let seconds = started.elapsed().as_secs_f64();
    assert!(format!("{error:#}").contains("cancelled"), "{error:#}");
    assert!(seconds < 1.0, "the cancelled solve took {seconds:.1} s");
}
