//! HTTP routes of `volrad serve` and their JSON errors (`{"error": "..."}` with a 4xx/5xx
//! status). Every input is checked against [`Limits`](super::Limits) before work starts.

use std::collections::HashMap;
use std::sync::Arc;

use axum::body::{Body, Bytes};
use axum::extract::rejection::BytesRejection;
use axum::extract::{DefaultBodyLimit, Path, RawQuery, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::Next;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use glam::DVec3;
use scene::CameraSpec;
use serde_json::{json, Value};

use super::cache::{self, is_id};
use super::jobs::{describe, parse_scene, JobState, Service, SubmitError};
use crate::views::CameraRequest;

/// The OpenAPI description served at `/v1/openapi.json`.
pub const OPENAPI: &str = include_str!("openapi.json");
/// The viewer page served at `/`.
pub const VIEWER: &str = include_str!("viewer.html");

/// An error answer: status and a message for people.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
}

impl ApiError {
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        ApiError {
            status,
            message: message.into(),
        }
    }
    fn bad(message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, message)
    }
    fn not_found(id: &str) -> Self {
        Self::new(StatusCode::NOT_FOUND, format!("no scene with id `{id}`"))
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.status, Json(json!({ "error": self.message }))).into_response()
    }
}

type ApiResult<T> = Result<T, ApiError>;

pub fn router(service: Service) -> Router {
    let body_limit = service.inner.limits.max_body_bytes;
    Router::new()
        .route("/", get(viewer))
        .route("/v1/openapi.json", get(openapi))
        .route("/v1/scenes", post(post_scene).get(list_scenes))
        .route("/v1/scenes/{id}", get(get_scene).delete(delete_scene))
        .route("/v1/scenes/{id}/cancel", post(cancel_scene))
        .route("/v1/scenes/{id}/relight", post(relight))
        .route("/v1/scenes/{id}/render", get(render))
        .route("/v1/scenes/{id}/slice", get(slice))
        .route("/v1/volumes", post(post_volume))
        .fallback(|| async { ApiError::new(StatusCode::NOT_FOUND, "no such route") })
        .layer(DefaultBodyLimit::max(body_limit))
        .layer(axum::middleware::from_fn_with_state(
            service.clone(),
            read_body_in_time,
        ))
        .with_state(service)
}

/// Reads every request's whole body before it is routed, under the body limit and the read
/// timeout ([`Limits`](super::Limits)): a `Content-Length` over the limit is refused (413)
/// before a byte of the body is read, a body that grows over it (chunked, or longer than
/// announced) as soon as it does, and one that has not all arrived within the timeout —
/// a client sending slowly — is answered 408; hyper then closes the connection. Without
/// this a client announcing a large body and sending nothing held its connection forever.
async fn read_body_in_time(State(service): State<Service>, req: Request, next: Next) -> Response {
    let limits = &service.inner.limits;
    let max = limits.max_body_bytes;
    let announced = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    if let Some(len) = announced.filter(|&n| n > max as u64) {
        return ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("request body of {len} bytes is larger than the server's limit of {max} bytes"),
        )
        .into_response();
    }
    let (parts, body) = req.into_parts();
    let limited = http_body_util::Limited::new(body, max);
    let read = http_body_util::BodyExt::collect(limited);
    match tokio::time::timeout(limits.request_read_timeout, read).await {
        Ok(Ok(collected)) => {
            let body = Body::from(collected.to_bytes());
            next.run(Request::from_parts(parts, body)).await
        }
        Ok(Err(e)) if e.is::<http_body_util::LengthLimitError>() => ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("request body is larger than the server's limit of {max} bytes"),
        )
        .into_response(),
        Ok(Err(e)) => ApiError::bad(format!("cannot read the request body: {e}")).into_response(),
        Err(_) => ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request body did not arrive within {} s",
                limits.request_read_timeout.as_secs_f64()
            ),
        )
        .into_response(),
    }
}

async fn viewer() -> Html<&'static str> {
    Html(VIEWER)
}

async fn openapi() -> Response {
    ([(header::CONTENT_TYPE, "application/json")], OPENAPI).into_response()
}

fn body_bytes(body: Result<Bytes, BytesRejection>) -> ApiResult<Bytes> {
    body.map_err(|e| {
        let status = e.status();
        if status == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::new(status, "request body is larger than the server's limit")
        } else {
            ApiError::new(status, format!("cannot read the request body: {e}"))
        }
    })
}

fn query_map(RawQuery(q): RawQuery) -> ApiResult<HashMap<String, String>> {
    query_from_str(q.as_deref().unwrap_or(""))
}

/// A query string (what follows `?`) as a map, decoded as axum's `Query` would
/// (`application/x-www-form-urlencoded`; a repeated key keeps its last value); public so that
/// the fuzz targets and property tests reach it.
pub fn query_from_str(query: &str) -> ApiResult<HashMap<String, String>> {
    serde_urlencoded::from_str(query)
        .map_err(|e| ApiError::bad(format!("malformed query string: {e}")))
}

