//! `volrad serve` end to end over loopback HTTP: solve, poll, render, limits and errors,
//! deletion, cancellation, and a restart on the same cache directory (valid solutions served
//! again, corrupt ones never).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use serde_json::Value;
use volrad::service::client::{get, request, HttpResponse};
use volrad::service::{ServerHandle, ServiceConfig};

fn scene(seed: u32, albedo: f64) -> String {
    format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = {seed} }}
dims = [10, 10, 8]

[medium]
albedo = {albedo}
phase = {{ kind = "isotropic" }}

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[solve]
method = "zonal"

[render]
exposure = 4.0

[[camera]]
name = "front"
eye = [5.0, -20.0, 4.0]
target = [5.0, 5.0, 4.0]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 64
height = 48
"#
    )
}

fn start(dir: &std::path::Path) -> ServerHandle {
    ServerHandle::start(ServiceConfig::new(dir), "127.0.0.1:0").expect("server starts")
}

/// `POST /v1/scenes` with a TOML scene (shared with `service_faults`).
pub(crate) fn post_scene(addr: SocketAddr, text: &str) -> HttpResponse {
    request(
        addr,
        "POST",
        "/v1/scenes",
        Some("application/toml"),
        text.as_bytes(),
    )
    .unwrap()
}

/// Posts a scene that must be accepted; its id.
pub(crate) fn submit(addr: SocketAddr, text: &str) -> String {
    let r = post_scene(addr, text);
    assert_eq!(r.status, 202, "{}", r.text());
    r.json()["id"].as_str().expect("id").to_string()
}

