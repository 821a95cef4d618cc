//! `volrad serve`: an HTTP service that solves scenes once on a background worker, keeps the
//! solutions in a cache directory, and renders many views of them concurrently.
//!
//! Layout: [`routes`] (HTTP handlers and the JSON error type), [`jobs`] (the scene registry and
//! the solve worker), [`cache`] (files on disk: solutions, scene texts, uploaded volumes),
//! [`client`] (a minimal loopback HTTP/1.1 client for tests and the load test). The OpenAPI
//! description and the viewer page are embedded files beside this one.
//!
//! A session (ids are content hashes: posting the same scene again returns the same id):
//!
//! ```text
//! volrad serve --addr 127.0.0.1:8080 --cache ./volrad-cache &
//! curl -s -X POST --data-binary @cloud.toml localhost:8080/v1/scenes
//!   {"id":"16e252f6…","state":"queued","queued":true,…}                        (202)
//! curl -s localhost:8080/v1/scenes/16e252f6…
//!   {"state":"solving","iteration":7,"residual":0.0019,…} … {"state":"done","report":{…}}
//! curl -s -o view.png 'localhost:8080/v1/scenes/16e252f6…/render?eye=5,-20,4&width=512&height=384'
//! curl -s -X POST --data-binary @density.f32 'localhost:8080/v1/volumes?dims=24,24,18'
//!   {"file":"c4af7a3e….f32","dims":[24,24,18]}   → use as `[volume] file = "c4af7a3e….f32"`
//! curl -s -X POST localhost:8080/v1/scenes/16e252f6…/cancel
//! curl -s -X DELETE localhost:8080/v1/scenes/16e252f6…                          (204)
//! ```
//!
//! Raw volumes are uploaded on their own (`POST /v1/volumes?dims=…`, stored by content hash
//! under `volumes/`) and named by the scene's `[volume] file`; a scene may not name any
//! other file. Every valid solution in the cache directory is loaded at start-up and kept in
//! memory; renders share it through an `Arc`. A background thread then builds each loaded
//! solution's render cache (the first bounce's light-depth model), as a fresh solve does
//! before it reports done.

pub mod cache;
pub mod client;
pub mod jobs;
pub mod routes;
pub mod slice;

use anyhow::{Context, Result};
use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

pub use jobs::{JobState, Service};

/// Caps on what one request may ask for; each is refused with a 4xx JSON error when exceeded.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest request body (scene text or volume upload), bytes.
    pub max_body_bytes: usize,
    /// Largest grid, nx·ny·nz.
    pub max_cells: usize,
    /// Largest image side, pixels.
    pub max_image_side: u32,
    /// Largest image, width·height.
    pub max_image_pixels: u64,
    /// Largest samples per pixel of a render.
    pub max_spp: u32,
    /// Largest `[solve] bins`.
    pub max_bins: usize,
    /// Largest `[solve] max_iterations`.
    pub max_iterations: usize,
    /// Largest memory a solve may need (the estimate of `volrad info`), bytes.
    pub max_solve_bytes: usize,
    /// Largest number of render requests waiting for a slot; more are refused with 503.
    pub max_waiting_renders: usize,
    /// Largest number of scenes the server keeps track of.
    pub max_scenes: usize,
    /// Total size of cached solution files; least recently used ones are evicted beyond it.
    pub max_cache_bytes: u64,
    /// Total size of uploaded volumes; oldest ones are evicted beyond it.
    pub max_volume_bytes: u64,
    /// Longest a client may take to send a request's head (request line and headers), and
    /// again its body. A connection whose head is late is closed (an idle kept-alive one
    /// too); a late body is answered 408. A slow client holds only its own connection, and
    /// only this long.
    pub request_read_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_body_bytes: 64 << 20,
            max_cells: 4_000_000,
            max_image_side: 4096,
            max_image_pixels: 4096 * 4096,
            max_spp: 64,
            max_bins: 384,
            max_iterations: 10_000,
            max_solve_bytes: 2 << 30,
            max_waiting_renders: 64,
            max_scenes: 1000,
            max_cache_bytes: 2 << 30,
            max_volume_bytes: 1 << 30,
            request_read_timeout: Duration::from_secs(30),
        }
    }
}

