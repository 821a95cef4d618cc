//! `volrad serve` under faults (issue 22): the real binary killed with SIGKILL during a solve
//! and during the write of its solution, then restarted on the same cache directory; a cache
//! write over the file-size limit; clients that send slowly or too much; and a short soak.
//! docs/reliability.md ("The service under faults") tabulates these tests.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;
use volrad::engine::solution::Solution;
use volrad::service::client::{get, request};
use volrad::service::{ServerHandle, ServiceConfig};

use crate::service::{post_scene, submit, wait_finished};

#[path = "../../examples/soak.rs"]
#[allow(dead_code)]
mod soak;

/// A `volrad serve` process on 127.0.0.1 (a port the kernel picks) and a cache directory.
struct Server {
    child: Child,
    addr: SocketAddr,
    /// Everything the server wrote to stderr, for failure messages.
    log: Arc<Mutex<String>>,
}

impl Server {
    /// Starts the binary and waits for the line naming its address.
    fn spawn(cache: &Path, args: &[&str], max_file_bytes: Option<u64>) -> Server {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_volrad"));
        cmd.args(["serve", "--addr", "127.0.0.1:0", "--cache"])
            .arg(cache)
            .args(args)
            .env("RUST_LOG", "volrad=info,warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        if let Some(limit) = max_file_bytes {
            use std::os::unix::process::CommandExt;
            // SAFETY: only setrlimit, async-signal-safe, runs between fork and exec.
            unsafe {
                cmd.pre_exec(move || {
                    let lim = libc::rlimit {
                        rlim_cur: limit as libc::rlim_t,
                        rlim_max: limit as libc::rlim_t,
                    };
                    if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let mut child = cmd.spawn().expect("volrad serve starts");
        let stderr = child.stderr.take().unwrap();
        let log = Arc::new(Mutex::new(String::new()));
        let (tx, rx) = std::sync::mpsc::channel();
        let sink = log.clone();
        // Drains stderr for the server's whole life (a full pipe would block it).
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if let Some(rest) = line.split("volrad serve: http://").nth(1) {
                    if let Some(addr) = rest.split('/').next() {
                        let _ = tx.send(addr.to_string());
                    }
                }
                let mut log = sink.lock().unwrap();
                log.push_str(&line);
                log.push('\n');
            }
        });
        let addr = match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(a) => a.parse().unwrap(),
            Err(_) => {
                let _ = child.kill();
                panic!("volrad serve printed no address:\n{}", log.lock().unwrap());
            }
        };
        Server { child, addr, log }
    }

    /// SIGKILL (what `Child::kill` sends), and reaped.
    fn kill9(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    fn log(&self) -> String {
        self.log.lock().unwrap().clone()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A cloud scene on `dims` cells solved by `method`, with `extra` lines in `[solve]`.
fn scene(seed: u32, dims: [usize; 3], method: &str, extra: &str) -> String {
    let [nx, ny, nz] = dims;
    let (cx, cy, cz) = (nx as f64 / 2.0, ny as f64 / 2.0, nz as f64 / 2.0);
    format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = {seed} }}
dims = [{nx}, {ny}, {nz}]

[medium]
albedo = 0.95
phase = {{ kind = "isotropic" }}

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[solve]
method = "{method}"
{extra}

[render]
exposure = 4.0
spp = 1

[[camera]]
name = "front"
eye = [{cx}, {ey}, {cz}]
target = [{cx}, {cy}, {cz}]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 48
height = 36
"#,
        ey = cy - 3.0 * nx.max(ny) as f64,
    )
}

/// A few seconds of solving (tens of iterations on 40×40×30 cells).
fn slow_scene() -> String {
    scene(
        11,
        [40, 40, 30],
        "zonal-hierarchical",
        "tolerance = 1e-9\nmax_iterations = 400",
    )
}

/// A solution file of 25 MB, written (and synced) for long enough to be caught mid-write;
/// solved in about a second.
fn big_solution_scene(seed: u32) -> String {
    scene(seed, [128, 128, 96], "single-scatter", "")
}