/// Polls until the scene leaves queued/solving (at most 60 s); returns its final
/// description.
pub(crate) fn wait_finished(addr: SocketAddr, id: &str) -> Value {
    let start = Instant::now();
    loop {
        let r = get(addr, &format!("/v1/scenes/{id}")).unwrap();
        assert_eq!(r.status, 200, "{}", r.text());
        let v = r.json();
        match v["state"].as_str() {
            Some("queued") | Some("solving") => {}
            _ => return v,
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "solve took too long: {v}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png).expect("decodes");
    (img.width(), img.height())
}

fn assert_error(r: &HttpResponse, status: u16, mentions: &str) {
    assert_eq!(r.status, status, "{}", r.text());
    let msg = r.json()["error"].as_str().unwrap_or_default().to_string();
    assert!(
        msg.contains(mentions),
        "error `{msg}` should mention `{mentions}`"
    );
}

#[test]
fn solve_poll_render_and_same_scene_is_one_job() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let text = scene(7, 0.9);
    let id = submit(addr, &text);
    let again = post_scene(addr, &text);
    assert_eq!(again.status, 202);
    assert_eq!(
        again.json()["id"].as_str(),
        Some(id.as_str()),
        "same scene, same id"
    );

    // The same scene as JSON is the same content, so the same id.
    let as_json: Value =
        serde_json::to_value(toml::from_str::<toml::Table>(&text).unwrap()).unwrap();
    let j = request(
        addr,
        "POST",
        "/v1/scenes",
        Some("application/json"),
        as_json.to_string().as_bytes(),
    )
    .unwrap();
    assert_eq!(j.status, 202, "{}", j.text());
    assert_eq!(j.json()["id"].as_str(), Some(id.as_str()));

    // The id is the scene hash the command line prints and stores in solution files.
    let parsed =
        scene::Scene::from_toml_str(&text, std::path::Path::new("."), std::path::Path::new("s"))
            .unwrap();
    assert_eq!(id, volrad::engine::pipeline::scene_hash(&parsed));
    // The viewer shows 12 characters of it; the API takes any unique prefix of 8 or more.
    let short = get(addr, &format!("/v1/scenes/{}", &id[..12])).unwrap();
    assert_eq!(short.status, 200, "{}", short.text());
    assert_eq!(short.json()["id"].as_str(), Some(id.as_str()));
    assert_eq!(
        get(addr, &format!("/v1/scenes/{}", &id[..4]))
            .unwrap()
            .status,
        404
    );

    let done = wait_finished(addr, &id);
    assert_eq!(done["state"], "done", "{done}");
    let report = &done["report"]["channels"][0];
    assert!(report["iterations"].as_u64().unwrap() > 0);
    assert!(report["converged"].as_bool().unwrap());
    assert!(!report["residual_history"].as_array().unwrap().is_empty());
    assert!(
        dir.path().join(format!("{id}.vrs")).exists(),
        "solution cached by id"
    );

    let list = get(addr, "/v1/scenes").unwrap().json();
    let scenes = list["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), 1);
    assert_eq!(scenes[0]["id"].as_str(), Some(id.as_str()));

    let png = get(
        addr,
        &format!("/v1/scenes/{id}/render?width=96&height=72&spp=1"),
    )
    .unwrap();
    assert_eq!(png.status, 200, "{}", png.text());
    assert_eq!(png.header("content-type"), Some("image/png"));
    assert_eq!(png_size(&png.body), (96, 72));
    let img = image::load_from_memory(&png.body).unwrap().to_luma8();
    let (lo, hi) = img
        .pixels()
        .fold((255u8, 0u8), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
    assert!(
        hi > lo + 20,
        "the lit cloud is visible against the background ({lo}..{hi})"
    );

    // Default camera from the scene; an orbiting eye gives a different image.
    let default = get(addr, &format!("/v1/scenes/{id}/render")).unwrap();
    assert_eq!(png_size(&default.body), (64, 48));
    let side = get(
        addr,
        &format!("/v1/scenes/{id}/render?eye=25,5,4&target=5,5,4&up=0,0,1&fov=40"),
    )
    .unwrap();
    assert_eq!(side.status, 200);
    assert_ne!(side.body, default.body);

    let pfm = get(
        addr,
        &format!("/v1/scenes/{id}/render?width=8&height=6&format=pfm"),
    )
    .unwrap();
    assert_eq!(pfm.status, 200);
    assert!(pfm.body.starts_with(b"Pf\n8 6\n"), "grey PFM header");
    assert!(pfm.body.len() >= 8 * 6 * 4);

    let spec = get(addr, "/v1/openapi.json").unwrap();
    let spec = spec.json();
    for path in [
        "/v1/scenes",
        "/v1/scenes/{id}",
        "/v1/scenes/{id}/render",
        "/v1/scenes/{id}/cancel",
        "/v1/scenes/{id}/relight",
        "/v1/scenes/{id}/slice",
        "/v1/volumes",
    ] {
        assert!(spec["paths"][path].is_object(), "openapi lists {path}");
    }
    // Every documented route and method exists (an unknown id answers 404 from the route,
    // not the "no such route" fallback).
    for (path, item) in spec["paths"].as_object().unwrap() {
        for method in item.as_object().unwrap().keys() {
            let url = path.replace("{id}", "ffffffffffffffff");
            let r = request(addr, &method.to_uppercase(), &url, None, &[]).unwrap();
            let msg = r.json()["error"].as_str().unwrap_or_default().to_string();
            assert_ne!(msg, "no such route", "{method} {path}");
            assert_ne!(r.status, 405, "{method} {path}");
        }
    }
    let page = get(addr, "/").unwrap();
    assert_eq!(page.status, 200);
    assert!(
        page.text().contains("/v1/scenes"),
        "the viewer talks to the API"
    );
}

#[test]
fn bad_input_is_refused_with_json_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = ServiceConfig::new(dir.path());
    config.limits.max_body_bytes = 64 * 1024;
    config.limits.max_image_pixels = 1_000_000;
    let server = ServerHandle::start(config, "127.0.0.1:0").unwrap();
    let addr = server.addr;

    assert_error(&post_scene(addr, &scene(7, 1.5)), 400, "medium.albedo");
    assert_error(&post_scene(addr, "[volume\n"), 400, "line 1");
    assert_error(
        &post_scene(addr, &scene(7, 0.5).replace("irradiance", "irradianse")),
        400,
        "irradianse",
    );
    assert_error(
        &post_scene(
            addr,
            &scene(7, 0.5).replace("dims = [10, 10, 8]", "dims = [4000, 4000, 4000]"),
        ),
        400,
        "volume.dims",
    );
    assert_error(
        &post_scene(
            addr,
            &scene(7, 0.5).replace(
                "method = \"zonal\"",
                "method = \"zonal\"\nmax_iterations = 99999999",
            ),
        ),
        400,
        "solve.max_iterations",
    );
    assert_error(
        &post_scene(
            addr,
            &scene(7, 0.5).replace(
                "generator = { kind = \"cloud\", seed = 7 }",
                "file = \"/etc/passwd\"",
            ),
        ),
        400,
        "volume.file",
    );
    // Exact zonal on 64³ cells needs (64³)² form factors: refused before any work.
    assert_error(
        &post_scene(
            addr,
            &scene(7, 0.5).replace("dims = [10, 10, 8]", "dims = [64, 64, 64]"),
        ),
        400,
        "the server allows",
    );
    let big = vec![b'#'; 100 * 1024];
    assert_error(
        &request(addr, "POST", "/v1/scenes", None, &big).unwrap(),
        413,
        "limit",
    );
    assert_error(
        &request(
            addr,
            "POST",
            "/v1/scenes",
            Some("application/json"),
            b"{\"volume\": nul",
        )
        .unwrap(),
        400,
        "JSON",
    );

    // Volumes: the size must match the dims.
    let seven = [0u8; 7];
    assert_error(
        &request(addr, "POST", "/v1/volumes?dims=1,1,2", None, &seven).unwrap(),
        400,
        "does not match",
    );
    assert_error(
        &request(addr, "POST", "/v1/volumes?dims=1,x,2", None, &seven).unwrap(),
        400,
        "dims",
    );
    let nan = f32::NAN.to_le_bytes();
    assert_error(
        &request(addr, "POST", "/v1/volumes?dims=1,1,1", None, &nan).unwrap(),
        400,
        "finite",
    );

    // Unknown ids.
    assert_error(
        &get(addr, "/v1/scenes/0123456789abcdef").unwrap(),
        404,
        "0123456789abcdef",
    );
    assert_error(&get(addr, "/v1/scenes/nope/render").unwrap(), 404, "nope");
    assert_error(
        &request(addr, "DELETE", "/v1/scenes/nope", None, &[]).unwrap(),
        404,
        "nope",
    );
    assert_error(
        &request(addr, "POST", "/v1/scenes/nope/cancel", None, &[]).unwrap(),
        404,
        "nope",
    );
    assert_error(&get(addr, "/v2/whatever").unwrap(), 404, "route");

    // Render requests against a solved scene.
    let id = submit(addr, &scene(3, 0.8));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    let render = |q: &str| get(addr, &format!("/v1/scenes/{id}/render?{q}")).unwrap();
    assert_error(&render("width=100000&height=10"), 400, "width");
    assert_error(&render("width=2000&height=2000&spp=1"), 400, "pixels");
    assert_error(&render("width=abc"), 400, "width");
    assert_error(&render("width=-3"), 400, "width");
    assert_error(&render("eye=1,2"), 400, "eye");
    assert_error(&render("eye=1,2,nan"), 400, "eye");
    assert_error(&render("fov=1e999"), 400, "fov");
    assert_error(&render("fov=200"), 400, "fov");
    assert_error(&render("spp=100000"), 400, "spp");
    assert_error(&render("format=gif"), 400, "format");
    assert_error(&render("eye=5,5,4&target=5,5,4"), 400, "eye");
    assert_error(&render("eye=5,5,20&target=5,5,4&up=0,0,1"), 400, "up");
    // Misspelled or unknown parameters are named, not ignored; cameras go by name.
    assert_error(&render("widht=100"), 400, "widht");
    assert_error(&render("width=16&height=12&colour=red"), 400, "colour");
    assert_error(&render("camera=top"), 400, "top");
    assert_eq!(render("camera=front&width=16&height=12").status, 200);
    // The server is still answering after all of that.
    assert_eq!(render("width=16&height=12").status, 200);
}

#[test]
fn raw_volume_upload_is_solved_and_rendered() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let dims = [6usize, 5, 4];
    let data: Vec<u8> = (0..dims.iter().product::<usize>())
        .flat_map(|i| (0.2 + (i % 7) as f32 * 0.1).to_le_bytes())
        .collect();
    let r = request(
        addr,
        "POST",
        "/v1/volumes?dims=6,5,4",
        Some("application/octet-stream"),
        &data,
    )
    .unwrap();
    assert_eq!(r.status, 201, "{}", r.text());
    let file = r.json()["file"].as_str().unwrap().to_string();
    let text = scene(1, 0.7).replace(
        "generator = { kind = \"cloud\", seed = 1 }\ndims = [10, 10, 8]",
        &format!("file = \"{file}\"\ndims = [6, 5, 4]"),
    );
    let id = submit(addr, &text);
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    let v = get(addr, &format!("/v1/scenes/{id}")).unwrap().json();
    assert_eq!(v["dims"], serde_json::json!([6, 5, 4]));
    // Declaring other dims for the same data is refused, naming the key.
    let wrong = text.replace("dims = [6, 5, 4]", "dims = [6, 5, 5]");
    assert_error(&post_scene(addr, &wrong), 400, "volume.dims");
    let png = get(addr, &format!("/v1/scenes/{id}/render?width=32&height=24")).unwrap();
    assert_eq!(png_size(&png.body), (32, 24));
}

#[test]
fn delete_and_cancel() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let id = submit(addr, &scene(5, 0.9));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    let path = dir.path().join(format!("{id}.vrs"));
    assert!(path.exists());
    let del = request(addr, "DELETE", &format!("/v1/scenes/{id}"), None, &[]).unwrap();
    assert_eq!(del.status, 204);
    assert!(!path.exists(), "the cached solution is deleted");
    assert_eq!(get(addr, &format!("/v1/scenes/{id}")).unwrap().status, 404);
    assert_eq!(
        get(addr, &format!("/v1/scenes/{id}/render"))
            .unwrap()
            .status,
        404
    );

    // A slow solve (high albedo, unreachable tolerance, Jacobi) is cancelled while it runs.
    let slow = scene(9, 0.999)
        .replace("dims = [10, 10, 8]", "dims = [16, 16, 12]")
        .replace(
            "method = \"zonal\"",
            "method = \"discrete-ordinates\"\nbins = 24\niteration = \"jacobi\"\ntolerance = 1e-14\nmax_iterations = 10000",
        );
    let sid = submit(addr, &slow);
    let queued_behind = submit(addr, &scene(11, 0.5));
    let start = Instant::now();
    loop {
        let v = get(addr, &format!("/v1/scenes/{sid}")).unwrap().json();
        if v["state"] == "solving" && v["iteration"].as_u64().unwrap_or(0) >= 1 {
            // The predicted time of the whole solve, from before its first iteration.
            assert!(
                v["predicted_seconds"].as_f64().is_some_and(|t| t > 0.0),
                "{v}"
            );
            break;
        }
        assert_ne!(
            v["state"], "done",
            "the slow scene must still be running: {v}"
        );
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "no progress reported: {v}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let c = request(addr, "POST", &format!("/v1/scenes/{sid}/cancel"), None, &[]).unwrap();
    assert_eq!(c.status, 200, "{}", c.text());
    assert_eq!(c.json()["cancelled"], true);
    let v = get(addr, &format!("/v1/scenes/{sid}")).unwrap().json();
    assert_eq!(v["state"], "failed");
    assert_eq!(v["reason"], "cancelled");
    // The worker moves on to the next scene, and the cancelled one leaves no solution.
    assert_eq!(wait_finished(addr, &queued_behind)["state"], "done");
    assert!(!dir.path().join(format!("{sid}.vrs")).exists());
    assert_eq!(
        get(addr, &format!("/v1/scenes/{sid}/render"))
            .unwrap()
            .status,
        409
    );
}

#[test]
fn restart_serves_cached_solutions_and_never_corrupt_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (kept, resolved, orphan) = {
        let server = start(dir.path());
        let addr = server.addr;
        let ids: Vec<String> = [1, 2, 3]
            .iter()
            .map(|&s| submit(addr, &scene(s, 0.9)))
            .collect();
        for id in &ids {
            assert_eq!(wait_finished(addr, id)["state"], "done");
        }
        server.stop();
        (ids[0].clone(), ids[1].clone(), ids[2].clone())
    };
    // Damage two cached solutions: one whose scene text is kept, one whose text is lost.
    for id in [&resolved, &orphan] {
        let path = dir.path().join(format!("{id}.vrs"));
        let mut bytes = std::fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0xff;
        bytes[mid + 1] ^= 0x55;
        std::fs::write(&path, bytes).unwrap();
    }
    std::fs::remove_file(dir.path().join(format!("{orphan}.toml"))).unwrap();
    let reference =
        volrad::engine::solution::Solution::read(&dir.path().join(format!("{kept}.vrs"))).unwrap();

    let server = start(dir.path());
    let addr = server.addr;
    // The intact one is served at once, without a new solve.
    let v = get(addr, &format!("/v1/scenes/{kept}")).unwrap().json();
    assert_eq!(v["state"], "done", "{v}");
    let png = get(
        addr,
        &format!("/v1/scenes/{kept}/render?width=40&height=30"),
    )
    .unwrap();
    assert_eq!(png.status, 200);
    assert_eq!(png_size(&png.body), (40, 30));
    let served = server.service.solution(&kept).unwrap();
    assert_eq!(served.scene_hash, reference.scene_hash);

    // The orphan is reported, never served.
    let v = get(addr, &format!("/v1/scenes/{orphan}")).unwrap().json();
    assert_eq!(v["state"], "failed", "{v}");
    assert!(v["reason"].as_str().unwrap().contains("corrupt"), "{v}");
    assert_error(
        &get(addr, &format!("/v1/scenes/{orphan}/render")).unwrap(),
        409,
        "corrupt",
    );

    // The one with a known scene is solved again and then served from a valid file.
    let v = wait_finished(addr, &resolved);
    assert_eq!(v["state"], "done", "{v}");
    assert!(
        v["note"].as_str().unwrap_or_default().contains("corrupt"),
        "{v}"
    );
    volrad::engine::solution::Solution::read(&dir.path().join(format!("{resolved}.vrs")))
        .expect("re-solved file is valid");
    assert_eq!(
        get(
            addr,
            &format!("/v1/scenes/{resolved}/render?width=8&height=8")
        )
        .unwrap()
        .status,
        200
    );
}

