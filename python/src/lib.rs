//! `volrad._volrad`: volrad from Python. A thin front end over the root crate's engine, as
//! the command line and the service are: scenes read from files or built from numpy arrays,
//! solved with the GIL released (Ctrl-C cancels), stored solutions loaded and saved, and
//! views rendered into numpy arrays bit-identical to `volrad render`'s.
//!
//! The core types:
//! - [`PyScene`] (`volrad.Scene`): a validated scene, from a file, TOML text, or arrays.
//! - [`PySolution`] (`volrad.Solution`): a solved scene; renders views, gives per-cell fields.
//! - `volrad.VolradError`: every refusal, with the message the command line prints.
//!
//! Arrays follow numpy's C order with x fastest, as volrad's cells are numbered
//! (`i + nx (j + ny k)`, docs/physics.md): a volume is `(nz, ny, nx)`, an image `(H, W)` or
//! `(H, W, 3)` with the top row first — Mitsuba's layout.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyBytes, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use volrad::commands::SolveOverrides;
use volrad::engine::budget::{parse_size, MemoryLimit};
use volrad::engine::methods::{
    convergence_warnings, export_field, refuse_cancelled, ExportField, SolveSummary,
};
use volrad::engine::pipeline::{render_view_through, solve_scene, view_medium};
use volrad::engine::solution::Solution;
use volrad::engine::SolveHooks;
use volrad::progress::SolveProgress;
use volrad::views::CameraRequest;

pyo3::create_exception!(
    _volrad,
    VolradError,
    PyException,
    "A scene, volume, solution file or request volrad refuses; the message is the command line's."
);

/// The command line's one-line message (`error: …` without the prefix), as an exception.
fn refuse(err: anyhow::Error) -> PyErr {
    VolradError::new_err(format!("{err:#}"))
}

/// How often a waiting call looks for Ctrl-C (Python runs signal handlers only when the
/// main thread holds the GIL, so a solve polls for them from the calling thread).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// The name a scene built from arrays is given in messages (where a file's path would be).
const ARRAY_SCENE_LABEL: &str = "<volrad.Scene>";

/// A validated scene: a medium with its lights, solve settings and cameras.
///
/// `Scene.from_file(path)` reads a scene file (docs/scene-format.md); `Scene(sigma_t, …)`
/// builds one from an extinction array of shape `(nz, ny, nx)` and the scene file's keys as
/// Python values.
#[pyclass(name = "Scene", module = "volrad", frozen)]
struct PyScene {
    scene: Arc<scene::Scene>,
}