/// A solution file of 3 MB, solved in a fraction of a second.
fn mid_solution_scene(seed: u32) -> String {
    scene(seed, [64, 64, 48], "single-scatter", "")
}

/// A scene solved in well under a second, with a solution file of a few kilobytes.
fn small_scene(seed: u32) -> String {
    scene(seed, [8, 8, 6], "zonal", "")
}

fn state(addr: SocketAddr, id: &str) -> Value {
    let r = get(addr, &format!("/v1/scenes/{id}")).unwrap();
    assert_eq!(r.status, 200, "{}", r.text());
    r.json()
}

fn assert_renders(addr: SocketAddr, id: &str) {
    let r = get(addr, &format!("/v1/scenes/{id}/render?width=32&height=24")).unwrap();
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("image/png"));
    image::load_from_memory(&r.body).expect("a whole PNG");
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Temporary files (`.NAME.tmp-PID-N`) in the cache directory.
fn temp_files(dir: &Path) -> Vec<PathBuf> {
    names(dir)
        .into_iter()
        .filter(|n| n.starts_with('.') && n.contains(".tmp-"))
        .map(|n| dir.join(n))
        .collect()
}

/// Every `*.vrs` in the directory reads back as a valid solution.
fn assert_every_solution_valid(dir: &Path) {
    for name in names(dir) {
        if name.ends_with(".vrs") {
            if let Err(e) = Solution::read(&dir.join(&name)) {
                panic!("{name} is corrupt after a kill: {e}");
            }
        }
    }
}

#[test]
fn kill_9_during_a_solve_then_restart_solves_it_again() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::spawn(dir.path(), &[], None);
    let id = submit(server.addr, &slow_scene());
    // Killed once the solve is under way (an iteration reported).
    let start = Instant::now();
    loop {
        let v = state(server.addr, &id);
        if v["state"] == "solving" && v["iteration"].as_u64().unwrap_or(0) >= 1 {
            break;
        }
        assert!(v["state"] != "done", "solved before the kill: {v}");
        assert!(start.elapsed() < Duration::from_secs(30), "{v}");
        std::thread::sleep(Duration::from_millis(10));
    }
    server.kill9();
    // Nothing under the solution's name, no temporary file; the scene text is kept.
    let files = names(dir.path());
    assert!(!files.contains(&format!("{id}.vrs")), "{files:?}");
    assert!(temp_files(dir.path()).is_empty(), "{files:?}");
    assert!(files.contains(&format!("{id}.toml")), "{files:?}");

    let server = Server::spawn(dir.path(), &[], None);
    let v = state(server.addr, &id);
    assert!(
        matches!(v["state"].as_str(), Some("queued") | Some("solving")),
        "the job resumes after the restart: {v}"
    );
    let v = wait_finished(server.addr, &id);
    assert_eq!(v["state"], "done", "{v}\n{}", server.log());
    assert_renders(server.addr, &id);
    Solution::read(&dir.path().join(format!("{id}.vrs"))).expect("a valid solution");
}