/// A solution found in the cache after a restart is prepared for rendering in the background
/// (its first-bounce light-depth model built), as a fresh solve is before it reports done, so
/// that the first view costs what later ones do; no render is asked for here. The cache's
/// Debug shows `light_depth: None` until the model is built.
#[test]
fn restart_prepares_cached_solutions_for_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let id = {
        let server = start(dir.path());
        let id = submit(server.addr, &scene(4, 0.9));
        assert_eq!(wait_finished(server.addr, &id)["state"], "done");
        server.stop();
        id
    };
    let read =
        volrad::engine::solution::Solution::read(&dir.path().join(format!("{id}.vrs"))).unwrap();
    let unprepared = |sol: &volrad::engine::solution::Solution| {
        sol.channels
            .iter()
            .filter(|ch| format!("{:?}", ch.render_cache).contains("light_depth: None"))
            .count()
    };
    assert_eq!(
        unprepared(&read),
        read.channels.len(),
        "a solution read from a file starts unprepared"
    );

    let server = start(dir.path());
    let started = Instant::now();
    loop {
        let served = server.service.solution(&id).expect("served after restart");
        if unprepared(&served) == 0 {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(8),
            "the cached solution was not prepared for rendering: {:?}",
            served.channels[0].render_cache
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let png = get(
        server.addr,
        &format!("/v1/scenes/{id}/render?width=16&height=12"),
    )
    .unwrap();
    assert_eq!(png.status, 200, "{}", png.text());
}

#[test]
fn least_recently_used_solutions_are_evicted() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = ServiceConfig::new(dir.path());
    // Room for about two small solutions.
    let one = {
        let server = start(&dir.path().join("probe"));
        let id = submit(server.addr, &scene(1, 0.9));
        wait_finished(server.addr, &id);
        std::fs::metadata(dir.path().join("probe").join(format!("{id}.vrs")))
            .unwrap()
            .len()
    };
    config.cache_dir = dir.path().join("lru");
    config.limits.max_cache_bytes = one * 5 / 2;
    let server = ServerHandle::start(config, "127.0.0.1:0").unwrap();
    let addr = server.addr;
    let a = submit(addr, &scene(1, 0.9));
    wait_finished(addr, &a);
    let b = submit(addr, &scene(2, 0.9));
    wait_finished(addr, &b);
    // Use `a`, so `b` is the least recently used when `c` arrives.
    assert_eq!(
        get(addr, &format!("/v1/scenes/{a}/render?width=4&height=4"))
            .unwrap()
            .status,
        200
    );
    let c = submit(addr, &scene(4, 0.9));
    assert_eq!(wait_finished(addr, &c)["state"], "done");
    let vb = get(addr, &format!("/v1/scenes/{b}")).unwrap().json();
    assert_eq!(vb["state"], "failed", "{vb}");
    assert!(vb["reason"].as_str().unwrap().contains("evicted"));
    assert!(!dir.path().join("lru").join(format!("{b}.vrs")).exists());
    assert_eq!(
        get(addr, &format!("/v1/scenes/{a}")).unwrap().json()["state"],
        "done"
    );
    // Posting it again solves it again.
    assert_eq!(submit(addr, &scene(2, 0.9)), b);
    assert_eq!(wait_finished(addr, &b)["state"], "done");
}

