//! Helpers shared by the integration tests.
#![allow(dead_code)]

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
