//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod broker;
pub mod chromium;

use std::path::PathBuf;
use vemlight::envmap::{DEFAULT_MAX_PIXELS, EnvMap};

/// The real HDR maps copied from ../shared/data (see tests/data/README.md).
pub const MAPS: [&str; 8] = [
    "sunrise.exr",
    "interior.exr",
    "night.exr",
    "city.exr",
    "studio.exr",
    "overcast-plaza.exr",
    "cumulus-sky-f16.exr",
    "apartment-f16.exr",
];

/// Every map of `vemlight eval`: tests/data in [`MAPS`] order, then the synthetic hard skies
/// (a real-size sun, low and high, clear and hazy; a room with a window and a lamp) at 1024 × 512.
pub fn every_map() -> Vec<(String, EnvMap)> {
    let mut maps: Vec<(String, EnvMap)> = MAPS.iter().map(|m| (m.to_string(), load(m))).collect();
    maps.extend(vemlight::eval::scenes::hard_skies(1024));
    maps
}

/// [`every_map`], then the .exr and .hdr maps of the directory `$VEMLIGHT_EXTRA_MAPS` when it is
/// set (the held-out maps of `scripts/heldout-maps.sh`, say), in name order: what the ignored
/// measurement tests run on.
pub fn every_map_and_extra() -> Vec<(String, EnvMap)> {
    let mut maps = every_map();
    if let Ok(dir) = std::env::var("VEMLIGHT_EXTRA_MAPS") {
        let mut paths: Vec<_> = std::fs::read_dir(&dir)
            .expect("VEMLIGHT_EXTRA_MAPS is a directory")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "exr" || x == "hdr"))
            .collect();
        paths.sort();
        for p in paths {
            let name = p.file_stem().expect("name").to_string_lossy().to_string();
            maps.push((name, EnvMap::open(&p, None, 1 << 26).expect("a map")));
        }
    }
    maps
}

/// Runs `job` on each of `items` on a pool of threads (one a core, at most 8), the items taken
/// in order: the ignored measurement tests' loop over maps or skies.
pub fn on_each<T: Sync>(items: &[T], job: impl Fn(&T) + Sync) {
    let next = std::sync::Mutex::new(0usize);
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get().min(8));
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                loop {
                    let i = {
                        let mut next = next.lock().expect("the next item");
                        *next += 1;
                        *next - 1
                    };
                    let Some(item) = items.get(i) else {
                        break;
                    };
                    job(item);
                }
            });
        }
    });
}

/// Sorts `(ratio, case)` rows worst first and names the first five: "1.36 (case), …".
pub fn worst_first(rows: &mut [(f64, String)]) -> String {
    rows.sort_by(|a, b| b.0.total_cmp(&a.0));
    rows.iter()
        .take(5)
        .map(|r| format!("{:.2} ({})", r.0, r.1))
        .collect::<Vec<_>>()
        .join(", ")
}

/// One case of a sweep: (N, map name, diffuse ÷ k-means, shadowed ÷ median cut).
pub type SweepRow = (usize, String, f64, f64);

/// The default's lights for `map` at `n` lights on the sphere, scored against the two anchors
/// (ALGORITHMS.md §9–§10): its diffuse error ÷ converged k-means', and its shadowed error ÷ median
/// cut's.
pub fn against_anchors(
    map: &EnvMap,
    truth: &vemlight::eval::accuracy::Truth,
    n: usize,
) -> (f64, f64) {
    use vemlight::lights::{ExtractOptions, Extractor, Method};
    let errors = |method| {
        let opts = ExtractOptions {
            lights: n,
            domain: vemlight::mapping::Domain::Sphere,
            method,
            side: None,
        };
        let lights = Extractor::new().extract(map, &opts).lights;
        (
            truth.diffuse.error(&lights).rel_rms,
            truth.shadowed_mean(&lights),
        )
    };
    let ours = errors(Method::Voronoi);
    (
        ours.0 / errors(Method::KMeans).0,
        ours.1 / errors(Method::MedianCut).1,
    )
}

/// `map` turned `yaw_deg` about +Y (itself at 0°).
pub fn turned_about_y(map: EnvMap, yaw_deg: f64) -> EnvMap {
    if yaw_deg == 0.0 {
        return map;
    }
    vemlight::eval::scenes::LatLongDirs::new(map.width, map.height)
        .rotated(&map, glam::DQuat::from_rotation_y(yaw_deg.to_radians()))
}

/// A sweep's cases: each job's named map (made on the pool by `map_of`) at each of `counts`,
/// scored by [`against_anchors`] and printed as it is done.
pub fn sweep<J: Sync>(
    jobs: &[J],
    counts: &[usize],
    map_of: impl Fn(&J) -> (String, EnvMap) + Sync,
) -> Vec<SweepRow> {
    let rows = std::sync::Mutex::new(Vec::new());
    on_each(jobs, |job| {
        let (name, map) = map_of(job);
        let truth = vemlight::eval::accuracy::Truth::new(&map, vemlight::mapping::Domain::Sphere);
        for &n in counts {
            let (diffuse, shadowed) = against_anchors(&map, &truth, n);
            eprintln!(
                "{name:<48} N={n:<4} diffuse {diffuse:.3} × k-means, shadowed {shadowed:.3} × median cut"
            );
            rows.lock()
                .expect("rows")
                .push((n, name.clone(), diffuse, shadowed));
        }
    });
    rows.into_inner().expect("rows")
}