#[test]
fn renders_beyond_the_waiting_limit_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = ServiceConfig::new(dir.path());
    config.limits.max_waiting_renders = 2;
    config.render_slots = 1;
    let server = ServerHandle::start(config, "127.0.0.1:0").unwrap();
    let addr = server.addr;
    let id = submit(addr, &scene(7, 0.9));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    // Twelve simultaneous large renders through one slot: at most one runs and two wait, so
    // some are refused with 503, and every one is answered either with an image or that.
    let statuses: Vec<u16> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..12)
            .map(|i| {
                let path = format!(
                    "/v1/scenes/{id}/render?width=600&height=450&spp=4&eye={},-20,4",
                    i
                );
                s.spawn(move || get(addr, &path).unwrap().status)
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(
        statuses.iter().all(|&c| c == 200 || c == 503),
        "{statuses:?}"
    );
    assert!(statuses.contains(&503), "{statuses:?}");
    assert!(statuses.contains(&200), "{statuses:?}");
    // Once the flood is over, renders are served again.
    assert_eq!(
        get(addr, &format!("/v1/scenes/{id}/render?width=8&height=8"))
            .unwrap()
            .status,
        200
    );
}

/// Several instances behind a load balancer share one cache directory: a scene solved by one
/// is served by the others (found by id or prefix, rendered the same), and posting it to
/// another is not solved again; a scene still solving elsewhere stays unknown there.
#[test]
fn instances_sharing_a_cache_directory_serve_each_others_solutions() {
    let dir = tempfile::tempdir().unwrap();
    let first = start(dir.path());
    let second = start(dir.path());
    let id = submit(first.addr, &scene(6, 0.9));
    assert_eq!(wait_finished(first.addr, &id)["state"], "done");

    // Unknown to the second instance when it started; found in the shared directory now.
    let v = get(second.addr, &format!("/v1/scenes/{}", &id[..12]))
        .unwrap()
        .json();
    assert_eq!(v["state"], "done", "{v}");
    assert_eq!(v["id"], id.as_str());
    let query = format!("/v1/scenes/{id}/render?width=32&height=24&format=pfm");
    let from_first = get(first.addr, &query).unwrap();
    let from_second = get(second.addr, &query).unwrap();
    assert_eq!(from_second.status, 200, "{}", from_second.text());
    assert_eq!(from_first.body, from_second.body);

    // Posting the same scene to a third instance serves the stored solution: no new solve.
    let third = start(dir.path());
    let r = post_scene(third.addr, &scene(6, 0.9));
    assert_eq!(r.status, 202, "{}", r.text());
    let v = r.json();
    assert_eq!(v["id"], id.as_str());
    assert_eq!(v["queued"], false, "{v}");
    assert_eq!(v["state"], "done", "{v}");

    // A scene text without its solution (as while another instance solves it) is left alone.
    let other = submit(first.addr, &scene(7, 0.9));
    let _ = wait_finished(first.addr, &other);
    std::fs::remove_file(dir.path().join(format!("{other}.vrs"))).unwrap();
    let r = get(second.addr, &format!("/v1/scenes/{other}")).unwrap();
    assert_eq!(r.status, 404, "{}", r.text());
    for server in [first, second, third] {
        server.stop();
    }
}

/// Volumes upload in every format the command line reads (told apart by their magic numbers),
/// are read with its readers before they are stored, and solve and render like raw ones;
/// a detached NRRD, a header over the cell limit and an unknown format are refused.
#[test]
fn volumes_upload_in_every_format_the_command_line_reads() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let root = crate::fixtures::root();
    let vol = {
        let path = dir.path().join("v.vol");
        let data = medium::volume_io::VolumeData::new(
            [5, 4, 3],
            (0..60).map(|i| 0.1 + (i % 5) as f32 * 0.2).collect(),
        )
        .unwrap();
        medium::volume_io::write_mitsuba_vol(&path, &data, 1.0).unwrap();
        std::fs::read(path).unwrap()
    };
    let uploads = [
        (
            std::fs::read(root.join("data/smoke32.nrrd")).unwrap(),
            "nrrd",
            [32, 32, 32],
        ),
        (vol, "vol", [5, 4, 3]),
        (
            std::fs::read(root.join("data/cloud24.vdb")).unwrap(),
            "vdb",
            [0, 0, 0],
        ),
        (
            std::fs::read(root.join("crates/medium/tests/data/nifti/float32_gz.nii.gz")).unwrap(),
            "nii.gz",
            [0, 0, 0],
        ),
    ];
    for (bytes, extension, dims) in uploads {
        let r = request(addr, "POST", "/v1/volumes", None, &bytes).unwrap();
        assert_eq!(r.status, 201, "{extension}: {}", r.text());
        let v = r.json();
        let file = v["file"].as_str().unwrap().to_string();
        assert!(file.ends_with(&format!(".{extension}")), "{v}");
        if dims != [0, 0, 0] {
            assert_eq!(v["dims"], serde_json::json!(dims), "{v}");
        }
        let text = scene(1, 0.7)
            .replace(
                "generator = { kind = \"cloud\", seed = 1 }\ndims = [10, 10, 8]",
                &format!("file = \"{file}\""),
            )
            .replace("method = \"zonal\"", "method = \"single-scatter\"");
        let id = submit(addr, &text);
        assert_eq!(wait_finished(addr, &id)["state"], "done", "{extension}");
        let png = get(addr, &format!("/v1/scenes/{id}/render?width=16&height=12")).unwrap();
        assert_eq!(png.status, 200, "{extension}: {}", png.text());
    }
    // A detached NRRD would read a file of the server's choosing: refused.
    let detached = b"NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nendian: little\n\
                     encoding: raw\ndata file: /etc/passwd\n\n";
    let r = request(addr, "POST", "/v1/volumes", None, detached).unwrap();
    assert_error(&r, 400, "same file");
    // A header asking for more cells than the server allows: refused before inflating data.
    let huge = b"NRRD0004\ntype: float\ndimension: 3\nsizes: 4000 4000 4000\nendian: little\n\
                 encoding: gzip\n\n\x1f\x8b";
    assert_error(
        &request(addr, "POST", "/v1/volumes", None, huge).unwrap(),
        400,
        "over the limit",
    );
    assert_error(
        &request(addr, "POST", "/v1/volumes", None, b"hello, volume").unwrap(),
        400,
        "?dims=",
    );
    server.stop();
}

