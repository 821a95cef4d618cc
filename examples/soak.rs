//! Soak test of `volrad serve` on loopback: N clients (default 8) for a given time (default
//! 10 minutes) doing what clients do — renders of a solved scene, status polls and listings,
//! posts of a few small scenes (solved, then deleted and posted again), renders of those, and
//! bad requests of every kind — while the server's resident memory is sampled. Every answer
//! is checked against the statuses that request may get; anything else is an error.
//!
//! ```text
//! cargo run --release --example soak -- [--seconds 600] [--clients 8] [--sample-seconds 5]
//! ```
//! The server runs in-process (127.0.0.1:0, a temporary cache directory), so the memory
//! sampled (VmRSS of /proc/self/status) is the server's plus the clients' (small, bounded:
//! latencies go into a fixed histogram). Exits with status 1 on any error. `tests/it/
//! service_faults.rs` runs the same code for a few seconds against the `volrad` binary.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use volrad::service::client::{get, request, HttpResponse};

/// Largest request body the soak's server takes (the oversized bodies exceed it).
pub const MAX_BODY_BYTES: usize = 256 * 1024;

pub struct SoakOptions {
    pub clients: usize,
    pub duration: Duration,
    pub sample_every: Duration,
    /// The server's process, for its memory; `None`: this process.
    pub server_pid: Option<u32>,
}

/// What a soak measured.
#[derive(Debug)]
pub struct Summary {
    pub requests: u64,
    pub errors: u64,
    /// The first few errors, for people.
    pub error_samples: Vec<String>,
    pub seconds: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// Resident memory samples, KiB, first at the start.
    pub rss_kib: Vec<u64>,
    /// Requests by kind, in [`KINDS`] order.
    pub by_kind: Vec<u64>,
}

impl Summary {
    pub fn rss_first(&self) -> u64 {
        self.rss_kib.first().copied().unwrap_or(0)
    }
    pub fn rss_max(&self) -> u64 {
        self.rss_kib.iter().copied().max().unwrap_or(0)
    }
    pub fn rss_last(&self) -> u64 {
        self.rss_kib.last().copied().unwrap_or(0)
    }

    pub fn print(&self) {
        println!(
            "{} requests in {:.0} s ({:.0}/s), {} errors; latency p50 {:.1} ms, p99 {:.1} ms, max {:.0} ms",
            self.requests,
            self.seconds,
            self.requests as f64 / self.seconds.max(1e-9),
            self.errors,
            self.p50_ms,
            self.p99_ms,
            self.max_ms
        );
        let kinds: Vec<String> = KINDS
            .iter()
            .zip(&self.by_kind)
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        println!("by kind: {}", kinds.join(", "));
        println!(
            "RSS: first {:.1} MiB, max {:.1} MiB, last {:.1} MiB ({} samples)",
            self.rss_first() as f64 / 1024.0,
            self.rss_max() as f64 / 1024.0,
            self.rss_last() as f64 / 1024.0,
            self.rss_kib.len()
        );
        let tenths: Vec<String> = (0..=10)
            .map(|i| {
                let k = (i * (self.rss_kib.len() - 1)) / 10;
                format!("{:.0}", self.rss_kib[k] as f64 / 1024.0)
            })
            .collect();
        println!("RSS at each tenth of the run, MiB: {}", tenths.join(" "));
        for e in &self.error_samples {
            println!("error: {e}");
        }
    }
}

/// Kinds of request a client makes, in its cycle's proportions (see `one_request`).
pub const KINDS: [&str; 7] = [
    "render",
    "status",
    "list",
    "post",
    "small render",
    "delete",
    "bad request",
];

/// A scene whose views the clients render (solved once before the soak starts).
pub fn main_scene() -> String {
    small_scene(1000, [16, 16, 12])
}

/// One of the few small scenes clients post, render and delete.
pub fn small_scene(seed: u32, dims: [usize; 3]) -> String {
    let [nx, ny, nz] = dims;
    format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = {seed} }}
dims = [{nx}, {ny}, {nz}]

[medium]
albedo = 0.9
phase = {{ kind = "isotropic" }}

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[solve]
method = "zonal-hierarchical"

[render]
exposure = 4.0
spp = 1

[[camera]]
name = "front"
eye = [8.0, -30.0, 6.0]
target = [8.0, 8.0, 6.0]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 64
height = 48
"#
    )
}

fn post(addr: SocketAddr, text: &str) -> std::io::Result<HttpResponse> {
    request(
        addr,
        "POST",
        "/v1/scenes",
        Some("application/toml"),
        text.as_bytes(),
    )
}