/// The `?name=` of a request that posts a scene (the only parameter it reads), checked.
fn name_parameter(q: RawQuery) -> ApiResult<Option<String>> {
    let q = query_map(q)?;
    refuse_unknown_parameters(&q, &["name"])?;
    q.get("name")
        .map(|n| check_scene_name(n).map_err(ApiError::bad))
        .transpose()
}

/// `POST /v1/scenes[?name=NAME]`: TOML (default) or JSON (`Content-Type: application/json`)
/// scene text; `name` is what lists and the viewer call it.
async fn post_scene(
    State(service): State<Service>,
    headers: HeaderMap,
    q: RawQuery,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<Response> {
    let name = name_parameter(q)?;
    let body = body_bytes(body)?;
    let is_json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.contains("json"));
    let text =
        std::str::from_utf8(&body).map_err(|_| ApiError::bad("the scene is not UTF-8 text"))?;
    let table: toml::Table = if is_json {
        json_scene_table(text)?
    } else {
        // Syntax errors are reported by the scene parser, with the line.
        match text.parse::<toml::Table>() {
            Ok(t) => t,
            Err(_) => {
                let e = parse_scene(&service.inner.cache, text).err();
                return Err(ApiError::bad(
                    e.map(|e| e.to_string())
                        .unwrap_or_else(|| "not valid TOML".into()),
                ));
            }
        }
    };
    submit_table(&service, table, name).await
}

/// Checks, parses and submits a scene given as a TOML table (what `POST /v1/scenes` and
/// `relight` share): 202 with the scene's description, or the error naming what was wrong.
async fn submit_table(
    service: &Service,
    table: toml::Table,
    name: Option<String>,
) -> ApiResult<Response> {
    let service = service.clone();
    check_scene_limits(&service, &table)?;
    let canonical = toml::to_string(&table)
        .map_err(|e| ApiError::bad(format!("cannot re-encode the scene: {e}")))?;
    let cache = service.inner.cache.clone();
    let parse_text = canonical.clone();
    // Generators and volume files can take a moment: off the async threads.
    let scene = tokio::task::spawn_blocking(move || parse_scene(&cache, &parse_text))
        .await
        .map_err(|_| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "scene parsing panicked"))?
        .map_err(|e| {
            // Name uploaded volumes as the client did, not by their place on the server.
            let dir = format!("{}/", service.inner.cache.volumes_dir().display());
            ApiError::bad(e.to_string().replace(&dir, ""))
        })?;
    let cells: usize = scene.medium.grid().dims.iter().product();
    if cells > service.inner.limits.max_cells {
        return Err(ApiError::bad(format!(
            "volume.dims: {cells} cells exceed the server's limit of {}",
            service.inner.limits.max_cells
        )));
    }
    // The model `volrad info` prints, against the per-solve limit (or less, when the machine
    // has less available): refused now, not after queueing. The worker checks again when the
    // solve starts, as memory may have gone meanwhile.
    crate::engine::budget::check_solve(&scene, &scene.solve, Some(service.solve_memory_limit()))
        .map_err(|e| ApiError::bad(format!("{e:#}")))?;
    // Submitting may read a solution another instance wrote (Service::adopt).
    let submitted = tokio::task::block_in_place(|| service.submit(scene, &canonical));
    let (id, queued) = submitted.map_err(|e| match e {
        SubmitError::TooMany(n) => ApiError::new(
            StatusCode::TOO_MANY_REQUESTS,
            format!("the server already holds {n} scenes; DELETE some first"),
        ),
        SubmitError::Storage(m) => ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, m),
    })?;
    if let Some(name) = name {
        service.set_name(&id, name);
    }
    let jobs = service.lock();
    let mut v = jobs
        .get(&id)
        .map(|j| describe(&id, j, false))
        .unwrap_or_else(|| json!({ "id": id }));
    v["queued"] = json!(queued);
    drop(jobs);
    let mut resp = (StatusCode::ACCEPTED, Json(v)).into_response();
    if let Ok(loc) = format!("/v1/scenes/{id}").parse() {
        resp.headers_mut().insert(header::LOCATION, loc);
    }
    Ok(resp)
}

/// A JSON scene (`POST /v1/scenes` with a JSON content type) as the TOML table the scene
/// parser reads; public so that the fuzz targets and property tests reach it.
pub fn json_scene_table(text: &str) -> Result<toml::Table, ApiError> {
    let v: Value =
        serde_json::from_str(text).map_err(|e| ApiError::bad(format!("not valid JSON: {e}")))?;
    match json_to_toml(&v, "")? {
        toml::Value::Table(t) => Ok(t),
        _ => Err(ApiError::bad("a JSON scene must be an object")),
    }
}