/// A scene posted with `?name=` is listed and described by that name; a bad name or another
/// parameter is refused naming it; a PNG says the exposure it was made with, and whether the
/// service chose it (what the viewer's exposure slider starts from).
#[test]
fn named_scenes_and_the_exposure_of_each_image() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let text = scene(11, 0.9).replace("[render]\nexposure = 4.0\n", "");
    let post = |query: &str| {
        request(
            addr,
            "POST",
            &format!("/v1/scenes{query}"),
            Some("application/toml"),
            text.as_bytes(),
        )
        .unwrap()
    };
    assert_error(&post("?name="), 400, "name");
    assert_error(&post("?name=a%0Ab"), 400, "name");
    assert_error(&post("?nmae=cloud"), 400, "nmae");
    let r = post("?name=small%20cloud");
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(wait_finished(addr, &id)["name"], "small cloud");
    let list = get(addr, "/v1/scenes").unwrap().json();
    assert_eq!(list["scenes"][0]["name"], "small cloud", "{list}");

    let auto = get(addr, &format!("/v1/scenes/{id}/render?width=32&height=24")).unwrap();
    assert_eq!(auto.status, 200, "{}", auto.text());
    assert_eq!(auto.header("x-volrad-exposure-source"), Some("auto"));
    let chosen: f64 = auto.header("x-volrad-exposure").unwrap().parse().unwrap();
    assert!(chosen.is_finite() && chosen > 0.0, "{chosen}");
    let given = get(
        addr,
        &format!("/v1/scenes/{id}/render?width=32&height=24&exposure=2.5"),
    )
    .unwrap();
    assert_eq!(given.header("x-volrad-exposure-source"), Some("given"));
    assert_eq!(given.header("x-volrad-exposure"), Some("2.5"));

    // The name is stored with the scene: a restart on the same cache knows it.
    drop(server);
    let again = start(dir.path());
    let v = get(again.addr, &format!("/v1/scenes/{id}")).unwrap().json();
    assert_eq!(v["name"], "small cloud", "{v}");
}