#[pymethods]
impl PyScene {
    /// A scene from arrays and scene-file values. `sigma_t` is the extinction per cell (1 /
    /// length) with shape `(nz, ny, nx)`; every other argument is the scene file's key of
    /// the same name with the same meaning (dicts for tables, lists for arrays of tables).
    #[new]
    #[pyo3(signature = (
        sigma_t, *, cell_size = None, albedo = None, phase = None, emission = None,
        lights = None, background = None, ground = None, method = None, solve = None,
        render = None, cameras = None, interpolation = None, base_dir = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        sigma_t: &Bound<'_, PyAny>,
        cell_size: Option<&Bound<'_, PyAny>>,
        albedo: Option<&Bound<'_, PyAny>>,
        phase: Option<&Bound<'_, PyAny>>,
        emission: Option<&Bound<'_, PyAny>>,
        lights: Option<&Bound<'_, PyAny>>,
        background: Option<&Bound<'_, PyAny>>,
        ground: Option<&Bound<'_, PyAny>>,
        method: Option<&Bound<'_, PyAny>>,
        solve: Option<&Bound<'_, PyAny>>,
        render: Option<&Bound<'_, PyAny>>,
        cameras: Option<&Bound<'_, PyAny>>,
        interpolation: Option<&Bound<'_, PyAny>>,
        base_dir: Option<PathBuf>,
    ) -> PyResult<Self> {
        let data = volume_from_array(py, sigma_t)?;
        let mut root = toml::Table::new();
        let mut volume = toml::Table::new();
        put(&mut volume, "cell_size", cell_size, "cell_size")?;
        put(&mut volume, "interpolation", interpolation, "interpolation")?;
        root.insert("volume".into(), toml::Value::Table(volume));
        let mut medium = toml::Table::new();
        put(&mut medium, "albedo", albedo, "albedo")?;
        put(&mut medium, "phase", phase, "phase")?;
        put(&mut medium, "emission", emission, "emission")?;
        root.insert("medium".into(), toml::Value::Table(medium));
        put(&mut root, "light", lights, "lights")?;
        put(&mut root, "background", background, "background")?;
        put(&mut root, "ground", ground, "ground")?;
        put(&mut root, "render", render, "render")?;
        put(&mut root, "camera", cameras, "cameras")?;
        let mut solve_table = match solve {
            Some(s) => match to_toml(s, "solve")? {
                toml::Value::Table(t) => t,
                _ => {
                    return Err(VolradError::new_err(
                        "solve: expected a dict of [solve] keys",
                    ))
                }
            },
            None => toml::Table::new(),
        };
        put(&mut solve_table, "method", method, "method")?;
        if !solve_table.is_empty() {
            root.insert("solve".into(), toml::Value::Table(solve_table));
        }
        let text = toml::to_string(&root)
            .map_err(|e| VolradError::new_err(format!("the scene's values: {e}")))?;
        let base = base_dir.unwrap_or_else(|| PathBuf::from("."));
        let scene = py
            .detach(|| {
                scene::Scene::with_volume_data(&text, data, &base, Path::new(ARRAY_SCENE_LABEL))
            })
            .map_err(|e| refuse(e.into()))?;
        Ok(PyScene {
            scene: Arc::new(scene),
        })
    }

    /// Reads and validates a scene file (TOML, docs/scene-format.md); volume paths inside
    /// are relative to the file's folder.
    #[staticmethod]
    fn from_file(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let scene = py
            .detach(|| volrad::commands::load_scene(&path))
            .map_err(refuse)?;
        Ok(PyScene {
            scene: Arc::new(scene),
        })
    }

    /// Validates scene text; relative volume paths are resolved against `base_dir`.
    #[staticmethod]
    #[pyo3(signature = (text, base_dir = None))]
    fn from_toml(py: Python<'_>, text: &str, base_dir: Option<PathBuf>) -> PyResult<Self> {
        let base = base_dir.unwrap_or_else(|| PathBuf::from("."));
        let scene = py
            .detach(|| scene::Scene::from_toml_str(text, &base, Path::new("<scene text>")))
            .map_err(|e| refuse(e.into()))?;
        Ok(PyScene {
            scene: Arc::new(scene),
        })
    }

    /// The built-in scene of `volrad` with no arguments (a sky-lit cloud).
    #[staticmethod]
    fn builtin() -> PyResult<Self> {
        let scene = volrad::commands::default_scene().map_err(refuse)?;
        Ok(PyScene {
            scene: Arc::new(scene),
        })
    }

    /// Cells along x, y, z.
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let [x, y, z] = self.scene.medium.grid().dims;
        (x, y, z)
    }

    /// The edge length of a cell.
    #[getter]
    fn cell_size(&self) -> f64 {
        self.scene.medium.grid().cell_size
    }

    /// Colour channels (1 grey, 3 RGB).
    #[getter]
    fn channels(&self) -> usize {
        self.scene.medium.channels().len()
    }

    /// `[solve] method`.
    #[getter]
    fn method(&self) -> &'static str {
        self.scene.solve.method.name()
    }

    /// The scene's camera names, in file order.
    #[getter]
    fn cameras(&self) -> Vec<String> {
        self.scene.cameras.iter().map(|c| c.name.clone()).collect()
    }

    /// The content hash a solution of this scene stores (`volrad info` prints it).
    #[getter]
    fn scene_hash(&self) -> String {
        volrad::engine::pipeline::scene_hash(&self.scene)
    }

    /// What `volrad info` prints for the scene: sizes, lights, predicted memory and time.
    fn info(&self) -> String {
        volrad::info::SceneInfo::of(&self.scene).to_string()
    }

    /// Solves the light transport. `method`, `iteration`, `tolerance` and `max_iterations`
    /// override `[solve]` as `volrad solve`'s flags do. The GIL is released while it runs;
    /// Ctrl-C (KeyboardInterrupt) cancels it. `progress` shows the command line's spinner.
    /// `max_memory` (bytes, or a size such as `"4G"`) is `--max-memory`: a solve predicted to
    /// need more — by default, more than the machine has available — is refused before it
    /// starts, saying what would fit. `transport_scale` (`"auto"` or 1..=16) overrides
    /// `[solve] transport_scale`: multiple scattering on blocks of N³ data cells.
    #[pyo3(signature = (method = None, *, iteration = None, tolerance = None, max_iterations = None, progress = false, max_memory = None, transport_scale = None))]
    #[allow(clippy::too_many_arguments)]
    fn solve(
        &self,
        py: Python<'_>,
        method: Option<&str>,
        iteration: Option<&str>,
        tolerance: Option<f64>,
        max_iterations: Option<usize>,
        progress: bool,
        max_memory: Option<&Bound<'_, PyAny>>,
        transport_scale: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PySolution> {
        let transport_scale = transport_scale
            .map(|t| {
                let text = match t.extract::<usize>() {
                    Ok(n) => n.to_string(),
                    Err(_) => t.extract::<String>().map_err(|_| {
                        VolradError::new_err("transport_scale: expected \"auto\" or a whole number")
                    })?,
                };
                text.parse::<scene::TransportScale>()
                    .map_err(|e| VolradError::new_err(format!("transport_scale: {e}")))
            })
            .transpose()?;
        let max_memory = match max_memory {
            None => None,
            Some(m) if m.is_instance_of::<PyString>() => Some(
                parse_size(&m.extract::<String>()?)
                    .map_err(|e| VolradError::new_err(format!("max_memory: {e}")))?,
            ),
            Some(m) => Some(m.extract::<u64>().map_err(|_| {
                VolradError::new_err(
                    "max_memory: expected a number of bytes or a size such as \"4G\"",
                )
            })?),
        };
        let overrides = SolveOverrides {
            method: method
                .map(|m| m.parse::<scene::SolveMethod>())
                .transpose()
                .map_err(|e| VolradError::new_err(format!("method: {e}")))?,
            iteration: iteration
                .map(|m| m.parse::<solver::Method>())
                .transpose()
                .map_err(|e| VolradError::new_err(format!("iteration: {e}")))?,
            tolerance,
            max_iterations,
            transport_scale,
        };
        let settings = overrides.apply(&self.scene.solve).map_err(refuse)?;
        let started = Instant::now();
        let bar = SolveProgress::start(&settings, !progress);
        let hooks = SolveHooks {
            control: Arc::new(bar.control()),
            memory_limit: MemoryLimit::given_or_available(max_memory),
            on_prediction: Some(bar.prediction()),
        };
        let scene = &self.scene;
        let outcome = run_cancellable(py, &hooks.control, || solve_scene(scene, &settings, &hooks));
        bar.finish();
        let solution = outcome?.map_err(refuse)?;
        refuse_cancelled(&solution).map_err(refuse)?;
        let seconds = started.elapsed().as_secs_f64();
        for message in convergence_warnings(&solution) {
            let category = py.get_type::<pyo3::exceptions::PyRuntimeWarning>();
            PyErr::warn(py, &category, &std::ffi::CString::new(message)?, 1)?;
        }
        Ok(PySolution {
            solution: Arc::new(solution),
            solve_seconds: Some(seconds),
        })
    }

    fn __repr__(&self) -> String {
        let [x, y, z] = self.scene.medium.grid().dims;
        format!(
            "volrad.Scene({x}×{y}×{z} cells of {}, {} channel(s), method {})",
            self.scene.medium.grid().cell_size,
            self.scene.medium.channels().len(),
            self.scene.solve.method.name()
        )
    }
}