/// JSON → TOML, refusing what TOML cannot hold (null, numbers out of range).
fn json_to_toml(v: &Value, key: &str) -> ApiResult<toml::Value> {
    let name = |k: &str| {
        if k.is_empty() {
            "(top level)".to_string()
        } else {
            k.to_string()
        }
    };
    Ok(match v {
        Value::Null => {
            return Err(ApiError::bad(format!(
                "`{}`: null is not allowed",
                name(key)
            )))
        }
        Value::Bool(b) => toml::Value::Boolean(*b),
        Value::Number(n) => {
            match n.as_i64() {
                Some(i) => toml::Value::Integer(i),
                None => toml::Value::Float(n.as_f64().ok_or_else(|| {
                    ApiError::bad(format!("`{}`: number out of range", name(key)))
                })?),
            }
        }
        Value::String(s) => toml::Value::String(s.clone()),
        Value::Array(a) => toml::Value::Array(
            a.iter()
                .enumerate()
                .map(|(i, x)| json_to_toml(x, &format!("{key}[{i}]")))
                .collect::<ApiResult<_>>()?,
        ),
        Value::Object(o) => {
            let mut t = toml::Table::new();
            for (k, x) in o {
                let sub = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                t.insert(k.clone(), json_to_toml(x, &sub)?);
            }
            toml::Value::Table(t)
        }
    })
}

/// Limits that must hold before the scene is built (a generator on huge dims would allocate),
/// and the rule that the files a scene names (its volume, an environment map) are uploads.
fn check_scene_limits(service: &Service, table: &toml::Table) -> ApiResult<()> {
    let limits = &service.inner.limits;
    let lights = table.get("light").and_then(|l| l.as_array());
    for (i, light) in lights.into_iter().flatten().enumerate() {
        let Some(file) = light.as_table().and_then(|t| t.get("file")) else {
            continue;
        };
        let name = file.as_str().unwrap_or("");
        if !is_upload_name(name, &MAP_EXTENSIONS) {
            return Err(ApiError::bad(format!(
                "light[{i}].file: the service only reads uploaded maps: POST the map (OpenEXR \
                 or PFM) to /v1/volumes and use the `file` it returns"
            )));
        }
        if !service.inner.cache.volume_path(name).exists() {
            return Err(ApiError::bad(format!(
                "light[{i}].file: no uploaded map `{name}` (upload it to /v1/volumes first)"
            )));
        }
    }
    let volume = table.get("volume").and_then(|v| v.as_table());
    if let Some(volume) = volume {
        if let Some(file) = volume.get("file") {
            let name = file.as_str().unwrap_or("");
            if !is_upload_name(name, &UPLOAD_EXTENSIONS) {
                return Err(ApiError::bad(
                    "volume.file: the service only reads uploaded volumes: POST the volume file \
                     (NRRD, Mitsuba .vol, OpenVDB, NIfTI, or raw f32 with ?dims=NX,NY,NZ) to \
                     /v1/volumes and use the `file` it returns",
                ));
            }
            if !service.inner.cache.volume_path(name).exists() {
                return Err(ApiError::bad(format!(
                    "volume.file: no uploaded volume `{name}` (upload it to /v1/volumes first)"
                )));
            }
        }
        if let Some(dims) = volume.get("dims").and_then(|d| d.as_array()) {
            let mut cells: u128 = 1;
            for d in dims {
                if let Some(n) = d.as_integer() {
                    cells = cells.saturating_mul(n.max(0) as u128);
                }
            }
            if cells > limits.max_cells as u128 {
                return Err(ApiError::bad(format!(
                    "volume.dims: {cells} cells exceed the server's limit of {}",
                    limits.max_cells
                )));
            }
        }
    }
    if let Some(solve) = table.get("solve").and_then(|v| v.as_table()) {
        if let Some(b) = solve.get("bins").and_then(|v| v.as_integer()) {
            if b > limits.max_bins as i64 {
                return Err(ApiError::bad(format!(
                    "solve.bins: {b} exceeds the server's limit of {}",
                    limits.max_bins
                )));
            }
        }
        if let Some(m) = solve.get("max_iterations").and_then(|v| v.as_integer()) {
            if m > limits.max_iterations as i64 {
                return Err(ApiError::bad(format!(
                    "solve.max_iterations: {m} exceeds the server's limit of {}",
                    limits.max_iterations
                )));
            }
        }
    }
    Ok(())
}

async fn list_scenes(State(service): State<Service>) -> Json<Value> {
    let jobs = service.lock();
    let mut ids: Vec<&String> = jobs.keys().collect();
    ids.sort();
    let scenes: Vec<Value> = ids
        .iter()
        .map(|id| describe(id, &jobs[*id], false))
        .collect();
    Json(json!({ "scenes": scenes }))
}

/// The full id for a path's id or unique prefix: 404 when nothing matches, 400 when the
/// prefix names several scenes.
fn resolve(service: &Service, id: &str) -> ApiResult<String> {
    // An unknown id may read a solution file another instance wrote (Service::adopt): the
    // read blocks, so the runtime moves this thread's other tasks elsewhere meanwhile.
    match tokio::task::block_in_place(|| service.resolve(id)) {
        Ok(Some(full)) => Ok(full),
        Ok(None) => Err(ApiError::not_found(id)),
        Err(candidates) => Err(ApiError::bad(format!(
            "scene id `{id}` is ambiguous: it begins {} ids ({}); give more of it",
            candidates.len(),
            candidates.join(", ")
        ))),
    }
}