/// Kills the server the moment the solution's temporary file appears — during its write or
/// its sync, just before the rename — over several trials, restarting each time. After
/// every kill every solution file present must be whole and every scene done or solving
/// again. At least one kill must land mid-write (the temporary file still there), or the
/// test has not tested anything and fails.
#[test]
fn kill_9_during_a_solution_write_never_leaves_a_corrupt_solution() {
    let dir = tempfile::tempdir().unwrap();
    let text = big_solution_scene(5);
    let mut server = Server::spawn(dir.path(), &[], None);
    let id = submit(server.addr, &text);
    let final_name = dir.path().join(format!("{id}.vrs"));
    let temp_prefix = format!(".{id}.vrs.tmp-");
    let (mut mid_write, mut after_rename) = (0, 0);
    for trial in 0..6 {
        // Watches for the temporary file as fast as the directory can be read.
        let start = Instant::now();
        loop {
            let seen = std::fs::read_dir(dir.path())
                .unwrap()
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(&temp_prefix));
            if seen {
                break;
            }
            assert!(
                !final_name.exists() && start.elapsed() < Duration::from_secs(60),
                "trial {trial}: the write was never seen\n{}",
                server.log()
            );
        }
        server.kill9();
        let temps = temp_files(dir.path());
        if temps.is_empty() {
            after_rename += 1;
        } else {
            mid_write += 1;
        }
        assert_every_solution_valid(dir.path());

        server = Server::spawn(dir.path(), &[], None);
        let v = state(server.addr, &id);
        if final_name.exists() {
            // The rename came first: served as done, from the whole file.
            assert_eq!(v["state"], "done", "trial {trial}: {v}");
            assert_renders(server.addr, &id);
            // Once more from the start: forget it and post it again.
            let r = request(
                server.addr,
                "DELETE",
                &format!("/v1/scenes/{id}"),
                None,
                &[],
            )
            .unwrap();
            assert_eq!(r.status, 204);
            assert_eq!(submit(server.addr, &text), id);
        } else {
            assert!(
                matches!(v["state"].as_str(), Some("queued") | Some("solving")),
                "trial {trial}: the scene is solved again after the restart: {v}"
            );
        }
        // A temporary file left by the kill is never served or loaded as a solution.
        for t in &temps {
            assert!(!t.to_string_lossy().ends_with(".vrs"), "{}", t.display());
        }
        if mid_write >= 2 {
            break;
        }
    }
    eprintln!("kills mid-write: {mid_write}, after the rename: {after_rename}");
    assert!(
        mid_write >= 1,
        "no kill landed during a write ({after_rename} after the rename)"
    );

    // Stale temporary files (unwritten for longer than the service's grace period) are deleted
    // at start-up; a fresh one, which another instance may be writing, is kept.
    server.kill9();
    let stale = temp_files(dir.path());
    assert!(!stale.is_empty(), "the last kill left its temporary file");
    let hour_ago = SystemTime::now() - Duration::from_secs(3600);
    for t in &stale {
        std::fs::File::options()
            .write(true)
            .open(t)
            .unwrap()
            .set_modified(hour_ago)
            .unwrap();
    }
    let fresh = dir.path().join(format!(".{id}.vrs.tmp-999999-0"));
    std::fs::write(&fresh, b"being written by another instance").unwrap();
    let server = Server::spawn(dir.path(), &[], None);
    for t in &stale {
        assert!(!t.exists(), "{} survived the restart", t.display());
    }
    assert!(fresh.exists(), "a fresh temporary file was deleted");
    let v = wait_finished(server.addr, &id);
    assert_eq!(v["state"], "done", "{v}\n{}", server.log());
    assert_renders(server.addr, &id);
    assert_every_solution_valid(dir.path());
    drop(server);
    std::fs::remove_file(&fresh).unwrap();
    assert_eq!(
        names(dir.path()),
        [
            format!("{id}.toml"),
            format!("{id}.vrs"),
            "volumes".to_string()
        ]
    );
}

/// The server under a file-size limit smaller than one solution (RLIMIT_FSIZE, as a
/// container or `ulimit -f` sets; the kernel then fails writes past it as a full disk
/// would): that scene fails with a reason naming the cache write, nothing is left under its
/// name or as a temporary file, and the server goes on serving other scenes. On the code
/// before, the kernel's SIGXFSZ killed the server.
#[test]
fn a_cache_write_past_the_file_size_limit_fails_that_scene_only() {
    let dir = tempfile::tempdir().unwrap();
    let limit = 256 * 1024;
    let mut server = Server::spawn(dir.path(), &[], Some(limit));
    let small = submit(server.addr, &small_scene(1));
    assert_eq!(wait_finished(server.addr, &small)["state"], "done");
    let small_bytes = std::fs::metadata(dir.path().join(format!("{small}.vrs")))
        .unwrap()
        .len();
    assert!(small_bytes < limit, "{small_bytes}");

    let big = submit(server.addr, &mid_solution_scene(2));
    let v = wait_finished(server.addr, &big);
    assert!(server.alive(), "the server died:\n{}", server.log());
    assert_eq!(v["state"], "failed", "{v}");
    let reason = v["reason"].as_str().unwrap();
    assert!(
        reason.contains("writing its solution to the cache failed") && reason.contains("large"),
        "{reason}"
    );
    assert!(!dir.path().join(format!("{big}.vrs")).exists());
    assert!(temp_files(dir.path()).is_empty(), "{:?}", names(dir.path()));

    // Everything else still works: the cached scene renders, a new one solves and renders,
    // and the failed one may be posted again (and fails again, cleanly).
    assert_renders(server.addr, &small);
    let other = submit(server.addr, &small_scene(2));
    assert_eq!(wait_finished(server.addr, &other)["state"], "done");
    assert_renders(server.addr, &other);
    let again = post_scene(server.addr, &mid_solution_scene(2));
    assert_eq!(again.json()["queued"], true, "{}", again.text());
    assert_eq!(wait_finished(server.addr, &big)["state"], "failed");
    assert!(server.alive(), "the server died:\n{}", server.log());
    assert_every_solution_valid(dir.path());
}