/// A slice of a solved field is a PNG with one pixel per cell of the plane, its colour range
/// in a header; the lit side of a cloud is brighter in the map than its far side; bad
/// requests are refused naming the parameter.
#[test]
fn slices_of_solved_fields() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let id = submit(addr, &scene(5, 0.9));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    let slice = |query: &str| get(addr, &format!("/v1/scenes/{id}/slice{query}")).unwrap();
    // The scene's grid is 10×10×8; the light travels along −y, so it enters at high y.
    let z = slice("?field=fluence&axis=z&index=4&scale=log");
    assert_eq!(z.status, 200, "{}", z.text());
    assert_eq!(png_size(&z.body), (10, 10));
    let range = z.header("x-volrad-range").unwrap().to_string();
    let ends: Vec<f64> = range.split(' ').map(|v| v.parse().unwrap()).collect();
    assert!(
        ends[0] > 0.0 && (ends[1] / ends[0] - 1e4).abs() < 1.0,
        "{range}"
    );
    let img = image::load_from_memory(&z.body).unwrap().to_rgb8();
    // Row 0 is the top of the plane: high y, the lit side; compare the middle columns.
    let brightness = |row: u32| -> u32 { (3..7).map(|x| img.get_pixel(x, row).0[1] as u32).sum() };
    assert!(
        brightness(1) > brightness(8),
        "{} vs {}",
        brightness(1),
        brightness(8)
    );
    assert_eq!(
        png_size(&slice("?field=sigma-t&axis=x&scale=linear").body),
        (10, 8)
    );
    for (query, mentions) in [
        ("?field=heat", "field"),
        ("?axis=z&index=8", "index"),
        ("?channel=1", "channel"),
        ("?axsi=z", "axsi"),
    ] {
        assert_error(&slice(query), 400, mentions);
    }
}