async fn get_scene(
    State(service): State<Service>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    let id = resolve(&service, &id)?;
    let jobs = service.lock();
    let job = jobs.get(&id).ok_or_else(|| ApiError::not_found(&id))?;
    Ok(Json(describe(&id, job, true)))
}

async fn delete_scene(
    State(service): State<Service>,
    Path(id): Path<String>,
) -> ApiResult<StatusCode> {
    let id = resolve(&service, &id)?;
    if service.delete(&id) {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(ApiError::not_found(&id))
    }
}

async fn cancel_scene(
    State(service): State<Service>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    let id = resolve(&service, &id)?;
    let cancelled = service
        .cancel(&id)
        .ok_or_else(|| ApiError::not_found(&id))?;
    let jobs = service.lock();
    let mut v = jobs
        .get(&id)
        .map(|j| describe(&id, j, false))
        .unwrap_or(json!({}));
    v["cancelled"] = json!(cancelled);
    Ok(Json(v))
}

/// The sky keys `relight` may change (`[[light]] kind = "sky"`; docs/scene-format.md).
pub const RELIGHT_KEYS: [&str; 5] = [
    "sun_elevation_degrees",
    "sun_azimuth_degrees",
    "turbidity",
    "sky_fraction",
    "ground_albedo",
];

/// `POST /v1/scenes/{id}/relight[?name=NAME]`: a new scene, made from this one's text with its
/// sky changed by the JSON body (any of [`RELIGHT_KEYS`], numbers), posted and solved like any
/// scene. The original stays as it is. Without `name` the new scene is called after the
/// original and its sun.
async fn relight(
    State(service): State<Service>,
    Path(id): Path<String>,
    q: RawQuery,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<Response> {
    let name = name_parameter(q)?;
    let id = resolve(&service, &id)?;
    let body = body_bytes(body)?;
    let changes: serde_json::Map<String, Value> = serde_json::from_slice(&body)
        .map_err(|e| ApiError::bad(format!("the body is not a JSON object: {e}")))?;
    let mut numbers = Vec::with_capacity(changes.len());
    for (key, value) in &changes {
        if !RELIGHT_KEYS.contains(&key.as_str()) {
            return Err(ApiError::bad(format!(
                "unknown key `{key}`: relight changes {}",
                RELIGHT_KEYS.join(", ")
            )));
        }
        let v = value
            .as_f64()
            .ok_or_else(|| ApiError::bad(format!("`{key}` must be a number, not {value}")))?;
        numbers.push((key.clone(), v));
    }
    if numbers.is_empty() {
        return Err(ApiError::bad(format!(
            "nothing to change: give any of {}",
            RELIGHT_KEYS.join(", ")
        )));
    }
    let (text, base_name) = {
        let jobs = service.lock();
        let job = jobs.get(&id).ok_or_else(|| ApiError::not_found(&id))?;
        let base_name = job.name.clone();
        drop(jobs);
        let text = std::fs::read_to_string(service.inner.cache.scene_path(&id)).map_err(|_| {
            ApiError::new(
                StatusCode::CONFLICT,
                format!(
                    "scene `{id}`'s text is not kept here (only its solution): post the scene \
                     again to relight it"
                ),
            )
        })?;
        (text, base_name)
    };
    let mut table: toml::Table = text.parse().map_err(|e| {
        ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("scene `{id}`'s stored text does not parse: {e}"),
        )
    })?;
    let sky = table
        .get_mut("light")
        .and_then(|l| l.as_array_mut())
        .and_then(|lights| {
            lights.iter_mut().find_map(|l| {
                l.as_table_mut()
                    .filter(|t| t.get("kind").and_then(|k| k.as_str()) == Some("sky"))
            })
        })
        .ok_or_else(|| {
            ApiError::bad(format!(
                "scene `{id}` has no sky ([[light]] kind = \"sky\"): only a sky can be relit"
            ))
        })?;
    for (key, v) in &numbers {
        sky.insert(key.clone(), toml::Value::Float(*v));
    }
    // Under a real ground the sky's own ground is hidden: its albedo is the [ground]'s.
    let ground_albedo = numbers
        .iter()
        .find_map(|(k, v)| (k == "ground_albedo").then_some(*v));
    let number = |key: &str| {
        sky.get(key)
            .and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))
    };
    let sun = match (
        number("sun_elevation_degrees"),
        number("sun_azimuth_degrees"),
    ) {
        (Some(el), az) => format!("sun {el}°, {}°", az.unwrap_or(0.0)),
        _ => "relit".to_string(),
    };
    if let (Some(a), Some(ground)) = (
        ground_albedo,
        table.get_mut("ground").and_then(|g| g.as_table_mut()),
    ) {
        ground.insert("albedo".into(), toml::Value::Float(a));
    }
    let name = name.or_else(|| {
        let base = base_name.unwrap_or_else(|| id[..12.min(id.len())].to_string());
        // Relighting a relit scene names it after the first.
        let base = base.split(" · ").next().unwrap_or_default().to_string();
        check_scene_name(&format!("{base} · {sun}")).ok()
    });
    submit_table(&service, table, name).await
}

