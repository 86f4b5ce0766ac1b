//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod broker;

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

/// [`spawn_serve`] with environment variables set for the daemon.
pub fn spawn_serve_with_env(
    args: &[&str],
    env: &[(&str, &str)],
) -> (std::process::Child, std::net::SocketAddr) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_vemlight"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .args(args)
        .envs(env.iter().copied())
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let rx = stderr_lines(stderr);
    let addr = loop {
        let line = rx
            .recv_timeout(std::time::Duration::from_secs(20))
            .expect("a startup line");
        if let Some(rest) = line.split("serving on http://").nth(1) {
            break rest.split_whitespace().next().unwrap().parse().unwrap();
        }
    };
    (child, addr)
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