/// The mean 8-bit value of a 32×24 render of scene `id` at `exposure`.
fn mean_pixel(addr: SocketAddr, id: &str, exposure: f64) -> f64 {
    let r = get(
        addr,
        &format!("/v1/scenes/{id}/render?width=32&height=24&exposure={exposure}"),
    )
    .unwrap();
    assert_eq!(r.status, 200, "{}", r.text());
    let img = image::load_from_memory(&r.body).unwrap().to_rgb8();
    img.pixels()
        .map(|p| p.0.iter().map(|&c| c as f64).sum::<f64>())
        .sum::<f64>()
        / (3 * img.width() * img.height()) as f64
}

/// A small cloud under a sky, by discrete ordinates (fast on 8×8×6 cells).
fn sky_scene() -> String {
    r#"
[volume]
generator = { kind = "cloud", seed = 3 }
dims = [8, 8, 6]

[medium]
albedo = 0.9
phase = { kind = "isotropic" }

[[light]]
kind = "sky"
sun_elevation_degrees = 60.0

[solve]
method = "discrete-ordinates"
bins = 24

[[camera]]
name = "front"
eye = [4.0, -16.0, 3.0]
target = [4.0, 4.0, 3.0]
up = [0.0, 0.0, 1.0]
fov_y = 40.0
width = 32
height = 24
"#
    .to_string()
}