/// The file names uploaded volumes are stored under: `SHA256.EXT`, by format.
const UPLOAD_EXTENSIONS: [&str; 6] = ["f32", "nrrd", "vol", "vdb", "nii", "nii.gz"];

/// The file names uploaded environment maps are stored under: `SHA256.EXT`.
const MAP_EXTENSIONS: [&str; 2] = ["exr", "pfm"];

/// Whether `name` is what an upload of one of `extensions` is stored under.
fn is_upload_name(name: &str, extensions: &[&str]) -> bool {
    extensions.iter().any(|ext| {
        name.strip_suffix(ext)
            .and_then(|stem| stem.strip_suffix('.'))
            .is_some_and(|stem| stem.len() == 64 && is_id(stem))
    })
}

/// `POST /v1/volumes`: a volume in any format the command line reads — NRRD (data attached),
/// Mitsuba `.vol`, OpenVDB, NIfTI (`.nii`, gzip or not), told apart by their magic numbers —
/// or raw little-endian f32 (x fastest) with `?dims=NX,NY,NZ`. Read with the command line's
/// readers before it is stored, under the server's cell limit.
async fn post_volume(
    State(service): State<Service>,
    q: RawQuery,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<Response> {
    let q = query_map(q)?;
    refuse_unknown_parameters(&q, &["dims"])?;
    let body = body_bytes(body)?;
    let limits = &service.inner.limits;
    let (dims, extension, format) = match q.get("dims") {
        Some(dims_text) => (
            raw_volume_dims(&body, dims_text, limits.max_cells)?,
            "f32",
            "raw f32",
        ),
        None => {
            let max_cells = limits.max_cells as u64;
            let body = body.clone();
            tokio::task::spawn_blocking(move || read_uploaded_volume(&body, max_cells))
                .await
                .map_err(|_| {
                    ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "volume reading panicked")
                })??
        }
    };
    let name = {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        h.update(&body);
        let hex: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        format!("{hex}.{extension}")
    };
    let svc = service.clone();
    let stored = name.clone();
    tokio::task::spawn_blocking(move || -> anyhow::Result<()> {
        let _guard = svc
            .inner
            .volume_lock
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let path = svc.inner.cache.volume_path(&stored);
        if !path.exists() {
            cache::write_atomic(&path, &body)?;
        }
        // Oldest uploads go first once the store is over its limit (never the new one).
        let vols = svc.inner.cache.volumes_by_age();
        let mut total: u64 = vols.iter().map(|v| v.1).sum();
        for (p, n) in vols {
            if total <= svc.inner.limits.max_volume_bytes {
                break;
            }
            if p != path {
                let _ = std::fs::remove_file(&p);
                total -= n;
            }
        }
        Ok(())
    })
    .await
    .map_err(|_| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "volume store panicked"))?
    .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")))?;
    Ok((
        StatusCode::CREATED,
        Json(json!({ "file": name, "dims": dims, "format": format })),
    )
        .into_response())
}

/// The dims of a raw f32 upload, checked against the body's length, the cell limit and the
/// values (finite).
fn raw_volume_dims(body: &[u8], dims_text: &str, max_cells: usize) -> ApiResult<[usize; 3]> {
    let parts: Vec<&str> = dims_text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(ApiError::bad(format!(
            "dims: expected NX,NY,NZ, got `{dims_text}`"
        )));
    }
    let mut dims = [0usize; 3];
    for (slot, p) in dims.iter_mut().zip(&parts) {
        *slot = p
            .parse::<usize>()
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| ApiError::bad(format!("dims: `{p}` is not a positive integer")))?;
    }
    let cells = dims
        .iter()
        .try_fold(1usize, |a, &n| a.checked_mul(n))
        .unwrap_or(usize::MAX);
    if cells > max_cells {
        return Err(ApiError::bad(format!(
            "dims: {cells} cells exceed the server's limit of {max_cells}"
        )));
    }
    if body.len() as u128 != cells as u128 * 4 {
        return Err(ApiError::bad(format!(
            "volume size {} bytes does not match dims {}×{}×{} ({} bytes of f32)",
            body.len(),
            dims[0],
            dims[1],
            dims[2],
            cells as u128 * 4
        )));
    }
    if let Some(i) = body
        .chunks_exact(4)
        .position(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
    {
        return Err(ApiError::bad(format!(
            "volume value {i} is not a finite number"
        )));
    }
    Ok(dims)
}

/// Reads a self-describing upload with the command line's readers (so a stored volume is one
/// a scene can load): its dims, the extension it is stored under, and its format's name.
fn read_uploaded_volume(
    body: &[u8],
    max_cells: u64,
) -> ApiResult<([usize; 3], &'static str, &'static str)> {
    use medium::volume_io::{read_volume_bytes_capped, VolumeFormat};
    if let Some(map) = read_uploaded_map(body)? {
        return Ok(map);
    }
    let format = VolumeFormat::sniff(body).ok_or_else(|| {
        ApiError::bad(
            "volume: not a format volrad reads (NRRD, Mitsuba .vol, OpenVDB, NIfTI); for raw \
             f32 give ?dims=NX,NY,NZ",
        )
    })?;
    let extension = format.extension(body);
    let label = format!("upload.{extension}");
    let data = read_volume_bytes_capped(body, format, std::path::Path::new(&label), max_cells)
        .map_err(|e| ApiError::bad(format!("volume: {e}")))?;
    Ok((data.dims, extension, format.name()))
}