/// Reads until the server closes the connection or `within` passes; what was read and
/// whether it closed.
fn read_until_closed(stream: &mut TcpStream, within: Duration) -> (Vec<u8>, bool) {
    let deadline = Instant::now() + within;
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return (got, false);
        }
        stream.set_read_timeout(Some(left)).unwrap();
        match stream.read(&mut buf) {
            Ok(0) => return (got, true),
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return (got, false)
            }
            // Reset by the server: closed.
            Err(_) => return (got, true),
        }
    }
}

fn status_of(answer: &[u8]) -> u16 {
    let text = String::from_utf8_lossy(answer);
    text.split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0)
}

#[test]
fn slow_clients_are_cut_off_and_oversized_bodies_refused_without_blocking_others() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = ServiceConfig::new(dir.path());
    config.limits.request_read_timeout = Duration::from_secs(1);
    config.limits.max_body_bytes = 64 * 1024;
    let server = ServerHandle::start(config, "127.0.0.1:0").unwrap();
    let addr = server.addr;

    // Twenty clients connect and send nothing; others are served meanwhile, at once.
    let silent: Vec<TcpStream> = (0..20).map(|_| TcpStream::connect(addr).unwrap()).collect();
    let t = Instant::now();
    for _ in 0..5 {
        assert_eq!(get(addr, "/v1/scenes").unwrap().status, 200);
    }
    assert!(
        t.elapsed() < Duration::from_millis(900),
        "{:?}",
        t.elapsed()
    );
    // And they are cut off after the timeout (1 s), not held open.
    for mut s in silent {
        let (got, closed) = read_until_closed(&mut s, Duration::from_secs(4));
        assert!(closed, "a silent connection was kept open");
        assert!(got.is_empty() || status_of(&got) == 408, "{got:?}");
    }

    // Headers sent a byte every 100 ms: cut off after the timeout, though bytes keep coming.
    let mut s = TcpStream::connect(addr).unwrap();
    let t = Instant::now();
    let head = b"GET /v1/scenes HTTP/1.1\r\nHost: x\r\nX-Slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\r\n\r\n";
    let mut cut = false;
    for &b in head.iter() {
        if s.write_all(&[b]).is_err() {
            cut = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
        // The server closing shows as a read of 0 bytes (or a reset) without waiting.
        s.set_nonblocking(true).unwrap();
        let mut one = [0u8; 1];
        let closed = matches!(s.read(&mut one), Ok(0))
            || matches!(s.read(&mut one), Err(e) if e.kind() != std::io::ErrorKind::WouldBlock);
        s.set_nonblocking(false).unwrap();
        if closed {
            cut = true;
            break;
        }
    }
    assert!(
        cut,
        "headers dribbled for {:?} were not cut off",
        t.elapsed()
    );
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());

    // A body within the limit sent a byte every 100 ms: 408 after the timeout.
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(b"POST /v1/scenes HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n")
        .unwrap();
    let t = Instant::now();
    let mut answered = Vec::new();
    for _ in 0..100 {
        if s.write_all(b"#").is_err() {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
        s.set_nonblocking(true).unwrap();
        let mut buf = [0u8; 1024];
        if let Ok(n) = s.read(&mut buf) {
            answered.extend_from_slice(&buf[..n]);
        }
        s.set_nonblocking(false).unwrap();
        if !answered.is_empty() {
            break;
        }
    }
    let (rest, _) = read_until_closed(&mut s, Duration::from_secs(3));
    answered.extend(rest);
    assert_eq!(
        status_of(&answered),
        408,
        "{}",
        String::from_utf8_lossy(&answered)
    );
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    assert!(String::from_utf8_lossy(&answered).contains("did not arrive within"));

    // A Content-Length over the limit: 413 before a byte of the body is sent.
    let mut s = TcpStream::connect(addr).unwrap();
    let t = Instant::now();
    s.write_all(b"POST /v1/scenes HTTP/1.1\r\nHost: x\r\nContent-Length: 10000000\r\n\r\n")
        .unwrap();
    let (answer, _) = read_until_closed(&mut s, Duration::from_secs(3));
    assert_eq!(
        status_of(&answer),
        413,
        "{}",
        String::from_utf8_lossy(&answer)
    );
    assert!(
        t.elapsed() < Duration::from_millis(900),
        "{:?}",
        t.elapsed()
    );
    assert!(String::from_utf8_lossy(&answer).contains("limit of 65536 bytes"));

    // A chunked body (no length announced) that grows past the limit, slowly: 413 as soon as
    // it does, before the timeout.
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(
        b"POST /v1/volumes?dims=100,100,10 HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n",
    )
    .unwrap();
    let chunk = vec![0u8; 16 * 1024];
    let t = Instant::now();
    for _ in 0..5 {
        let mut framed = format!("{:x}\r\n", chunk.len()).into_bytes();
        framed.extend_from_slice(&chunk);
        framed.extend_from_slice(b"\r\n");
        if s.write_all(&framed).is_err() {
            break;
        }
        std::thread::sleep(Duration::from_millis(150));
    }
    let (answer, _) = read_until_closed(&mut s, Duration::from_secs(3));
    assert_eq!(
        status_of(&answer),
        413,
        "{}",
        String::from_utf8_lossy(&answer)
    );
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());

    // A kept-alive connection left idle is closed after the timeout too.
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(b"GET /v1/scenes HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    let (answer, closed) = read_until_closed(&mut s, Duration::from_secs(4));
    assert_eq!(status_of(&answer), 200);
    assert!(closed, "an idle kept-alive connection was kept open");

    // After all of that the server answers as before.
    let id = submit(addr, &small_scene(3));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    assert_renders(addr, &id);
}

