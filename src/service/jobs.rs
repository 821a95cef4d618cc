//! The scene registry and the solve worker: one solve at a time on a dedicated thread, with
//! progress and cancellation through [`SolveHooks`]; solutions are written to the cache and
//! kept in memory behind an `Arc` for the renderers.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};

use anyhow::{Context, Result};
use medium::environment::EnvironmentSpec;
use scene::Scene;
use serde_json::{json, Value};

use super::cache::{self, CacheDir};
use super::{Limits, ServiceConfig};
use crate::engine::budget::{LimitSource, MemoryLimit};
use crate::engine::pipeline::{scene_hash, solve_scene};
use crate::engine::solution::Solution;
use crate::engine::SolveHooks;

/// Where a scene is in its life.
#[derive(Clone, Debug, PartialEq)]
pub enum JobState {
    Queued,
    /// `phase` says what the solve does (a light pass, building the operator, iterating);
    /// `iteration` and `residual` are the iteration's latest (0 and NaN before the first).
    Solving {
        phase: String,
        iteration: usize,
        residual: f64,
    },
    Done,
    Failed {
        reason: String,
    },
}

impl JobState {
    pub fn name(&self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Solving { .. } => "solving",
            JobState::Done => "done",
            JobState::Failed { .. } => "failed",
        }
    }
}

/// One scene the server knows.
pub(crate) struct Job {
    /// The validated scene, when its text is known (it may not be, after a restart that found
    /// only a solution file).
    pub scene: Option<Arc<Scene>>,
    pub state: JobState,
    pub solution: Option<Arc<Solution>>,
    /// Control of the current (or next) solve; replaced for each new solve.
    pub control: Arc<solver::SolveControl>,
    /// Bytes of the cached solution file (0 when none).
    pub file_bytes: u64,
    /// Recency stamp for LRU eviction (larger is more recent).
    pub last_used: u64,
    /// A note for people, e.g. that a corrupt cache file was found and is being re-solved.
    pub note: Option<String>,
    /// What people call it (`?name=` of the upload, a preloaded file's stem); stored beside
    /// the scene (`ID.name`).
    pub name: Option<String>,
    /// The predicted time of the running solve (`engine::timing`), seconds.
    pub predicted_seconds: Option<f64>,
}

enum WorkerMsg {
    Solve(String),
    Stop,
}

pub(crate) struct Inner {
    pub cache: CacheDir,
    pub limits: Limits,
    pub jobs: Mutex<HashMap<String, Job>>,
    pub render_slots: Arc<tokio::sync::Semaphore>,
    /// Render requests waiting for a slot (bounded by `limits.max_waiting_renders`).
    pub waiting_renders: std::sync::atomic::AtomicUsize,
    clock: AtomicU64,
    queue: Mutex<Option<mpsc::Sender<WorkerMsg>>>,
    worker: Mutex<Option<std::thread::JoinHandle<()>>>,
    /// Serialises writes into `volumes/` with their eviction.
    pub volume_lock: Mutex<()>,
}

/// The service: a cheap handle (an `Arc`) shared by the handlers and the worker.
#[derive(Clone)]
pub struct Service {
    pub(crate) inner: Arc<Inner>,
}

/// What the cache holds for one scene id after a restart.
struct Recovered {
    scene: Option<Arc<Scene>>,
    state: JobState,
    solution: Option<Arc<Solution>>,
    note: Option<String>,
    bytes: u64,
    /// The scene is known but has no valid solution: solve it again.
    requeue: bool,
    name: Option<String>,
}