/// Everything the service needs to start.
#[derive(Clone, Debug)]
pub struct ServiceConfig {
    pub cache_dir: PathBuf,
    pub limits: Limits,
    /// Renders running at once (each also uses the rayon pool); default: the core count.
    pub render_slots: usize,
}

impl ServiceConfig {
    pub fn new(cache_dir: impl Into<PathBuf>) -> Self {
        ServiceConfig {
            cache_dir: cache_dir.into(),
            limits: Limits::default(),
            render_slots: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(2),
        }
    }
}

/// A server running on its own tokio runtime in a background thread (tests, embedding).
pub struct ServerHandle {
    pub addr: SocketAddr,
    pub service: Service,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ServerHandle {
    /// Opens the cache, binds `addr` (port 0 picks a free one) and serves in the background.
    pub fn start(config: ServiceConfig, addr: &str) -> Result<ServerHandle> {
        let read_timeout = config.limits.request_read_timeout;
        let service = Service::open(config)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .context("starting the tokio runtime")?;
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(addr))
            .with_context(|| format!("binding {addr}"))?;
        let local = listener.local_addr()?;
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let app = routes::router(service.clone());
        let thread = std::thread::Builder::new()
            .name("volrad-http".into())
            .spawn(move || {
                runtime.block_on(async move {
                    serve(listener, app, read_timeout, async move {
                        let _ = rx.await;
                    })
                    .await;
                });
                runtime.shutdown_timeout(std::time::Duration::from_secs(2));
            })
            .context("spawning the server thread")?;
        Ok(ServerHandle {
            addr: local,
            service,
            shutdown: Some(tx),
            thread: Some(thread),
        })
    }

    /// Stops accepting requests, cancels a running solve and waits for both to end.
    pub fn stop(mut self) {
        self.stop_inner();
    }

    fn stop_inner(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.service.shutdown();
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        self.stop_inner();
    }
}

/// Serves `app` on `listener` until `shutdown` completes, then lets requests in progress
/// finish and returns. What `axum::serve` does, with HTTP/1.1 connections built here so that
/// a request's head has a deadline (hyper's `header_read_timeout`, which needs a timer that
/// `axum::serve` does not give it): a client that connects and sends nothing, or its headers
/// a byte at a time, is cut off after `read_timeout` instead of holding its connection (and
/// a task, and a file descriptor) forever. The body's deadline is [`routes::router`]'s.
pub async fn serve(
    listener: tokio::net::TcpListener,
    app: axum::Router,
    read_timeout: Duration,
    shutdown: impl Future<Output = ()>,
) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;

    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(read_timeout);
    // Connections hold a receiver each; closing them and waiting for the sender to see
    // none left is the graceful shutdown.
    let (closing_tx, closing_rx) = tokio::sync::watch::channel(false);
    tokio::pin!(shutdown);
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            () = &mut shutdown => break,
        };
        let stream = match accepted {
            Ok((stream, _peer)) => stream,
            Err(e) => {
                // Out of file descriptors, or a connection reset before it was accepted:
                // wait a moment (as axum::serve does) instead of spinning.
                tracing::warn!("accepting a connection: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let service = TowerToHyperService::new(app.clone());
        let http = http.clone();
        let mut closing = closing_rx.clone();
        tokio::spawn(async move {
            let conn = http.serve_connection(TokioIo::new(stream), service);
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => {}
                _ = closing.changed() => {
                    conn.as_mut().graceful_shutdown();
                    let _ = conn.await;
                }
            }
            drop(closing);
        });
    }
    drop(listener);
    drop(closing_rx);
    let _ = closing_tx.send(true);
    closing_tx.closed().await;
}

