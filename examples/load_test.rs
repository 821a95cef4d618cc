//! Loopback load test of `volrad serve`: N concurrent clients render views of one cached
//! solution; prints p50/p99 latency and throughput. Bounded in requests and in time.
//!
//! ```text
//! cargo run --release --example load_test -- [--clients 8] [--requests 20] [--width 512]
//!     [--height 384] [--dims 24,24,18] [--max-seconds 120] [--render-slots N]
//!     [--addr HOST:PORT --id ID]
//! ```
//! Without `--addr` it starts a server in-process on 127.0.0.1:0 with a temporary cache and
//! solves a generated cloud first (the solve is not timed). Every request has its own eye on an
//! orbit, so no two images are the same.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use volrad::service::client::{get, request};
use volrad::service::{ServerHandle, ServiceConfig};

struct Options {
    clients: usize,
    requests: usize,
    width: u32,
    height: u32,
    dims: [usize; 3],
    max_seconds: f64,
    render_slots: Option<usize>,
    addr: Option<SocketAddr>,
    id: Option<String>,
}

fn parse_args() -> Result<Options> {
    let mut o = Options {
        clients: 8,
        requests: 20,
        width: 512,
        height: 384,
        dims: [24, 24, 18],
        max_seconds: 120.0,
        render_slots: None,
        addr: None,
        id: None,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let value = it.next().with_context(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--clients" => o.clients = value.parse()?,
            "--requests" => o.requests = value.parse()?,
            "--width" => o.width = value.parse()?,
            "--height" => o.height = value.parse()?,
            "--max-seconds" => o.max_seconds = value.parse()?,
            "--render-slots" => o.render_slots = Some(value.parse()?),
            "--addr" => o.addr = Some(value.parse()?),
            "--id" => o.id = Some(value.clone()),
            "--dims" => {
                let v: Vec<usize> = value
                    .split(',')
                    .map(|s| s.trim().parse())
                    .collect::<Result<_, _>>()?;
                if v.len() != 3 {
                    bail!("--dims wants NX,NY,NZ");
                }
                o.dims = [v[0], v[1], v[2]];
            }
            _ => bail!("unknown flag {flag}"),
        }
    }
    if o.addr.is_some() != o.id.is_some() {
        bail!("--addr and --id go together");
    }
    Ok(o)
}

fn scene_text(dims: [usize; 3]) -> String {
    let [nx, ny, nz] = dims.map(|d| d as f64);
    format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 7 }}
dims = [{}, {}, {}]
sigma_t_scale = 0.6
# The render the p50 floor (#7) is about: exact per-cell segments.
interpolation = "nearest"

[medium]
albedo = 0.95
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
eye = [{cx}, {ey}, {cz}]
target = [{cx}, {cy}, {cz}]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 512
height = 384
"#,
        dims[0],
        dims[1],
        dims[2],
        cx = nx / 2.0,
        cy = ny / 2.0,
        cz = nz / 2.0,
        ey = ny / 2.0 - 2.5 * nx.max(ny).max(nz),
    )
}