/// Reads one id's scene and solution back from the cache: a valid solution is served, a
/// corrupt one deleted (and solved again when its scene is known, else reported as failed),
/// a scene without a solution queued; `None` when there is nothing to recover.
fn recover(cache: &CacheDir, id: &str) -> Option<Recovered> {
    let scene = match std::fs::read_to_string(cache.scene_path(id)) {
        Ok(text) => match parse_scene(cache, &text) {
            Ok(s) => Some(Arc::new(s)),
            Err(e) => {
                tracing::warn!("cache: scene {id} no longer parses: {e}");
                None
            }
        },
        Err(_) => None,
    };
    let sol_path = cache.solution_path(id);
    let (state, solution, note, bytes, requeue) = if sol_path.exists() {
        match Solution::read(&sol_path) {
            Ok(sol) => (
                JobState::Done,
                Some(Arc::new(sol)),
                None,
                cache::file_len(&sol_path),
                false,
            ),
            Err(e) => {
                let _ = std::fs::remove_file(&sol_path);
                let note = format!("the cached solution was corrupt and was deleted: {e}");
                tracing::warn!("cache: {id}: {note}");
                if scene.is_some() {
                    (
                        JobState::Queued,
                        None,
                        Some(format!("{note}; solving again")),
                        0,
                        true,
                    )
                } else {
                    (
                        JobState::Failed {
                            reason: format!("corrupt: {note}"),
                        },
                        None,
                        Some(note),
                        0,
                        false,
                    )
                }
            }
        }
    } else if scene.is_some() {
        (JobState::Queued, None, None, 0, true)
    } else {
        return None;
    };
    Some(Recovered {
        scene,
        state,
        solution,
        note,
        bytes,
        requeue,
        name: read_name(cache, id),
    })
}

/// A scene's stored name, when it has a valid one.
fn read_name(cache: &CacheDir, id: &str) -> Option<String> {
    let text = std::fs::read_to_string(cache.name_path(id)).ok()?;
    crate::service::routes::check_scene_name(text.trim_end()).ok()
}

/// Most solution files one lookup of an unknown id reads from a shared cache directory.
const MAX_ADOPTED_PER_LOOKUP: usize = 4;

/// Shortest id prefix the API accepts for a scene (the viewer shows 12 characters).
pub const MIN_ID_PREFIX: usize = 8;

/// The id of a scene: its content hash, the one `volrad solve` prints and stores in the
/// solution file ([`scene_hash`]: medium, lights, background, solve settings). Cameras and
/// render settings are views of the solution, not part of its identity: a scene posted again
/// with other cameras is the same scene, and keeps the cameras it was first posted with.
pub fn scene_id(scene: &Scene) -> String {
    scene_hash(scene)
}

/// Parses scene text the way the service stores it: volume files resolve inside `volumes/`.
pub(crate) fn parse_scene(cache: &CacheDir, text: &str) -> Result<Scene, scene::SceneError> {
    Scene::from_toml_str(text, &cache.volumes_dir(), Path::new("scene"))
}

impl Service {
    /// Opens (or creates) the cache directory, loads what it holds and starts the worker.
    /// Valid solutions are served; a corrupt one is deleted and, when its scene text is
    /// known, queued to be solved again, otherwise reported as failed. Temporary files
    /// abandoned by a writer killed mid-write are deleted once stale
    /// ([`CacheDir::remove_stale_temp_files`]).
    pub fn open(config: ServiceConfig) -> Result<Service> {
        let cache = CacheDir::open(&config.cache_dir)?;
        cache.remove_stale_temp_files(cache::STALE_TEMP_AGE);
        let (tx, rx) = mpsc::channel();
        let inner = Arc::new(Inner {
            cache: cache.clone(),
            limits: config.limits.clone(),
            jobs: Mutex::new(HashMap::new()),
            render_slots: Arc::new(tokio::sync::Semaphore::new(config.render_slots.max(1))),
            waiting_renders: std::sync::atomic::AtomicUsize::new(0),
            clock: AtomicU64::new(1),
            queue: Mutex::new(Some(tx)),
            worker: Mutex::new(None),
            volume_lock: Mutex::new(()),
        });
        let service = Service { inner };
        let mut requeue = Vec::new();
        // Solutions read from the cache, to be prepared for rendering off the startup path.
        let mut loaded = Vec::new();
        for id in cache.known_ids() {
            let Some(Recovered {
                scene,
                state,
                solution,
                note,
                bytes,
                requeue: again,
                name,
            }) = recover(&cache, &id)
            else {
                continue;
            };
            if again {
                requeue.push(id.clone());
            }
            if let Some(sol) = &solution {
                loaded.push((id.clone(), Arc::downgrade(sol)));
            }
            let stamp = service.tick();
            service.lock().insert(
                id,
                Job {
                    scene,
                    state,
                    solution,
                    control: Arc::new(solver::SolveControl::new()),
                    file_bytes: bytes,
                    last_used: stamp,
                    note,
                    name,
                    predicted_seconds: None,
                },
            );
        }
        let worker_service = service.clone();
        let handle = std::thread::Builder::new()
            .name("volrad-solve".into())
            .spawn(move || worker_service.worker(rx))
            .context("spawning the solve worker")?;
        *service
            .inner
            .worker
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(handle);
        for id in requeue {
            service.enqueue(&id);
        }
        service.prepare_in_background(loaded);
        Ok(service)
    }