/// Posts the main scene and waits (up to 120 s) until it is solved; returns its id.
pub fn setup(addr: SocketAddr) -> Result<String> {
    let r = post(addr, &main_scene())?;
    if r.status != 202 {
        bail!("posting the main scene: {} {}", r.status, r.text());
    }
    let id = r.json()["id"]
        .as_str()
        .context("no id in the answer")?
        .to_string();
    let started = Instant::now();
    loop {
        let v = get(addr, &format!("/v1/scenes/{id}"))?.json();
        match v["state"].as_str() {
            Some("done") => return Ok(id),
            Some("queued") | Some("solving") => {}
            _ => bail!("the main scene did not solve: {v}"),
        }
        if started.elapsed() > Duration::from_secs(120) {
            bail!("the main scene took over 120 s to solve");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Resident memory of a process (or this one), KiB.
pub fn rss_kib(pid: Option<u32>) -> Option<u64> {
    let path = match pid {
        Some(p) => format!("/proc/{p}/status"),
        None => "/proc/self/status".to_string(),
    };
    let status = std::fs::read_to_string(path).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Latency histogram with 2 % wide buckets from 10 µs up: fixed memory however long the run.
struct Histogram {
    counts: Vec<u64>,
    max_ms: f64,
}

const BUCKET_RATIO: f64 = 1.02;
const BUCKETS: usize = 1200; // 10 µs · 1.02^1200 ≈ 2·10⁸ ms

impl Histogram {
    fn new() -> Self {
        Histogram {
            counts: vec![0; BUCKETS],
            max_ms: 0.0,
        }
    }
    fn add(&mut self, ms: f64) {
        let i = ((ms / 0.01).max(1.0).ln() / BUCKET_RATIO.ln()) as usize;
        self.counts[i.min(BUCKETS - 1)] += 1;
        self.max_ms = self.max_ms.max(ms);
    }
    fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.max_ms = self.max_ms.max(other.max_ms);
    }
    /// Upper edge of the bucket holding quantile `q`.
    fn quantile(&self, q: f64) -> f64 {
        let total: u64 = self.counts.iter().sum();
        let target = (q * total as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= target {
                return 0.01 * BUCKET_RATIO.powi(i as i32 + 1);
            }
        }
        self.max_ms
    }
}

/// One client's request number `n`: what it asks and which statuses are right.
fn one_request(
    addr: SocketAddr,
    client: usize,
    n: u64,
    main_id: &str,
    small_ids: &[Mutex<Option<String>>],
) -> (usize, std::io::Result<HttpResponse>, &'static [u16]) {
    let slot = ((n / 10) as usize + client) % small_ids.len();
    let small_id = || small_ids[slot].lock().unwrap().clone();
    match n % 10 {
        0..=3 => {
            // An orbit: every view is new.
            let a = (client as f64 * 0.7 + n as f64 * 0.05).sin() * 3.0;
            let (ex, ey) = (8.0 + 30.0 * a.cos(), 8.0 + 30.0 * a.sin());
            let path = format!(
                "/v1/scenes/{main_id}/render?eye={ex:.3},{ey:.3},6&target=8,8,6&up=0,0,1&width=128&height=96&spp=1"
            );
            (0, get(addr, &path), &[200])
        }
        4 => (1, get(addr, &format!("/v1/scenes/{main_id}")), &[200]),
        5 => (2, get(addr, "/v1/scenes"), &[200]),
        6 => {
            let text = small_scene(slot as u32 + 1, [8, 8, 6]);
            let r = post(addr, &text);
            if let Ok(resp) = &r {
                if let Some(id) = resp.json()["id"].as_str() {
                    *small_ids[slot].lock().unwrap() = Some(id.to_string());
                }
            }
            (3, r, &[202])
        }
        7 => match small_id() {
            // Done, still solving (409), or deleted by another client meanwhile (404).
            Some(id) => (
                4,
                get(addr, &format!("/v1/scenes/{id}/render?width=32&height=24")),
                &[200, 404, 409],
            ),
            None => (1, get(addr, &format!("/v1/scenes/{main_id}")), &[200]),
        },
        8 => match small_id() {
            Some(id) if n % 20 == 8 => (
                5,
                request(addr, "DELETE", &format!("/v1/scenes/{id}"), None, &[]),
                &[204, 404],
            ),
            _ => (2, get(addr, "/v1/scenes"), &[200]),
        },
        _ => {
            let which = (n / 10) % 6;
            let r = match which {
                0 => get(addr, &format!("/v1/scenes/{main_id}/render?widht=10")),
                1 => get(addr, "/v1/scenes/0123456789abcdef0123"),
                2 => post(addr, "[volume]\ndims = [4, 4]\n"),
                3 => request(
                    addr,
                    "POST",
                    "/v1/scenes",
                    None,
                    &vec![b'#'; MAX_BODY_BYTES + 1000],
                ),
                4 => get(addr, &format!("/v1/scenes/{main_id}/render?width=100000")),
                _ => request(addr, "POST", "/v1/volumes?dims=2,2,2", None, &[0u8; 7]),
            };
            let ok: &'static [u16] = match which {
                1 => &[404],
                3 => &[413],
                _ => &[400],
            };
            (6, r, ok)
        }
    }
}

/// Runs the clients against the server at `addr` (which holds the solved `main_id`) for
/// `options.duration`, sampling the server's memory.
pub fn soak(addr: SocketAddr, main_id: &str, options: &SoakOptions) -> Summary {
    let stop = Arc::new(AtomicBool::new(false));
    let requests = Arc::new(AtomicU64::new(0));
    let errors = Arc::new(AtomicU64::new(0));
    let samples: Arc<Mutex<Vec<String>>> = Arc::new(Mutex::new(Vec::new()));
    let small_ids: Arc<Vec<Mutex<Option<String>>>> =
        Arc::new((0..4).map(|_| Mutex::new(None)).collect());
    let started = Instant::now();
    let mut rss = vec![rss_kib(options.server_pid).unwrap_or(0)];
    let (hist, by_kind) = std::thread::scope(|s| {
        let mut handles = Vec::new();
        for client in 0..options.clients {
            let (stop, requests, errors, samples, small_ids) = (
                stop.clone(),
                requests.clone(),
                errors.clone(),
                samples.clone(),
                small_ids.clone(),
            );
            handles.push(s.spawn(move || {
                let mut hist = Histogram::new();
                let mut by_kind = vec![0u64; KINDS.len()];
                let mut n = client as u64 * 3;
                while !stop.load(Ordering::Relaxed) {
                    let t = Instant::now();
                    let (kind, result, ok) = one_request(addr, client, n, main_id, &small_ids);
                    hist.add(t.elapsed().as_secs_f64() * 1e3);
                    by_kind[kind] += 1;
                    requests.fetch_add(1, Ordering::Relaxed);
                    let bad = match &result {
                        Ok(r) if ok.contains(&r.status) => None,
                        Ok(r) => Some(format!(
                            "{}: status {} (expected {ok:?}): {}",
                            KINDS[kind],
                            r.status,
                            r.text().chars().take(200).collect::<String>()
                        )),
                        Err(e) => Some(format!("{}: {e}", KINDS[kind])),
                    };
                    if let Some(msg) = bad {
                        errors.fetch_add(1, Ordering::Relaxed);
                        let mut v = samples.lock().unwrap();
                        if v.len() < 10 {
                            v.push(msg);
                        }
                    }
                    n += 1;
                }
                (hist, by_kind)
            }));
        }
        while started.elapsed() < options.duration {
            let left = options.duration.saturating_sub(started.elapsed());
            std::thread::sleep(left.min(options.sample_every));
            rss.push(rss_kib(options.server_pid).unwrap_or(0));
        }
        stop.store(true, Ordering::Relaxed);
        let mut hist = Histogram::new();
        let mut by_kind = vec![0u64; KINDS.len()];
        for h in handles {
            let (h, k) = h.join().expect("client thread");
            hist.merge(&h);
            for (a, b) in by_kind.iter_mut().zip(k) {
                *a += b;
            }
        }
        (hist, by_kind)
    });
    rss.push(rss_kib(options.server_pid).unwrap_or(0));
    let error_samples = samples.lock().unwrap().clone();
    Summary {
        requests: requests.load(Ordering::Relaxed),
        errors: errors.load(Ordering::Relaxed),
        error_samples,
        seconds: started.elapsed().as_secs_f64(),
        p50_ms: hist.quantile(0.5),
        p99_ms: hist.quantile(0.99),
        max_ms: hist.max_ms,
        rss_kib: rss,
        by_kind,
    }
}

fn main() -> Result<()> {
    let mut options = SoakOptions {
        clients: 8,
        duration: Duration::from_secs(600),
        sample_every: Duration::from_secs(5),
        server_pid: None,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let value = it.next().with_context(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--seconds" => options.duration = Duration::from_secs_f64(value.parse()?),
            "--clients" => options.clients = value.parse()?,
            "--sample-seconds" => options.sample_every = Duration::from_secs_f64(value.parse()?),
            _ => bail!("unknown flag {flag}"),
        }
    }
    let dir = tempfile_dir()?;
    let mut config = volrad::service::ServiceConfig::new(&dir);
    config.limits.max_body_bytes = MAX_BODY_BYTES;
    let server = volrad::service::ServerHandle::start(config, "127.0.0.1:0")?;
    let main_id = setup(server.addr)?;
    println!(
        "soak: {} clients for {:.0} s against http://{} (cache {})",
        options.clients,
        options.duration.as_secs_f64(),
        server.addr,
        dir.display()
    );
    let summary = soak(server.addr, &main_id, &options);
    summary.print();
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
    if summary.errors > 0 {
        std::process::exit(1);
    }
    Ok(())
}

/// A fresh directory under the system's temporary directory.
fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("volrad-soak-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}