/// Milliseconds of one phase in a `Server-Timing` header (`name;dur=12.3, ...`).
fn server_timing(header: &str, name: &str) -> f64 {
    header
        .split(',')
        .filter_map(|part| part.trim().split_once(";dur="))
        .find(|(n, _)| *n == name)
        .and_then(|(_, d)| d.parse().ok())
        .unwrap_or(0.0)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn main() -> Result<()> {
    let o = parse_args()?;
    let tmp = std::env::temp_dir().join(format!("volrad-load-{}", std::process::id()));
    let mut server = None;
    let (addr, id, extent) = match (o.addr, o.id.clone()) {
        (Some(a), Some(id)) => {
            let v = get(a, &format!("/v1/scenes/{id}"))?.json();
            let ext: Vec<f64> =
                serde_json::from_value(v["extent"].clone()).context("scene not done")?;
            (a, id, [ext[0], ext[1], ext[2]])
        }
        _ => {
            let mut config = ServiceConfig::new(&tmp);
            if let Some(n) = o.render_slots {
                config.render_slots = n;
            }
            let handle = ServerHandle::start(config, "127.0.0.1:0")?;
            let a = handle.addr;
            let text = scene_text(o.dims);
            let r = request(
                a,
                "POST",
                "/v1/scenes",
                Some("application/toml"),
                text.as_bytes(),
            )?;
            if r.status != 202 {
                bail!("posting the scene: {}", r.text());
            }
            let id = r.json()["id"].as_str().context("id")?.to_string();
            let t0 = Instant::now();
            loop {
                let v = get(a, &format!("/v1/scenes/{id}"))?.json();
                match v["state"].as_str() {
                    Some("done") => break,
                    Some("failed") => bail!("solve failed: {v}"),
                    _ if t0.elapsed() > Duration::from_secs(300) => bail!("solve too slow"),
                    _ => std::thread::sleep(Duration::from_millis(50)),
                }
            }
            eprintln!(
                "solved {}×{}×{} in {:.2} s",
                o.dims[0],
                o.dims[1],
                o.dims[2],
                t0.elapsed().as_secs_f64()
            );
            server = Some(handle);
            (a, id, o.dims.map(|d| d as f64))
        }
    };
    let center = extent.map(|e| e / 2.0);
    let radius = 2.5 * extent.iter().cloned().fold(0.0, f64::max);
    let deadline = Instant::now() + Duration::from_secs_f64(o.max_seconds);
    let started = Instant::now();
    let results: Vec<(Vec<f64>, usize, [f64; 3])> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..o.clients)
            .map(|c| {
                let id = &id;
                let o = &o;
                s.spawn(move || {
                    let mut lat = Vec::with_capacity(o.requests);
                    let mut failures = 0;
                    // Server-side wait, render and encode milliseconds, summed.
                    let mut phases = [0.0f64; 3];
                    for r in 0..o.requests {
                        if Instant::now() > deadline {
                            break;
                        }
                        let angle = (c * o.requests + r) as f64 * 0.0731;
                        let eye = [
                            center[0] + radius * angle.sin(),
                            center[1] - radius * angle.cos(),
                            center[2] + 0.3 * radius,
                        ];
                        let path = format!(
                            "/v1/scenes/{id}/render?eye={:.4},{:.4},{:.4}&target={},{},{}&up=0,0,1&fov=40&width={}&height={}&spp=1",
                            eye[0], eye[1], eye[2], center[0], center[1], center[2], o.width, o.height
                        );
                        let t = Instant::now();
                        match get(addr, &path) {
                            Ok(resp) if resp.status == 200 => {
                                lat.push(t.elapsed().as_secs_f64() * 1e3);
                                for (slot, name) in phases.iter_mut().zip(["wait", "render", "encode"]) {
                                    *slot += server_timing(resp.header("server-timing").unwrap_or(""), name);
                                }
                            }
                            _ => failures += 1,
                        }
                    }
                    (lat, failures, phases)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("client thread"))
            .collect()
    });
    let wall = started.elapsed().as_secs_f64();
    let failures: usize = results.iter().map(|r| r.1).sum();
    let mut phases = [0.0f64; 3];
    for r in &results {
        for (sum, part) in phases.iter_mut().zip(r.2) {
            *sum += part;
        }
    }
    let mut lat: Vec<f64> = results.into_iter().flat_map(|r| r.0).collect();
    lat.sort_by(|a, b| a.total_cmp(b));
    if lat.is_empty() {
        bail!("no successful requests ({failures} failed)");
    }
    println!(
        "{} clients, {} renders of {}×{} (spp 1) in {:.2} s, {} failed",
        o.clients,
        lat.len(),
        o.width,
        o.height,
        wall,
        failures
    );
    println!(
        "latency p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms; throughput {:.1} renders/s",
        percentile(&lat, 0.5),
        percentile(&lat, 0.99),
        lat[lat.len() - 1],
        lat.len() as f64 / wall
    );
    let n = lat.len() as f64;
    println!(
        "server side, mean per render: waiting for a render slot {:.1} ms, rendering {:.1} ms, PNG encoding {:.1} ms",
        phases[0] / n,
        phases[1] / n,
        phases[2] / n
    );
    if let Some(h) = server.take() {
        h.stop();
        let _ = std::fs::remove_dir_all(&tmp);
    }
    Ok(())
}