    /// Builds the render caches of solutions found in the cache directory on a thread of their
    /// own, as a finished solve does before it reports done, so that the first view after a
    /// restart costs what later ones do. Not at startup (each build can cost more than a
    /// render, and the server should answer at once) and not on the solve worker (solves would
    /// wait). A render that comes first builds the cache itself, or waits for the build in
    /// progress; solutions deleted or evicted meanwhile are skipped.
    fn prepare_in_background(&self, loaded: Vec<(String, std::sync::Weak<Solution>)>) {
        if loaded.is_empty() {
            return;
        }
        let service = self.clone();
        let spawned = std::thread::Builder::new()
            .name("volrad-prepare".into())
            .spawn(move || {
                let started = std::time::Instant::now();
                for (id, solution) in loaded {
                    if service.is_shut_down() {
                        return;
                    }
                    let Some(solution) = solution.upgrade() else {
                        continue;
                    };
                    let prepared = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        solution.prepare_renders()
                    }));
                    if prepared.is_err() {
                        tracing::warn!(
                            "preparing renders of {id} panicked; its renders will retry"
                        );
                    }
                }
                tracing::info!(
                    "prepared cached solutions for rendering in {:.2} s",
                    started.elapsed().as_secs_f64()
                );
            });
        if let Err(e) = spawned {
            // Renders then build each cache on first use, as before.
            tracing::warn!("not preparing cached solutions for rendering: {e}");
        }
    }

    /// Whether [`Service::shutdown`] has run (the solve queue is closed).
    fn is_shut_down(&self) -> bool {
        self.inner
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .is_none()
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, HashMap<String, Job>> {
        // A panic while holding the lock cannot leave a job half-updated in a way that matters
        // more than refusing every later request would.
        self.inner.jobs.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(crate) fn tick(&self) -> u64 {
        self.inner.clock.fetch_add(1, Ordering::Relaxed)
    }

    pub fn scene_count(&self) -> usize {
        self.lock().len()
    }

    /// The full id of a known scene given its id or a unique prefix of at least
    /// [`MIN_ID_PREFIX`] characters (what the viewer shows). `Err` names the candidates when
    /// the prefix is ambiguous; `Ok(None)` when nothing matches.
    ///
    /// An id this instance does not know may name a solution another instance sharing the
    /// cache directory wrote since: such solutions are adopted first ([`Service::adopt`]).
    pub fn resolve(&self, id: &str) -> Result<Option<String>, Vec<String>> {
        match self.resolve_known(id)? {
            Some(full) => Ok(Some(full)),
            None if self.adopt(id) > 0 => self.resolve_known(id),
            None => Ok(None),
        }
    }

    /// [`Service::resolve`] among the scenes this instance already holds.
    fn resolve_known(&self, id: &str) -> Result<Option<String>, Vec<String>> {
        let jobs = self.lock();
        if jobs.contains_key(id) {
            return Ok(Some(id.to_string()));
        }
        if id.len() < MIN_ID_PREFIX {
            return Ok(None);
        }
        let mut matches: Vec<String> = jobs.keys().filter(|k| k.starts_with(id)).cloned().collect();
        match matches.len() {
            0 => Ok(None),
            1 => Ok(matches.pop()),
            _ => {
                matches.sort();
                Err(matches)
            }
        }
    }

    /// Registers, as done, the valid solution files in the cache directory whose ids begin
    /// with `prefix` (at least [`MIN_ID_PREFIX`] characters) and that this instance does not
    /// hold: several instances sharing one cache directory (README, "Several instances")
    /// serve each other's solutions. Only finished solutions are adopted — a scene text without its
    /// solution may be solving elsewhere, and is left alone. Returns how many were adopted.
    pub fn adopt(&self, prefix: &str) -> usize {
        if prefix.len() < MIN_ID_PREFIX {
            return 0;
        }
        let cache = &self.inner.cache;
        let candidates: Vec<String> = {
            let jobs = self.lock();
            if jobs.contains_key(prefix) {
                return 0;
            }
            if cache.solution_path(prefix).is_file() {
                // A whole id: no need to list the directory.
                vec![prefix.to_string()]
            } else {
                cache
                    .known_ids()
                    .into_iter()
                    .filter(|id| id.starts_with(prefix) && !jobs.contains_key(id))
                    .filter(|id| cache.solution_path(id).is_file())
                    // A bound on the work one request can cause; a prefix this loose is
                    // ambiguous anyway.
                    .take(MAX_ADOPTED_PER_LOOKUP)
                    .collect()
            }
        };
        let mut adopted = 0;
        for id in candidates {
            let Some(found) = recover(cache, &id) else {
                continue;
            };
            let Some(solution) = found.solution else {
                continue;
            };
            let stamp = self.tick();
            let mut jobs = self.lock();
            if jobs.contains_key(&id) {
                continue;
            }
            tracing::info!("cache: serving {id}, solved by another instance");
            jobs.insert(
                id.clone(),
                Job {
                    scene: found.scene,
                    state: JobState::Done,
                    solution: Some(solution),
                    control: Arc::new(solver::SolveControl::new()),
                    file_bytes: found.bytes,
                    last_used: stamp,
                    note: None,
                    name: found.name,
                    predicted_seconds: None,
                },
            );
            evict(&mut jobs, cache, self.inner.limits.max_cache_bytes, &id);
            adopted += 1;
        }
        adopted
    }

    /// Updates the phase, iteration and residual of scene `id` while it is solving (a cancel
    /// or a delete may have ended that meanwhile: then nothing changes).
    fn update_solving(&self, id: &str, update: impl FnOnce(&mut String, &mut usize, &mut f64)) {
        if let Some(Job {
            state:
                JobState::Solving {
                    phase,
                    iteration,
                    residual,
                },
            ..
        }) = self.lock().get_mut(id)
        {
            update(phase, iteration, residual);
        }
    }

    /// What one solve may use: the per-solve limit, or less when the machine has less
    /// available now (renders and other solutions hold memory too).
    pub(crate) fn solve_memory_limit(&self) -> MemoryLimit {
        let configured = MemoryLimit {
            bytes: self.inner.limits.max_solve_bytes as u64,
            source: LimitSource::Service,
        };
        match MemoryLimit::given_or_available(None) {
            Some(available) if available.bytes < configured.bytes => available,
            _ => configured,
        }
    }

    /// State of scene `id`, if known.
    pub fn state(&self, id: &str) -> Option<JobState> {
        self.lock().get(id).map(|j| j.state.clone())
    }

    fn enqueue(&self, id: &str) {
        if let Some(tx) = self
            .inner
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
        {
            let _ = tx.send(WorkerMsg::Solve(id.to_string()));
        }
    }

    /// Registers a validated scene (text already checked against the limits) and queues its
    /// solve. Returns the id and whether a new solve was queued.
    pub(crate) fn submit(&self, scene: Scene, text: &str) -> Result<(String, bool), SubmitError> {
        let id = scene_id(&scene);
        // Solved already by another instance sharing the cache directory: served, not solved.
        // (A stat first: a new scene, the common case, costs no directory listing.)
        if self.inner.cache.solution_path(&id).is_file() && self.adopt(&id) > 0 {
            let mut jobs = self.lock();
            if let Some(job) = jobs.get_mut(&id) {
                if job.scene.is_none() {
                    job.scene = Some(Arc::new(scene));
                    cache::write_atomic(&self.inner.cache.scene_path(&id), text.as_bytes())
                        .map_err(|e| SubmitError::Storage(format!("{e:#}")))?;
                }
                return Ok((id, false));
            }
        }
        let mut jobs = self.lock();
        if let Some(job) = jobs.get_mut(&id) {
            // The same scene again is the same job; a failed or evicted one is tried again.
            let retry = matches!(job.state, JobState::Failed { .. }) && job.solution.is_none();
            if job.scene.is_none() {
                job.scene = Some(Arc::new(scene));
                cache::write_atomic(&self.inner.cache.scene_path(&id), text.as_bytes())
                    .map_err(|e| SubmitError::Storage(format!("{e:#}")))?;
            }
            if retry {
                job.state = JobState::Queued;
                job.control = Arc::new(solver::SolveControl::new());
                job.note = None;
                drop(jobs);
                self.enqueue(&id);
            }
            return Ok((id, retry));
        }
        if jobs.len() >= self.inner.limits.max_scenes {
            return Err(SubmitError::TooMany(self.inner.limits.max_scenes));
        }
        cache::write_atomic(&self.inner.cache.scene_path(&id), text.as_bytes())
            .map_err(|e| SubmitError::Storage(format!("{e:#}")))?;
        let stamp = self.tick();
        jobs.insert(
            id.clone(),
            Job {
                scene: Some(Arc::new(scene)),
                state: JobState::Queued,
                solution: None,
                control: Arc::new(solver::SolveControl::new()),
                file_bytes: 0,
                last_used: stamp,
                note: None,
                name: None,
                predicted_seconds: None,
            },
        );
        drop(jobs);
        self.enqueue(&id);
        Ok((id, true))
    }

    /// Names scene `id` (no effect if it is unknown); the name is stored beside its scene,
    /// so it survives a restart (a name that cannot be stored is kept while the service runs).
    pub fn set_name(&self, id: &str, name: String) {
        if let Some(job) = self.lock().get_mut(id) {
            if let Err(e) = cache::write_atomic(&self.inner.cache.name_path(id), name.as_bytes()) {
                tracing::warn!("cache: the name of {id} is not stored: {e:#}");
            }
            job.name = Some(name);
        }
    }

    /// Cancels a queued or running solve. `None` for an unknown id, else whether there was
    /// anything to cancel.
    pub fn cancel(&self, id: &str) -> Option<bool> {
        let mut jobs = self.lock();
        let job = jobs.get_mut(id)?;
        match job.state {
            JobState::Queued | JobState::Solving { .. } => {
                job.control.cancel();
                job.state = JobState::Failed {
                    reason: "cancelled".into(),
                };
                Some(true)
            }
            _ => Some(false),
        }
    }

    /// Forgets scene `id`: cancels its solve and deletes its files. False when unknown.
    pub fn delete(&self, id: &str) -> bool {
        let removed = self.lock().remove(id);
        match removed {
            Some(job) => {
                job.control.cancel();
                let _ = std::fs::remove_file(self.inner.cache.solution_path(id));
                let _ = std::fs::remove_file(self.inner.cache.scene_path(id));
                let _ = std::fs::remove_file(self.inner.cache.name_path(id));
                true
            }
            None => false,
        }
    }

    /// The solution of a finished scene, marked as just used.
    pub fn solution(&self, id: &str) -> Option<Arc<Solution>> {
        let stamp = self.tick();
        let mut jobs = self.lock();
        let job = jobs.get_mut(id)?;
        job.last_used = stamp;
        job.solution.clone()
    }

    /// Stops the worker (cancelling a running solve) and waits for it.
    pub fn shutdown(&self) {
        for job in self.lock().values() {
            if matches!(job.state, JobState::Solving { .. }) {
                job.control.cancel();
            }
        }
        if let Some(tx) = self
            .inner
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            let _ = tx.send(WorkerMsg::Stop);
        }
        let handle = self
            .inner
            .worker
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some(h) = handle {
            let _ = h.join();
        }
    }

    fn worker(self, rx: mpsc::Receiver<WorkerMsg>) {
        while let Ok(WorkerMsg::Solve(id)) = rx.recv() {
            self.solve_one(&id);
        }
    }

    fn solve_one(&self, id: &str) {
        let (scene, control) = {
            let mut jobs = self.lock();
            let Some(job) = jobs.get_mut(id) else { return };
            if job.state != JobState::Queued || job.control.is_cancelled() {
                return;
            }
            let Some(scene) = job.scene.clone() else {
                job.state = JobState::Failed {
                    reason: "the scene text is not known".into(),
                };
                return;
            };
            job.state = JobState::Solving {
                phase: "starting".into(),
                iteration: 0,
                residual: f64::NAN,
            };
            (scene, Arc::clone(&job.control))
        };
        let (predict_service, predict_id) = (self.clone(), id.to_string());
        let (phase_service, phase_id) = (self.clone(), id.to_string());
        let (progress_service, progress_id) = (self.clone(), id.to_string());
        let solve_control = solver::SolveControl::with_flag(control.flag())
            .with_phase(move |name| {
                phase_service.update_solving(&phase_id, |phase, _, _| *phase = name.to_string())
            })
            .with_progress(move |iteration, residual| {
                progress_service.update_solving(&progress_id, |_, i, r| {
                    *i = iteration;
                    *r = residual;
                })
            });
        let hooks = SolveHooks {
            control: Arc::new(solve_control),
            memory_limit: Some(self.solve_memory_limit()),
            on_prediction: Some(Arc::new(
                move |predicted: &crate::engine::timing::TimeEstimate| {
                    if let Some(job) = predict_service.lock().get_mut(&predict_id) {
                        job.predicted_seconds = Some(predicted.total().as_secs_f64());
                    }
                },
            )),
        };
        let started = std::time::Instant::now();
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            solve_scene(&scene, &scene.solve, &hooks)
        }));
        let outcome: Result<Solution, String> = match outcome {
            Ok(Ok(sol)) => Ok(sol),
            Ok(Err(e)) => Err(format!("{e:#}")),
            Err(_) => Err("the solver panicked (a bug; please report the scene)".into()),
        };
        if control.is_cancelled() {
            return; // cancel() or delete() already set the state (or removed the job)
        }
        let path = self.inner.cache.solution_path(id);
        let outcome = outcome.and_then(|sol| {
            // A full disk or a file-size limit fails here (ENOSPC, EFBIG): the temporary file
            // is removed, nothing is stored under the final name, and this scene alone fails.
            sol.write(&path).map_err(|e| {
                format!(
                    "the solve finished but writing its solution to the cache failed, so \
                     nothing was stored (POST the scene again to retry): {e}"
                )
            })?;
            // Before "done": the first view then costs what every later one does.
            sol.prepare_renders();
            Ok(sol)
        });
        let stamp = self.tick();
        let mut jobs = self.lock();
        let Some(job) = jobs.get_mut(id) else {
            let _ = std::fs::remove_file(&path);
            return;
        };
        match outcome {
            Ok(sol) => {
                tracing::info!("solved {id} in {:.2} s", started.elapsed().as_secs_f64());
                job.state = JobState::Done;
                job.solution = Some(Arc::new(sol));
                job.file_bytes = cache::file_len(&path);
                job.last_used = stamp;
            }
            Err(reason) => {
                job.state = JobState::Failed { reason };
            }
        }
        evict(
            &mut jobs,
            &self.inner.cache,
            self.inner.limits.max_cache_bytes,
            id,
        );
    }
}