/// A solved scene: the first-bounce light and the solved scattered field, the medium, lights
/// and cameras — what `volrad solve` writes and `volrad render --solution` reads.
#[pyclass(name = "Solution", module = "volrad", frozen)]
struct PySolution {
    solution: Arc<Solution>,
    /// Wall time of the solve that made it (`None` for a loaded solution).
    solve_seconds: Option<f64>,
}

impl PySolution {
    fn loaded(solution: Solution) -> Self {
        PySolution {
            solution: Arc::new(solution),
            solve_seconds: None,
        }
    }
}

#[pymethods]
impl PySolution {
    /// Reads a solution file (`volrad solve -o FILE`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let solution = py
            .detach(|| Solution::read(&path))
            .map_err(|e| refuse(e.into()))?;
        Ok(PySolution::loaded(solution))
    }

    /// A solution from the bytes of a solution file (as `to_bytes` gives them).
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<Self> {
        let solution = py
            .detach(|| Solution::from_bytes(data, Path::new("<bytes>")))
            .map_err(|e| refuse(e.into()))?;
        Ok(PySolution::loaded(solution))
    }

    /// Writes the solution file (atomically: a crash leaves the old file or none).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let solution = &self.solution;
        py.detach(|| solution.write(&path)).map_err(|e| {
            refuse(anyhow::Error::from(e).context(format!("writing {}", path.display())))
        })
    }

    /// The bytes of the solution file.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let solution = &self.solution;
        let bytes = py.detach(|| solution.to_bytes());
        PyBytes::new(py, &bytes)
    }

    /// Pickling (Ray, multiprocessing) carries the solution file's bytes.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let py = slf.py();
        let from_bytes = py.get_type::<PySolution>().getattr("from_bytes")?;
        let bytes = slf.get().to_bytes(py);
        PyTuple::new(
            py,
            [from_bytes.into_any(), PyTuple::new(py, [bytes])?.into_any()],
        )
    }

    /// Renders one view into a float32 array of radiance, `(H, W)` grey or `(H, W, 3)` RGB,
    /// top row first. `camera` is a scene camera's name, or a dict of camera keys (`name`,
    /// `eye`, `target`, `up`, `fov_y_degrees`, `width`, `height`), or `None` for the first
    /// camera; keyword arguments override its parts as `volrad render`'s flags do. The same
    /// view as `volrad render --solution … -o view.pfm`, bit for bit.
    #[pyo3(signature = (
        camera = None, *, eye = None, target = None, up = None, fov_y_degrees = None,
        width = None, height = None, spp = None, extinction_scale = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        camera: Option<&Bound<'py, PyAny>>,
        eye: Option<[f64; 3]>,
        target: Option<[f64; 3]>,
        up: Option<[f64; 3]>,
        fov_y_degrees: Option<f64>,
        width: Option<u32>,
        height: Option<u32>,
        spp: Option<u32>,
        extinction_scale: Option<f32>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let mut request = camera_argument(camera)?;
        let overrides = CameraRequest {
            name: None,
            eye: eye.map(glam::DVec3::from),
            target: target.map(glam::DVec3::from),
            up: up.map(glam::DVec3::from),
            fov_y_degrees,
            width,
            height,
        };
        request.merge(&overrides);
        let solution = &self.solution;
        let image = py
            .detach(|| -> anyhow::Result<gather::Image> {
                let view = request.camera(&solution.cameras, solution.medium.grid())?;
                // As `volrad render` does before its views (the service bounds image sizes
                // by its own limits): a camera too large for memory is refused, not aborted.
                volrad::engine::budget::check_image(
                    view.width,
                    view.height,
                    solution.channels.len(),
                    MemoryLimit::given_or_available(None),
                )?;
                let medium = view_medium(solution, extinction_scale)?;
                render_view_through(solution, &medium, &view, spp)
            })
            .map_err(refuse)?;
        let (h, w, c) = (
            image.height as usize,
            image.width as usize,
            image.channels as usize,
        );
        // The pixels move into numpy without a copy; the reshape is a view of them.
        let flat = PyArray1::from_vec(py, image.pixels);
        let shaped = if c == 1 {
            flat.reshape([h, w])?.into_any()
        } else {
            flat.reshape([h, w, c])?.into_any()
        };
        Ok(shaped)
    }

    /// `n` cameras on a horizontal circle around `camera`'s target (the same as `volrad
    /// render --orbit n`), keeping its distance, elevation and image: a list of camera dicts
    /// for `render`, in order. `camera` is as in `render` (a name, a dict or `None`).
    #[pyo3(signature = (n, camera = None))]
    fn orbit<'py>(
        &self,
        py: Python<'py>,
        n: u32,
        camera: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        if n == 0 {
            return Err(VolradError::new_err("orbit: n must be at least 1"));
        }
        let request = camera_argument(camera)?;
        let base = request
            .camera(&self.solution.cameras, self.solution.medium.grid())
            .map_err(refuse)?;
        volrad::views::orbit_cameras(&base, n)
            .into_iter()
            .map(|cam| {
                let d = PyDict::new(py);
                // A stored camera's name carries what a dict cannot say (an orthographic
                // projection); the keys below override the rest of it.
                if let Some(name) = &request.name {
                    d.set_item("name", name)?;
                }
                d.set_item("eye", cam.eye.to_array())?;
                d.set_item("target", cam.target.to_array())?;
                d.set_item("up", cam.up.to_array())?;
                if let gather::Projection::Perspective { fov_y_degrees } = cam.projection {
                    d.set_item("fov_y_degrees", fov_y_degrees)?;
                }
                d.set_item("width", cam.width)?;
                d.set_item("height", cam.height)?;
                Ok(d)
            })
            .collect()
    }

    /// A per-cell field as a float32 array `(nz, ny, nx)` for one channel, or `(nz, ny, nx,
    /// C)` for all channels of an RGB solution when `channel` is `None`. Fields are those of
    /// `volrad export`: `fluence` (∫ I dω: unscattered, emitted and scattered light),
    /// `source` (the solved source, radiance per length) and `sigma-t` (extinction).
    #[pyo3(signature = (name, channel = None))]
    fn field<'py>(
        &self,
        py: Python<'py>,
        name: &str,
        channel: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let field: ExportField = name
            .parse()
            .map_err(|e: String| VolradError::new_err(format!("field: {e}")))?;
        let [nx, ny, nz] = self.solution.medium.grid().dims;
        let solution = &self.solution;
        let channels = solution.channels.len();
        let values = py
            .detach(|| -> anyhow::Result<Vec<f32>> {
                match channel {
                    Some(c) => Ok(export_field(solution, c, field)?.0),
                    None if channels == 1 => Ok(export_field(solution, 0, field)?.0),
                    None => {
                        let per_channel = (0..channels)
                            .map(|c| export_field(solution, c, field).map(|(v, _)| v))
                            .collect::<anyhow::Result<Vec<_>>>()?;
                        // Channel last, as Mitsuba's volume grids and the images are.
                        let cells = per_channel[0].len();
                        let mut interleaved = Vec::with_capacity(cells * channels);
                        for i in 0..cells {
                            interleaved.extend(per_channel.iter().map(|v| v[i]));
                        }
                        Ok(interleaved)
                    }
                }
            })
            .map_err(|e| refuse(e.context(format!("field `{name}`"))))?;
        let flat = PyArray1::from_vec(py, values);
        let per_cell = flat.len() / (nx * ny * nz).max(1);
        Ok(if per_cell == 1 {
            flat.reshape([nz, ny, nx])?.into_any()
        } else {
            flat.reshape([nz, ny, nx, per_cell])?.into_any()
        })
    }

    /// Cells along x, y, z.
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let [x, y, z] = self.solution.medium.grid().dims;
        (x, y, z)
    }

    /// The edge length of a cell.
    #[getter]
    fn cell_size(&self) -> f64 {
        self.solution.medium.grid().cell_size
    }

    /// Colour channels (1 grey, 3 RGB).
    #[getter]
    fn channels(&self) -> usize {
        self.solution.channels.len()
    }

    /// The solve method that made it.
    #[getter]
    fn method(&self) -> &'static str {
        self.solution.method.name()
    }

    /// The stored scene cameras' names.
    #[getter]
    fn cameras(&self) -> Vec<String> {
        self.solution
            .cameras
            .iter()
            .map(|c| c.name.clone())
            .collect()
    }

    /// The content hash of the scene it was solved from.
    #[getter]
    fn scene_hash(&self) -> String {
        self.solution.scene_hash.clone()
    }

    /// What `volrad solve --json` prints, as a dict: the method, the scene hash, seconds
    /// (`None` for a loaded file) and per channel the iteration, its count, the final relative
    /// residual, whether it converged, and its seconds.
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        // The command line's own JSON (a NaN time is `null`), so the two cannot drift apart.
        let summary = SolveSummary::of(&self.solution, self.solve_seconds.unwrap_or(f64::NAN));
        let json = serde_json::to_string(&summary)
            .map_err(|e| VolradError::new_err(format!("report: {e}")))?;
        py.import("json")?.call_method1("loads", (json,))
    }

    /// The per-cell fields (`fluence`, `source`, `sigma_t`) as an xarray Dataset with cell
    /// centres as coordinates (needs xarray installed).
    fn to_xarray<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyAny>> {
        slf.py()
            .import("volrad._xarray")?
            .call_method1("dataset", (slf,))
    }

    fn __repr__(&self) -> String {
        let [x, y, z] = self.solution.medium.grid().dims;
        format!(
            "volrad.Solution({x}×{y}×{z} cells, {} channel(s), method {})",
            self.solution.channels.len(),
            self.solution.method.name()
        )
    }
}