/// `relight` makes a new scene from a stored one with its sky's keys changed and solves it;
/// the original stays; more skylight makes a brighter picture; bad bodies and scenes without
/// a sky are refused naming what was wrong.
#[test]
fn relighting_a_sky_makes_a_new_scene() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let r = request(
        addr,
        "POST",
        "/v1/scenes?name=sky%20cloud",
        Some("application/toml"),
        sky_scene().as_bytes(),
    )
    .unwrap();
    assert_eq!(r.status, 202, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let first = wait_finished(addr, &id);
    assert_eq!(first["sky"]["sun_elevation_degrees"], 60.0, "{first}");
    let relight = |id: &str, body: &str| {
        request(
            addr,
            "POST",
            &format!("/v1/scenes/{id}/relight"),
            Some("application/json"),
            body.as_bytes(),
        )
        .unwrap()
    };
    let relit = |body: &str| {
        let r = relight(&id, body);
        assert_eq!(r.status, 202, "{}", r.text());
        let new = r.json()["id"].as_str().unwrap().to_string();
        assert_ne!(new, id);
        (new.clone(), wait_finished(addr, &new))
    };
    let (low, low_v) = relit(r#"{"sun_elevation_degrees": 20, "sun_azimuth_degrees": 90}"#);
    assert_eq!(low_v["state"], "done", "{low_v}");
    assert_eq!(low_v["sky"]["sun_elevation_degrees"], 20.0, "{low_v}");
    assert_eq!(low_v["sky"]["sun_azimuth_degrees"], 90.0, "{low_v}");
    assert_eq!(low_v["name"], "sky cloud · sun 20°, 90°", "{low_v}");
    let original = get(addr, &format!("/v1/scenes/{id}")).unwrap().json();
    assert_eq!(original["sky"]["sun_elevation_degrees"], 60.0, "{original}");
    // Relighting the relit scene changes its sky again (and names it after the first).
    let r = relight(&low, r#"{"sun_elevation_degrees": 45}"#);
    assert_eq!(r.status, 202, "{}", r.text());
    let again = wait_finished(addr, r.json()["id"].as_str().unwrap());
    assert_eq!(again["sky"]["sun_azimuth_degrees"], 90.0, "{again}");
    assert_eq!(again["name"], "sky cloud · sun 45°, 90°", "{again}");

    // The same sun with no skylight and with a bright sky: the second is brighter.
    let mean = |id: &str| mean_pixel(addr, id, 2.0);
    let (dark, _) = relit(r#"{"sky_fraction": 0}"#);
    let (bright, _) = relit(r#"{"sky_fraction": 0.6}"#);
    let (d, b) = (mean(&dark), mean(&bright));
    assert!(d > 1.0, "the sun alone still lights the cloud: {d}");
    assert!(b > 1.5 * d, "more skylight, brighter: {b} vs {d}");

    for (body, status, mentions) in [
        (r#"{"sun_elevation": 10}"#, 400, "sun_elevation"),
        (r#"{"turbidity": "hazy"}"#, 400, "turbidity"),
        (
            r#"{"sun_elevation_degrees": 95}"#,
            400,
            "sun_elevation_degrees",
        ),
        (r#"{}"#, 400, "nothing to change"),
        ("[1, 2]", 400, "JSON object"),
    ] {
        assert_error(&relight(&id, body), status, mentions);
    }
    assert_error(
        &relight("0123456789ab", r#"{"turbidity": 4}"#),
        404,
        "0123456789ab",
    );
    let plain = submit(addr, &scene(5, 0.9));
    assert_error(&relight(&plain, r#"{"turbidity": 4}"#), 400, "no sky");
}

/// An environment map is uploaded like a volume (OpenEXR or PFM) and named by what the
/// upload returns; a scene naming any other file as its map is refused before anything is
/// read.
#[test]
fn environment_maps_are_uploads() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    // A 4 × 2 grey PFM: a bright upper row, a dark lower one.
    let mut pfm = b"Pf\n4 2\n-1.0\n".to_vec();
    for v in [0.1f32, 0.1, 0.1, 0.1, 0.8, 0.8, 0.8, 0.8] {
        pfm.extend(v.to_le_bytes());
    }
    let r = request(addr, "POST", "/v1/volumes", None, &pfm).unwrap();
    assert_eq!(r.status, 201, "{}", r.text());
    let v = r.json();
    assert_eq!(v["format"], "PFM environment map", "{v}");
    assert_eq!(v["dims"], serde_json::json!([4, 2, 1]), "{v}");
    let file = v["file"].as_str().unwrap().to_string();
    assert!(file.ends_with(".pfm"), "{file}");
    let with_map = |name: &str| {
        scene(5, 0.9).replace(
            "kind = \"directional\"\ndirection = [0.5, -1.0, 0.35]\nirradiance = 1.0",
            &format!("kind = \"environment\"\nfile = \"{name}\""),
        )
    };
    let id = submit(addr, &with_map(&file));
    assert_eq!(wait_finished(addr, &id)["state"], "done");
    let img = get(addr, &format!("/v1/scenes/{id}/render?width=16&height=12")).unwrap();
    assert_eq!(img.status, 200, "{}", img.text());
    for name in ["/etc/passwd", "../x.exr", &file.replace(".pfm", ".exr")] {
        assert_error(&post_scene(addr, &with_map(name)), 400, "light[0].file");
    }
    // A map with a negative texel is refused at upload, naming it.
    let mut bad = b"Pf\n2 1\n-1.0\n".to_vec();
    bad.extend(1.0f32.to_le_bytes());
    bad.extend((-1.0f32).to_le_bytes());
    let r = request(addr, "POST", "/v1/volumes", None, &bad).unwrap();
    assert_error(&r, 400, "texel (1, 0)");
}

/// Under a `[ground]` relight's `ground_albedo` is the ground's (the sky's own ground is
/// hidden): the description carries it, and a brighter ground makes a brighter picture.
#[test]
fn relighting_a_ground_changes_its_albedo() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(dir.path());
    let addr = server.addr;
    let text = sky_scene().replace("[solve]", "[ground]\nalbedo = 0.1\n\n[solve]");
    let id = submit(addr, &text);
    let first = wait_finished(addr, &id);
    assert_eq!(
        first["ground"]["albedo"],
        serde_json::json!([0.1, 0.1, 0.1]),
        "{first}"
    );
    assert!((first["sky"]["ground_albedo"].as_f64().unwrap() - 0.1).abs() < 1e-9);
    let r = request(
        addr,
        "POST",
        &format!("/v1/scenes/{id}/relight"),
        Some("application/json"),
        br#"{"ground_albedo": 0.7}"#,
    )
    .unwrap();
    assert_eq!(r.status, 202, "{}", r.text());
    let relit = r.json()["id"].as_str().unwrap().to_string();
    let v = wait_finished(addr, &relit);
    assert_eq!(
        v["ground"]["albedo"],
        serde_json::json!([0.7, 0.7, 0.7]),
        "{v}"
    );
    let (dark, bright) = (mean_pixel(addr, &id, 1.0), mean_pixel(addr, &relit, 1.0));
    assert!(
        bright > 1.3 * dark,
        "a brighter ground, a brighter picture: {bright} vs {dark}"
    );
}