/// The soak (examples/soak.rs) for a few seconds against the binary: 8 clients, no errors,
/// and the server's memory bounded.
#[test]
fn soak_for_a_few_seconds_has_no_errors_and_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let max_body = soak::MAX_BODY_BYTES.to_string();
    let server = Server::spawn(dir.path(), &["--max-body-bytes", &max_body], None);
    let main_id = soak::setup(server.addr).unwrap();
    let options = soak::SoakOptions {
        clients: 8,
        duration: Duration::from_secs(6),
        sample_every: Duration::from_millis(500),
        server_pid: Some(server.child.id()),
    };
    let summary = soak::soak(server.addr, &main_id, &options);
    summary.print();
    assert_eq!(summary.errors, 0, "{:?}", summary.error_samples);
    assert!(summary.requests > 100, "{summary:?}");
    assert!(summary.by_kind.iter().all(|&n| n > 0), "{summary:?}");
    // Growth from the first third of the run to its end: allocator arenas and caches settle
    // early; a leak per request would keep growing.
    let third = summary.rss_kib[summary.rss_kib.len() / 3];
    assert!(third > 0, "{summary:?}");
    assert!(
        summary.rss_max() < third + 48 * 1024,
        "RSS grew from {third} KiB to {} KiB",
        summary.rss_max()
    );
}