/// Per N: how many cases of `what` are over 1.25 × k-means and over median cut's shadowed error,
/// the worst five named; returns the worst diffuse and shadowed ratios of all.
pub fn report_sweep(what: &str, rows: &[SweepRow], counts: &[usize]) -> (f64, f64) {
    let (mut worst_diffuse, mut worst_shadowed) = (0.0f64, 0.0f64);
    for &n in counts {
        let at: Vec<&SweepRow> = rows.iter().filter(|r| r.0 == n).collect();
        let mut diffuse: Vec<(f64, String)> = at.iter().map(|r| (r.2, r.1.clone())).collect();
        let mut shadowed: Vec<(f64, String)> = at.iter().map(|r| (r.3, r.1.clone())).collect();
        let over_d = diffuse.iter().filter(|r| r.0 > 1.25).count();
        let over_s = shadowed.iter().filter(|r| r.0 > 1.0).count();
        let (wd, ws) = (worst_first(&mut diffuse), worst_first(&mut shadowed));
        eprintln!(
            "N={n}: {} {what}; diffuse over 1.25 × k-means: {over_d}, worst {wd}; shadowed over median cut's: {over_s}, worst {ws}",
            at.len()
        );
        worst_diffuse = worst_diffuse.max(diffuse.first().map_or(0.0, |r| r.0));
        worst_shadowed = worst_shadowed.max(shadowed.first().map_or(0.0, |r| r.0));
    }
    (worst_diffuse, worst_shadowed)
}

pub fn data_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

pub fn load(name: &str) -> EnvMap {
    EnvMap::open(&data_path(name), None, DEFAULT_MAX_PIXELS).expect("shared map decodes")
}

/// A validator for proto/lightset.schema.json.
pub fn lightset_validator() -> jsonschema::Validator {
    let schema: serde_json::Value =
        serde_json::from_str(vemlight::lightset::SCHEMA_JSON).expect("schema is JSON");
    jsonschema::draft202012::new(&schema).expect("schema compiles")
}

/// Panics with every violation if `doc` does not validate.
pub fn assert_valid(validator: &jsonschema::Validator, doc: &serde_json::Value) {
    let errors: Vec<String> = validator
        .iter_errors(doc)
        .map(|e| format!("{} at {}", e, e.instance_path()))
        .collect();
    assert!(errors.is_empty(), "schema violations: {errors:#?}");
}

/// Writes an RGB f32 OpenEXR file.
pub fn write_exr(path: &std::path::Path, w: usize, h: usize, px: &[[f32; 3]]) {
    exr::prelude::write_rgb_file(path, w, h, |x, y| {
        let p = px[y * w + x];
        (p[0], p[1], p[2])
    })
    .expect("write exr");
}

/// Where each chunk's data starts in a single-part scan-line EXR of `chunks` chunks: past the
/// magic and version, the attributes (name, type, i32 size, value; an empty name ends them) and
/// the offset table (one u64 per chunk), each chunk begins with its y and size (two i32).
pub fn exr_chunk_data(bytes: &[u8], chunks: usize) -> Vec<usize> {
    let mut at = 8;
    let past_cstr = |at: usize| bytes[at..].iter().position(|&b| b == 0).unwrap() + at + 1;
    while bytes[at] != 0 {
        at = past_cstr(past_cstr(at));
        at += 4 + i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    }
    at += 1;
    let table_end = at + 8 * chunks;
    (0..chunks)
        .map(|k| {
            let o = at + 8 * k;
            let offset = u64::from_le_bytes(bytes[o..o + 8].try_into().unwrap()) as usize;
            assert!(
                offset >= table_end && offset + 8 <= bytes.len(),
                "offset table"
            );
            offset + 8
        })
        .collect()
}

/// sunrise.exr (DWAB) with its first chunk's leader claiming 2^57 AC values, what one flipped bit
/// did to a shared map: unchecked, the exr crate asks for that many bytes and the process aborts.
pub fn dwa_with_a_huge_ac_count() -> Vec<u8> {
    let mut bytes = std::fs::read(data_path("sunrise.exr")).unwrap();
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&bytes[..]), false)
        .expect("sunrise.exr's header");
    let header = &meta.headers[0];
    assert!(matches!(
        header.compression,
        exr::compression::Compression::DWAB(_)
    ));
    let chunks = header
        .layer_size
        .height()
        .div_ceil(header.compression.scan_lines_per_block());
    // The DWA leader's eleven u64 counters open the chunk's data; the ninth is the AC value count.
    let ac = exr_chunk_data(&bytes, chunks)[0] + 8 * 8;
    let intact = u64::from_le_bytes(bytes[ac..ac + 8].try_into().unwrap());
    assert!(
        intact <= 1024 * 256 * 3,
        "the intact count {intact} fits the block"
    );
    bytes[ac..ac + 8].copy_from_slice(&(1u64 << 57).to_le_bytes());
    bytes
}