/// Runs `work` on a worker thread with the GIL released, looking for Ctrl-C from the calling
/// thread every [`SIGNAL_POLL`]: a KeyboardInterrupt (or any signal handler's exception)
/// cancels `control`, waits for the work to stop at its next check, and is raised.
fn run_cancellable<T: Send>(
    py: Python<'_>,
    control: &solver::SolveControl,
    work: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    std::thread::scope(|s| {
        let handle = s.spawn(work);
        loop {
            py.detach(|| {
                let deadline = Instant::now() + SIGNAL_POLL;
                while !handle.is_finished() && Instant::now() < deadline {
                    std::thread::sleep(Duration::from_millis(5));
                }
            });
            if handle.is_finished() {
                return handle
                    .join()
                    .map_err(|_| VolradError::new_err("internal error: the solve panicked"));
            }
            if let Err(interrupt) = py.check_signals() {
                control.cancel();
                // The solve stops at its next iteration; its partial result is dropped.
                let _ = py.detach(|| handle.join());
                return Err(interrupt);
            }
        }
    })
}

/// The extinction array as volrad's volume: any array-like numpy can read as float32, shape
/// `(nz, ny, nx)`; copied once into the medium, which owns its cells.
fn volume_from_array(
    py: Python<'_>,
    sigma_t: &Bound<'_, PyAny>,
) -> PyResult<medium::volume_io::VolumeData> {
    let numpy = py.import("numpy")?;
    let float32 = numpy.getattr("float32")?;
    let array = numpy
        .call_method1("ascontiguousarray", (sigma_t, float32))
        .map_err(|e| VolradError::new_err(format!("sigma_t: not an array of numbers ({e})")))?;
    let array = array
        .cast_into::<numpy::PyArrayDyn<f32>>()
        .map_err(|_| VolradError::new_err("sigma_t: not a float32 array"))?;
    let shape = array.shape().to_vec();
    let [nz, ny, nx] = shape[..] else {
        return Err(VolradError::new_err(format!(
            "sigma_t: expected a 3-dimensional array (nz, ny, nx), got shape {shape:?}"
        )));
    };
    let readonly = array.readonly();
    let values = readonly
        .as_slice()
        .map_err(|e| VolradError::new_err(format!("sigma_t: {e}")))?
        .to_vec();
    medium::volume_io::VolumeData::new([nx, ny, nz], values).map_err(|e| refuse(e.into()))
}