/// An environment map upload (OpenEXR or PFM, told by their magic numbers), read and checked
/// as a scene's `[[light]] file` would be: `([width, height, 1], extension, format)`, or
/// `None` for anything else.
fn read_uploaded_map(body: &[u8]) -> ApiResult<Option<([usize; 3], &'static str, &'static str)>> {
    let (extension, format, image) = if body.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        (
            "exr",
            "OpenEXR environment map",
            gather::image_io::parse_exr(body),
        )
    } else if body.len() > 3
        && (body.starts_with(b"PF") || body.starts_with(b"Pf"))
        && body[2].is_ascii_whitespace()
    {
        (
            "pfm",
            "PFM environment map",
            gather::image_io::parse_pfm(body),
        )
    } else {
        return Ok(None);
    };
    let image = image.map_err(|e| ApiError::bad(format!("environment map: {e}")))?;
    let (w, h) = (image.width as usize, image.height as usize);
    let channels = image.channels as usize;
    medium::environment_map::EnvironmentMap::from_interleaved(
        w,
        h,
        channels,
        &image.pixels,
        DVec3::Z,
        0.0,
        1.0,
    )
    .map_err(|e| ApiError::bad(format!("environment map: {e}")))?;
    Ok(Some(([w, h, 1], extension, format)))
}

fn parse_f64(q: &HashMap<String, String>, key: &str) -> ApiResult<Option<f64>> {
    match q.get(key) {
        None => Ok(None),
        Some(s) => s
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .map(Some)
            .ok_or_else(|| ApiError::bad(format!("{key}: `{s}` is not a finite number"))),
    }
}

fn parse_u32(q: &HashMap<String, String>, key: &str) -> ApiResult<Option<u32>> {
    match q.get(key) {
        None => Ok(None),
        Some(s) => s
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| n >= 1)
            .map(Some)
            .ok_or_else(|| ApiError::bad(format!("{key}: `{s}` is not a positive integer"))),
    }
}

fn parse_vec3(q: &HashMap<String, String>, key: &str) -> ApiResult<Option<DVec3>> {
    let Some(s) = q.get(key) else { return Ok(None) };
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(ApiError::bad(format!("{key}: expected x,y,z, got `{s}`")));
    }
    let mut v = [0.0; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| ApiError::bad(format!("{key}: `{p}` is not a finite number")))?;
    }
    Ok(Some(DVec3::from(v)))
}

/// Output formats of `render`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum RenderFormat {
    Png,
    Pfm,
}

/// What a render request's query string asks, checked against the limits that need no
/// solution: everything but resolving the camera, which [`render_camera`] does.
#[derive(Clone, Debug)]
pub struct RenderQuery {
    format: RenderFormat,
    pub spp: Option<u32>,
    pub exposure: Option<f64>,
    pub camera: CameraRequest,
}

/// Reads the query of `GET /v1/scenes/{id}/render` (unknown parameters, format, spp,
/// exposure, the camera overrides); public so that the fuzz targets and property tests reach
/// it.
pub fn parse_render_query(
    q: &HashMap<String, String>,
    limits: &super::Limits,
) -> ApiResult<RenderQuery> {
    refuse_unknown_parameters(q, &RENDER_PARAMETERS)?;
    let format = match q.get("format").map(String::as_str) {
        None | Some("png") => RenderFormat::Png,
        Some("pfm") => RenderFormat::Pfm,
        Some(other) => {
            return Err(ApiError::bad(format!(
                "format: `{other}` is not png or pfm"
            )))
        }
    };
    let spp = parse_u32(q, "spp")?;
    if let Some(s) = spp {
        if s > limits.max_spp {
            return Err(ApiError::bad(format!(
                "spp: {s} exceeds the server's limit of {}",
                limits.max_spp
            )));
        }
    }
    let exposure = parse_f64(q, "exposure")?;
    if exposure.is_some_and(|e| e < 0.0) {
        return Err(ApiError::bad("exposure: must not be negative"));
    }
    let fov = parse_f64(q, "fov")?;
    if let Some(f) = fov {
        if !(f > 0.0 && f < 180.0) {
            return Err(ApiError::bad(format!(
                "fov: {f} is not in (0, 180) degrees"
            )));
        }
    }
    let camera = CameraRequest {
        name: q.get("camera").cloned(),
        eye: parse_vec3(q, "eye")?,
        target: parse_vec3(q, "target")?,
        up: parse_vec3(q, "up")?,
        fov_y_degrees: fov,
        width: parse_u32(q, "width")?,
        height: parse_u32(q, "height")?,
    };
    Ok(RenderQuery {
        format,
        spp,
        exposure,
        camera,
    })
}