/// Starts `vemlight serve --bind 127.0.0.1:0 ARGS` (stdin piped) and reads the address it
/// listens on from its log.
pub fn spawn_serve(args: &[&str]) -> (std::process::Child, std::net::SocketAddr) {
    spawn_serve_with_env(args, &[])
}

/// [`spawn_serve`] with environment variables set for the daemon; a `--bind` in `args` replaces
/// the default one.
pub fn spawn_serve_with_env(
    args: &[&str],
    env: &[(&str, &str)],
) -> (std::process::Child, std::net::SocketAddr) {
    let vemlight = std::process::Command::new(env!("CARGO_BIN_EXE_vemlight"));
    try_spawn_serve(vemlight, args, env)
        .unwrap_or_else(|e| panic!("vemlight serve {args:?} did not start: {e}"))
}

/// [`spawn_serve_with_env`] run by `program` (the binary, or a wrapper that runs the binary with
/// the arguments that follow): its exit status and log if it does not start.
pub fn try_spawn_serve(
    mut program: std::process::Command,
    args: &[&str],
    env: &[(&str, &str)],
) -> Result<(std::process::Child, std::net::SocketAddr), String> {
    let bind: &[&str] = if args.contains(&"--bind") {
        &[]
    } else {
        &["--bind", "127.0.0.1:0"]
    };
    let mut child = program
        .arg("serve")
        .args(bind)
        .args(args)
        .envs(env.iter().copied())
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let lines = stderr_lines(child.stderr.take().unwrap());
    let addr = serving_address(&mut child, &lines)?;
    Ok((child, addr))
}

/// The address a starting `vemlight serve` says it listens on, read from its log `lines`; or,
/// if it exits first (or says nothing for 20 s, when it is killed), its exit status and log.
pub fn serving_address(
    child: &mut std::process::Child,
    lines: &std::sync::mpsc::Receiver<String>,
) -> Result<std::net::SocketAddr, String> {
    use std::sync::mpsc::RecvTimeoutError;
    let mut log = String::new();
    loop {
        match lines.recv_timeout(std::time::Duration::from_secs(20)) {
            Ok(line) => {
                if let Some(rest) = line.split("serving on http://").nth(1) {
                    return Ok(rest.split_whitespace().next().unwrap().parse().unwrap());
                }
                log.push_str(&line);
                log.push('\n');
            }
            Err(e) => {
                if e == RecvTimeoutError::Timeout {
                    let _ = child.kill();
                }
                let status = child.wait().unwrap();
                return Err(format!("{status}: {log}"));
            }
        }
    }
}

/// A child's standard error, line by line, read on a thread of its own (so the child never
/// blocks on a full pipe).
pub fn stderr_lines(stderr: std::process::ChildStderr) -> std::sync::mpsc::Receiver<String> {
    use std::io::BufRead;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    rx
}

/// A client of the daemon's `/v1/stream`.
pub type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// A WebSocket handshake request for `/v1/stream{query}` with the vemlight subprotocol.
pub fn stream_request(
    addr: std::net::SocketAddr,
    query: &str,
) -> tokio_tungstenite::tungstenite::handshake::client::Request {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let mut req = format!("ws://{addr}/v1/stream{query}")
        .into_client_request()
        .unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        tokio_tungstenite::tungstenite::http::HeaderValue::from_static("vemlight.v1"),
    );
    req
}

/// The next LightSet from a stream, within `timeout`.
pub async fn next_set(ws: &mut Ws, timeout: std::time::Duration) -> serde_json::Value {
    use futures_util::StreamExt;
    loop {
        let msg = tokio::time::timeout(timeout, ws.next())
            .await
            .expect("a message in time")
            .expect("stream open")
            .expect("no ws error");
        if let tokio_tungstenite::tungstenite::Message::Text(t) = msg {
            return serde_json::from_str(t.as_str()).expect("JSON");
        }
    }
}

/// `GET url` as a JSON document.
pub async fn get_json(c: &reqwest::Client, url: &str) -> serde_json::Value {
    c.get(url).send().await.unwrap().json().await.unwrap()
}

/// The status line of the answer to a raw request on `tcp`, within `limit`.
pub async fn status_line(tcp: &mut tokio::net::TcpStream, limit: std::time::Duration) -> String {
    use tokio::io::AsyncReadExt;
    let mut reply = vec![0u8; 4096];
    let n = tokio::time::timeout(limit, tcp.read(&mut reply))
        .await
        .expect("an answer in time")
        .unwrap();
    String::from_utf8_lossy(&reply[..n])
        .lines()
        .next()
        .unwrap_or("")
        .to_string()
}

/// Kills the process when dropped (a daemon, a browser), so a failing test leaves none behind.
pub struct Killed(pub std::process::Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