/// Puts `value` (when given) under `key`, converted to TOML; `name` is the Python argument.
fn put(
    table: &mut toml::Table,
    key: &str,
    value: Option<&Bound<'_, PyAny>>,
    name: &str,
) -> PyResult<()> {
    if let Some(v) = value.filter(|v| !v.is_none()) {
        table.insert(key.to_string(), to_toml(v, name)?);
    }
    Ok(())
}

/// A Python value as the TOML value a scene file would hold: bool, int, float, str, lists
/// and tuples (arrays), dicts with string keys (tables); numpy scalars and arrays through
/// their Python equivalents.
fn to_toml(value: &Bound<'_, PyAny>, path: &str) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        let v: i64 = value
            .extract()
            .map_err(|_| VolradError::new_err(format!("{path}: integer out of range")))?;
        return Ok(toml::Value::Integer(v));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if let Ok(s) = value.cast::<PyString>() {
        return Ok(toml::Value::String(s.to_str()?.to_string()));
    }
    if let Ok(d) = value.cast::<PyDict>() {
        let mut t = toml::Table::new();
        for (k, v) in d.iter() {
            let key: String = k
                .extract()
                .map_err(|_| VolradError::new_err(format!("{path}: dict keys must be strings")))?;
            if v.is_none() {
                continue;
            }
            let inner = to_toml(&v, &format!("{path}.{key}"))?;
            t.insert(key, inner);
        }
        return Ok(toml::Value::Table(t));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items = value
            .try_iter()?
            .enumerate()
            .map(|(i, item)| to_toml(&item?, &format!("{path}[{i}]")))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    // numpy scalars and small arrays: `tolist()` gives Python numbers and lists.
    if let Ok(plain) = value.call_method0("tolist") {
        if !plain.is(value) {
            return to_toml(&plain, path);
        }
    }
    Err(VolradError::new_err(format!(
        "{path}: a {} cannot be a scene value (expected a number, string, list or dict)",
        value.get_type().name()?
    )))
}

/// `render`'s and `orbit`'s `camera` argument: a stored camera's name, a dict of camera
/// keys, or `None` for the first stored camera.
fn camera_argument(camera: Option<&Bound<'_, PyAny>>) -> PyResult<CameraRequest> {
    match camera {
        None => Ok(CameraRequest::default()),
        Some(c) if c.is_instance_of::<PyString>() => Ok(CameraRequest {
            name: Some(c.extract()?),
            ..CameraRequest::default()
        }),
        Some(c) => camera_request(c.cast::<PyDict>().map_err(|_| {
            VolradError::new_err("camera: expected a camera name, a dict of camera keys or None")
        })?),
    }
}

/// A camera request from a dict of the camera keys `volrad render` takes.
fn camera_request(d: &Bound<'_, PyDict>) -> PyResult<CameraRequest> {
    const KEYS: [&str; 7] = [
        "name",
        "eye",
        "target",
        "up",
        "fov_y_degrees",
        "width",
        "height",
    ];
    for k in d.keys() {
        let k: String = k.extract()?;
        if !KEYS.contains(&k.as_str()) {
            return Err(VolradError::new_err(format!(
                "camera: unknown key `{k}` (expected one of: {})",
                KEYS.join(", ")
            )));
        }
    }
    fn get<'py, T: for<'a> FromPyObject<'a, 'py>>(
        d: &Bound<'py, PyDict>,
        key: &str,
    ) -> PyResult<Option<T>> {
        match d.get_item(key)? {
            Some(v) if !v.is_none() => v
                .extract::<T>()
                .map(Some)
                .map_err(|_| VolradError::new_err(format!("camera: `{key}` has the wrong type"))),
            _ => Ok(None),
        }
    }
    Ok(CameraRequest {
        name: get::<String>(d, "name")?,
        eye: get::<[f64; 3]>(d, "eye")?.map(glam::DVec3::from),
        target: get::<[f64; 3]>(d, "target")?.map(glam::DVec3::from),
        up: get::<[f64; 3]>(d, "up")?.map(glam::DVec3::from),
        fov_y_degrees: get::<f64>(d, "fov_y_degrees")?,
        width: get::<u32>(d, "width")?,
        height: get::<u32>(d, "height")?,
    })
}

/// Writes a rendered image as `volrad render` does, by extension: `.png` tone-mapped with
/// `exposure` (automatic when `None`, as the command line's), `.pfm` and `.exr` linear.
#[pyfunction]
#[pyo3(signature = (image, path, exposure = None))]
fn write_image(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    path: PathBuf,
    exposure: Option<f64>,
) -> PyResult<()> {
    let numpy = py.import("numpy")?;
    let array = numpy
        .call_method1("ascontiguousarray", (image, numpy.getattr("float32")?))?
        .cast_into::<numpy::PyArrayDyn<f32>>()
        .map_err(|_| VolradError::new_err("image: not a float32 array"))?;
    let (height, width, channels) = match array.shape() {
        [h, w] => (*h, *w, 1),
        [h, w, 3] => (*h, *w, 3),
        other => {
            return Err(VolradError::new_err(format!(
                "image: expected shape (H, W) or (H, W, 3), got {other:?}"
            )))
        }
    };
    let pixels = array
        .readonly()
        .as_slice()
        .map_err(|e| VolradError::new_err(format!("image: {e}")))?
        .to_vec();
    let image = gather::Image {
        width: u32::try_from(width).map_err(|_| VolradError::new_err("image: too wide"))?,
        height: u32::try_from(height).map_err(|_| VolradError::new_err("image: too tall"))?,
        channels,
        pixels,
    };
    py.detach(|| {
        let exposure = exposure.unwrap_or_else(|| gather::auto_exposure(&image));
        image
            .save(&path, exposure)
            .map_err(|e| anyhow::Error::from(e).context(format!("writing {}", path.display())))
    })
    .map_err(refuse)
}

#[pymodule]
fn _volrad(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(write_image, m)?)?;
    m.add_class::<PyScene>()?;
    m.add_class::<PySolution>()?;
    m.add("VolradError", m.py().get_type::<VolradError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