/// Deletes least recently used solution files (never `keep`) until the total fits `max`.
/// Evicted scenes stay known (their text is kept) and are solved again when posted again.
fn evict(jobs: &mut HashMap<String, Job>, cache: &CacheDir, max: u64, keep: &str) {
    let mut total: u64 = jobs.values().map(|j| j.file_bytes).sum();
    while total > max {
        let victim = jobs
            .iter()
            .filter(|(id, j)| j.file_bytes > 0 && id.as_str() != keep)
            .min_by_key(|(_, j)| j.last_used)
            .map(|(id, _)| id.clone());
        let Some(victim) = victim else { break };
        let job = jobs.get_mut(&victim).expect("victim exists");
        let _ = std::fs::remove_file(cache.solution_path(&victim));
        total -= job.file_bytes;
        job.file_bytes = 0;
        job.solution = None;
        job.state = JobState::Failed {
            reason: "evicted from the cache (least recently used); POST the scene again to solve it again"
                .into(),
        };
        tracing::info!("cache: evicted {victim}");
    }
}

/// Why a scene could not be registered.
#[derive(Debug)]
pub(crate) enum SubmitError {
    TooMany(usize),
    Storage(String),
}

/// JSON summary of one scene (the body of `GET /v1/scenes/{id}`).
pub(crate) fn describe(id: &str, job: &Job, with_history: bool) -> Value {
    let mut v = json!({ "id": id, "state": job.state.name() });
    if let Some(name) = &job.name {
        v["name"] = json!(name);
    }
    match &job.state {
        JobState::Solving {
            phase,
            iteration,
            residual,
        } => {
            v["phase"] = json!(phase);
            if let Some(t) = job.predicted_seconds {
                v["predicted_seconds"] = json!(t);
            }
            v["iteration"] = json!(iteration);
            v["residual"] = if residual.is_finite() {
                json!(residual)
            } else {
                Value::Null
            };
        }
        JobState::Failed { reason } => v["reason"] = json!(reason),
        _ => {}
    }
    if let Some(note) = &job.note {
        v["note"] = json!(note);
    }
    let dims = job
        .solution
        .as_ref()
        .map(|s| s.medium.grid().dims)
        .or_else(|| job.scene.as_ref().map(|s| s.medium.grid().dims));
    if let Some(d) = dims {
        v["dims"] = json!(d);
    }
    if let Some(scene) = &job.scene {
        v["method"] = json!(scene.solve.method.name());
    }
    // The sky's keys, for the viewer's light controls (`relight` changes them).
    let environment = job
        .solution
        .as_ref()
        .and_then(|s| s.environment.clone())
        .or_else(|| job.scene.as_ref().and_then(|s| s.environment.clone()));
    let ground = job
        .solution
        .as_ref()
        .and_then(|s| s.ground.as_ref().map(|g| *g.ground()))
        .or_else(|| job.scene.as_ref().and_then(|s| s.ground));
    if let Some(g) = &ground {
        v["ground"] = json!({ "height": g.height(), "albedo": g.albedo_rgb() });
    }
    if let Some(EnvironmentSpec::Sky(sky)) = environment.map(|e| e.spec()) {
        v["sky"] = json!({
            "sun_elevation_degrees": sky.sun_elevation_degrees,
            "sun_azimuth_degrees": sky.sun_azimuth_degrees,
            "turbidity": sky.turbidity,
            "sky_fraction": sky.sky_fraction,
            // Under a [ground] the sky's own ground is hidden; relight changes the [ground]'s.
            "ground_albedo": ground.map_or(sky.ground_albedo, |g| medium::environment::luminance(&g.albedo_rgb())),
        });
    }
    if let Some(sol) = &job.solution {
        let channels: Vec<Value> = sol
            .channels
            .iter()
            .map(|ch| match &ch.report {
                Some(r) => {
                    let mut rv = json!({
                        "iteration": r.method,
                        "iterations": r.iterations,
                        "converged": r.converged,
                        "final_residual": r.final_residual,
                        "seconds": r.seconds,
                        "stop_reason": r.stop_reason.name(),
                    });
                    if with_history {
                        rv["residual_history"] = json!(r
                            .residual_history
                            .iter()
                            .map(|x| if x.is_finite() { json!(x) } else { Value::Null })
                            .collect::<Vec<_>>());
                    }
                    rv
                }
                None => Value::Null,
            })
            .collect();
        let g = sol.medium.grid();
        let extent: Vec<f64> = g.dims.iter().map(|&n| n as f64 * g.cell_size).collect();
        v["method"] = json!(sol.method.name());
        v["report"] = json!({
            "method": sol.method.name(),
            "channels": channels,
        });
        v["extent"] = json!(extent);
        v["cameras"] = serde_json::to_value(&sol.cameras).unwrap_or(Value::Null);
        v["exposure"] = json!(sol.render.exposure);
    }
    v
}