/// The camera of a render request: the scene camera named by `camera` (default: the
/// solution's first, or one looking at the volume), with the query's overrides — the same
/// rules as the command line's ([`CameraRequest`]) — checked against the limits.
pub fn render_camera(
    request: &CameraRequest,
    cameras: &[CameraSpec],
    grid: &medium::Grid,
    limits: &super::Limits,
) -> ApiResult<CameraSpec> {
    let cam = request
        .camera(cameras, grid)
        .map_err(|e| ApiError::bad(format!("{e:#}")))?;
    if cam.width > limits.max_image_side || cam.height > limits.max_image_side {
        return Err(ApiError::bad(format!(
            "width/height: {}×{} exceeds the server's limit of {} pixels per side",
            cam.width, cam.height, limits.max_image_side
        )));
    }
    if cam.width as u64 * cam.height as u64 > limits.max_image_pixels {
        return Err(ApiError::bad(format!(
            "width/height: {}×{} exceeds the server's limit of {} pixels",
            cam.width, cam.height, limits.max_image_pixels
        )));
    }
    Ok(cam)
}

/// Parameters `render` reads; anything else is a misspelling and refused.
const RENDER_PARAMETERS: [&str; 10] = [
    "camera", "eye", "target", "up", "fov", "width", "height", "spp", "exposure", "format",
];

/// A scene's display name: 1 to 64 characters, none of them control characters.
pub(crate) fn check_scene_name(name: &str) -> Result<String, String> {
    let n = name.chars().count();
    if n == 0 || n > 64 || name.chars().any(char::is_control) {
        return Err(format!(
            "name: `{}` is not 1 to 64 characters without control characters",
            name.escape_debug()
        ));
    }
    Ok(name.to_string())
}

/// Refuses query parameters the endpoint does not read, naming them and the ones it does,
/// rather than answering as if they were not there.
fn refuse_unknown_parameters(q: &HashMap<String, String>, known: &[&str]) -> ApiResult<()> {
    let mut unknown: Vec<&str> = q
        .keys()
        .map(String::as_str)
        .filter(|k| !known.contains(k))
        .collect();
    if unknown.is_empty() {
        return Ok(());
    }
    unknown.sort_unstable();
    Err(ApiError::bad(format!(
        "unknown query parameter{} {} (this endpoint reads: {})",
        if unknown.len() > 1 { "s" } else { "" },
        unknown
            .iter()
            .map(|k| format!("`{k}`"))
            .collect::<Vec<_>>()
            .join(", "),
        known.join(", ")
    )))
}

/// `GET /v1/scenes/{id}/render`: renders from the in-memory solution on a bounded pool.
async fn render(
    State(service): State<Service>,
    Path(id): Path<String>,
    q: RawQuery,
) -> ApiResult<Response> {
    let q = query_map(q)?;
    let limits = &service.inner.limits;
    let RenderQuery {
        format,
        spp,
        exposure,
        camera,
    } = parse_render_query(&q, limits)?;
    let solution = solved(&service, &id)?;
    let camera = render_camera(&camera, &solution.cameras, solution.medium.grid(), limits)?;
    if spp.unwrap_or(solution.render.spp) > limits.max_spp {
        return Err(ApiError::bad(format!(
            "spp: the scene's {} exceeds the server's limit of {}; give spp",
            solution.render.spp, limits.max_spp
        )));
    }
    let exposure = exposure.or(solution.render.exposure);
    let queued_at = std::time::Instant::now();
    let auto_exposure = exposure.is_none();
    let permit = render_slot(&service).await?;
    let (encoded, timing, used_exposure) =
        tokio::task::spawn_blocking(move || -> Result<(Vec<u8>, String, f64), String> {
            let _permit = permit;
            let t0 = std::time::Instant::now();
            let wait_ms = (t0 - queued_at).as_secs_f64() * 1e3;
            let image = crate::engine::pipeline::render_view(&solution, &camera, spp)
                .map_err(|e| format!("{e:#}"))?;
            let t1 = std::time::Instant::now();
            let exposure = exposure.unwrap_or_else(|| gather::auto_exposure(&image));
            let bytes = match format {
                RenderFormat::Png => encode_png(&image, exposure)?,
                RenderFormat::Pfm => {
                    let mut out = Vec::new();
                    image.write_pfm_to(&mut out).map_err(|e| e.to_string())?;
                    out
                }
            };
            let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
            // Server-Timing lets clients (the load test, browser dev tools) see where time went.
            let timing = format!(
                "wait;dur={wait_ms:.1}, render;dur={:.1}, encode;dur={:.1}",
                ms(t0, t1),
                ms(t1, std::time::Instant::now())
            );
            Ok((bytes, timing, exposure))
        })
        .await
        .map_err(|_| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "the renderer panicked"))?
        .map_err(|e| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, e))?;
    let content_type = match format {
        RenderFormat::Png => "image/png",
        RenderFormat::Pfm => "application/x-portable-floatmap",
    };
    Ok((
        [
            (header::CONTENT_TYPE, content_type.to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (header::HeaderName::from_static("server-timing"), timing),
            // The exposure a PNG was made with (automatic when the request and the scene
            // give none), so a client can offer to adjust it from there.
            (
                header::HeaderName::from_static("x-volrad-exposure"),
                format!("{used_exposure}"),
            ),
            (
                header::HeaderName::from_static("x-volrad-exposure-source"),
                if auto_exposure { "auto" } else { "given" }.to_string(),
            ),
        ],
        encoded,
    )
        .into_response())
}