/// A scene file given to `volrad serve`, read before the service starts.
pub struct Preload {
    /// The file's stem: the scene's name in lists and the viewer.
    pub name: String,
    pub scene: scene::Scene,
    /// The file's text, stored as an uploaded scene's is.
    pub text: String,
}

impl Preload {
    /// Reads and checks `path` (errors name the file).
    pub fn read(path: &std::path::Path) -> Result<Preload> {
        let scene = scene::Scene::from_file(path)?;
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        let name = routes::check_scene_name(&name).map_err(|e| anyhow::anyhow!(e))?;
        Ok(Preload { name, scene, text })
    }
}

/// `volrad serve`: serves until Ctrl-C.
pub fn run(config: ServiceConfig, addr: &str, quiet: bool) -> Result<()> {
    run_with(config, addr, quiet, Vec::new())
}

/// [`run`], first submitting `preload` (solved in order unless the cache holds them).
pub fn run_with(
    config: ServiceConfig,
    addr: &str,
    quiet: bool,
    preload: Vec<Preload>,
) -> Result<()> {
    // A write beyond the file-size limit (RLIMIT_FSIZE: `ulimit -f`, a container's or a
    // supervisor's limit) raises SIGXFSZ, whose default action kills the process: every
    // client would lose the server, and solves in progress, over one large solution file.
    // Ignored, the write fails with EFBIG instead, and that solve alone reports it.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to SIG_IGN has no handler to run.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let service = Service::open(config.clone())?;
    for p in preload {
        crate::engine::budget::check_solve(
            &p.scene,
            &p.scene.solve,
            Some(service.solve_memory_limit()),
        )
        .with_context(|| format!("scene `{}`", p.name))?;
        let (id, _) = service.submit(p.scene, &p.text).map_err(|e| match e {
            jobs::SubmitError::TooMany(n) => {
                anyhow::anyhow!("scene `{}`: the cache already holds {n} scenes", p.name)
            }
            jobs::SubmitError::Storage(m) => anyhow::anyhow!("scene `{}`: {m}", p.name),
        })?;
        service.set_name(&id, p.name);
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the tokio runtime")?;
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("binding {addr}"))?;
        let local = listener.local_addr()?;
        if !quiet {
            eprintln!(
                "volrad serve: http://{local}/ (cache {}, {} scenes known)",
                config.cache_dir.display(),
                service.scene_count()
            );
        }
        let app = routes::router(service.clone());
        serve(listener, app, config.limits.request_read_timeout, async {
            let _ = tokio::signal::ctrl_c().await;
        })
        .await;
        anyhow::Ok(())
    })?;
    service.shutdown();
    Ok(())
}

/// `volrad serve` from its command-line arguments.
/// `max_memory` is `--max-memory`: the limit of each solve (default 2 GiB, or what the
/// machine has available when that is less).
pub fn run_cli(args: &crate::cli::ServeArgs, quiet: bool, max_memory: Option<u64>) -> Result<()> {
    let mut config = ServiceConfig::new(&args.cache);
    config.limits.max_body_bytes = args.max_body_bytes;
    config.limits.max_cells = args.max_cells;
    config.limits.max_image_side = args.max_image_side;
    config.limits.max_spp = args.max_spp;
    config.limits.max_iterations = args.max_iterations;
    if let Some(bytes) = max_memory {
        config.limits.max_solve_bytes = usize::try_from(bytes).unwrap_or(usize::MAX);
    }
    config.limits.max_cache_bytes = args.max_cache_mib.saturating_mul(1 << 20);
    config.limits.request_read_timeout = Duration::from_secs_f64(args.request_timeout_secs);
    if let Some(n) = args.render_slots {
        config.render_slots = n.max(1);
    }
    // Scene files are read and checked before anything starts.
    let preload = args
        .scenes
        .iter()
        .map(|p| Preload::read(p))
        .collect::<Result<Vec<_>>>()?;
    run_with(config, &args.addr, quiet, preload)
}