/// The solution of scene `id` (or a unique prefix): 404 when unknown, 409 while it has none.
fn solved(service: &Service, id: &str) -> ApiResult<Arc<crate::engine::solution::Solution>> {
    let id = resolve(service, id)?;
    match service.solution(&id) {
        Some(s) => Ok(s),
        None => {
            let state = service.state(&id).ok_or_else(|| ApiError::not_found(&id))?;
            let why = match state {
                JobState::Failed { reason } => format!("scene `{id}` has no solution: {reason}"),
                s => format!("scene `{id}` is {}; ask again when it is done", s.name()),
            };
            Err(ApiError::new(StatusCode::CONFLICT, why))
        }
    }
}

/// `GET /v1/scenes/{id}/slice?field=&axis=&index=&channel=&scale=`: a plane of cells of a
/// solved field as a colour-mapped PNG ([`super::slice`]); `X-Volrad-Range` gives the values
/// of the colour map's ends (`none` for a field with no positive value).
async fn slice(
    State(service): State<Service>,
    Path(id): Path<String>,
    q: RawQuery,
) -> ApiResult<Response> {
    use super::slice::{colour, parse_slice_query, plane, range, SLICE_PARAMETERS};
    let q = query_map(q)?;
    refuse_unknown_parameters(&q, &SLICE_PARAMETERS)?;
    let query = parse_slice_query(&q).map_err(ApiError::bad)?;
    let solution = solved(&service, &id)?;
    let dims = solution.medium.grid().dims;
    let axis_name = ["x", "y", "z"][query.axis];
    let index = query.index.unwrap_or(dims[query.axis] / 2);
    if index >= dims[query.axis] {
        return Err(ApiError::bad(format!(
            "index: {index} is outside the grid's {} cells along {axis_name}",
            dims[query.axis]
        )));
    }
    if query.channel >= solution.channels.len() {
        return Err(ApiError::bad(format!(
            "channel: {} is not one of the solution's {} channel(s)",
            query.channel,
            solution.channels.len()
        )));
    }
    // The field comes from the whole solution (fluence interpolates the transport grid): in
    // a render slot, off the async threads.
    let permit = render_slot(&service).await?;
    let (png, value_range) = tokio::task::spawn_blocking(move || -> Result<_, String> {
        let _permit = permit;
        let (values, _units) =
            crate::engine::methods::export_field(&solution, query.channel, query.field)
                .map_err(|e| format!("{e:#}"))?;
        let value_range = range(&values, query.log);
        let (w, h, cells) = plane(&values, dims, query.axis, index);
        let rgb = colour(&cells, value_range, query.log);
        let png = gather::image_io::encode_png(
            w as u32,
            h as u32,
            3,
            &rgb,
            gather::PngCompression::Fast,
        )?;
        Ok((png, value_range))
    })
    .await
    .map_err(|_| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "the slice panicked"))?
    .map_err(|e| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, e))?;
    let range_text = match value_range {
        Some((lo, hi)) => format!("{lo:e} {hi:e}"),
        None => "none".to_string(),
    };
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::HeaderName::from_static("x-volrad-range"),
                range_text,
            ),
        ],
        png,
    )
        .into_response())
}

/// One of the render slots, waited for among a bounded number of requests (beyond it, 503):
/// renders and slices hold one while they compute.
async fn render_slot(service: &Service) -> ApiResult<tokio::sync::OwnedSemaphorePermit> {
    let waiting = WaitingRender::enter(service)?;
    let permit = Arc::clone(&service.inner.render_slots)
        .acquire_owned()
        .await
        .map_err(|_| {
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "the server is shutting down",
            )
        })?;
    drop(waiting);
    Ok(permit)
}

/// A render request waiting for a slot; the count is bounded so a flood of requests is
/// refused (503) instead of piling up.
struct WaitingRender<'a>(&'a Service);

impl<'a> WaitingRender<'a> {
    fn enter(service: &'a Service) -> ApiResult<Self> {
        use std::sync::atomic::Ordering;
        let before = service.inner.waiting_renders.fetch_add(1, Ordering::AcqRel);
        let guard = WaitingRender(service);
        if before >= service.inner.limits.max_waiting_renders {
            return Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("{before} renders are already waiting; try again shortly"),
            ));
        }
        Ok(guard)
    }
}

impl Drop for WaitingRender<'_> {
    fn drop(&mut self) {
        self.0
            .inner
            .waiting_renders
            .fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
    }
}

/// Tone-mapped 8-bit PNG in memory (fast compression: renders are viewed, not archived).
fn encode_png(image: &gather::Image, exposure: f64) -> Result<Vec<u8>, String> {
    gather::image_io::encode_png(
        image.width,
        image.height,
        image.channels,
        &image.tone_mapped(exposure),
        gather::PngCompression::Fast,
    )
}
