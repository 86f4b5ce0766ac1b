//! The LightSet document (proto/lightset.schema.json) and the glTF export.
//!
//! Input: an [`EnvMap`] and a [`LightRequest`]. Output: a [`LightSet`], the one document that the
//! HTTP endpoint returns, the WebSocket stream sends and the CLI prints (DESIGN.md "wire format").

use crate::envmap::{EnvMap, Projection};
use crate::lights::budget::fewest_meeting;
use crate::lights::error::IrradianceReference;
use crate::lights::{
    Extractor, FrameRequest, Light, Method, PrimaryLight, primary_light, total_irradiance,
};
use crate::mapping::Domain;
use crate::sampling::N_MAX;
use crate::temporal::FilterInfo;
use serde::{Deserialize, Serialize};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The value of the `schema` field.
pub const SCHEMA_ID: &str = "vemlight.lightset/1";

/// The WebSocket subprotocol of `GET /v1/stream`, which carries these documents one per message.
/// It lives with the document, not the server, so the render client and the daemon share it
/// without one importing the other (DESIGN.md "wire format").
pub const SUBPROTOCOL: &str = "vemlight.v1";

/// The JSON Schema, embedded so servers and tests use the same file.
pub const SCHEMA_JSON: &str = include_str!("../proto/lightset.schema.json");

/// One set of lights for one frame.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightSet {
    pub schema: String,
    /// Sequence number of this document from its producer (0 for one-off requests).
    pub seq: u64,
    /// Index of the source frame.
    pub frame: u64,
    /// When the frame was captured (its last rows read), nanoseconds since the Unix epoch.
    pub t_capture_ns: u64,
    /// When this document was produced, nanoseconds since the Unix epoch.
    pub t_emit_ns: u64,
    /// Where the frame came from (a file name, "synthetic", "upload", …).
    pub source: String,
    pub method: Method,
    pub domain: Domain,
    pub lights: Vec<Light>,
    /// The brightest light or cluster; absent for a black map.
    pub primary: Option<PrimaryLight>,
    /// L2 radiance SH, 27 floats, RGB interleaved, WebXR order (see `lights::sh`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sh9: Option<Vec<f32>>,
    /// With a shadow budget (`shadowed=K`): the L2 radiance SH of the map less the lights marked
    /// `shadowed`, so that K shadowed lights plus this ambient term hold the map's energy.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sh9_unshadowed: Option<Vec<f32>>,
    /// Σ irradiance over the lights = ∫ L dω over the domain, linear RGB.
    pub total_irradiance: [f64; 3],
    /// The temporal filter applied (streams only); its delay is how far the lights lag the frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<FilterInfo>,
    pub diagnostics: Diagnostics,
}

impl LightSet {
    /// A document for `lights` computed from `map`; sequence numbers, timestamps, error and
    /// timings are the caller's to fill in. Lights without energy are left out (DESIGN.md: every
    /// light carries energy), and `diagnostics.lights_short` says how many fewer than
    /// `lights_requested` the set holds.
    pub fn new(
        mut lights: Vec<Light>,
        map: &EnvMap,
        method: Method,
        domain: Domain,
        source: &str,
        lights_requested: usize,
        domain_side: usize,
    ) -> Self {
        let now = now_ns();
        lights.retain(Light::carries_energy);
        let short = match lights_requested.saturating_sub(lights.len()) {
            0 => None,
            k => Some(k),
        };
        LightSet {
            schema: SCHEMA_ID.into(),
            seq: 0,
            frame: 0,
            t_capture_ns: now,
            t_emit_ns: now,
            source: source.into(),
            method,
            domain,
            primary: primary_light(&lights),
            sh9: None,
            sh9_unshadowed: None,
            total_irradiance: total_irradiance(&lights),
            filter: None,
            diagnostics: Diagnostics {
                clamped_pixels: map.repairs.clamped_pixels(),
                non_finite_pixels: map.repairs.non_finite_pixels,
                negative_pixels: map.repairs.negative_pixels,
                overbright_pixels: map.repairs.overbright_pixels,
                projection: map.projection.name().into(),
                lights_requested,
                lights_chosen: None,
                lights_short: short,
                domain_side,
                ..Diagnostics::default()
            },
            lights,
        }
    }
}

/// How the set was made and what went wrong on the way.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Diagnostics {
    /// Pixels clamped (non-finite or negative to 0, above `envmap::MAX_RADIANCE` to it).
    pub clamped_pixels: u64,
    pub non_finite_pixels: u64,
    pub negative_pixels: u64,
    /// Pixels with a channel above `envmap::MAX_RADIANCE`, clamped to it.
    #[serde(default)]
    pub overbright_pixels: u64,
    /// Input projection.
    pub projection: String,
    /// Light count asked for (the cap, with `max_error`).
    pub lights_requested: usize,
    /// With `max_error`: the light count chosen, the fewest whose estimated error meets it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lights_chosen: Option<usize>,
    /// How many fewer lights than asked the map could give (every light carries energy; a map
    /// with fewer lit regions gives fewer lights). Absent when none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lights_short: Option<usize>,
    /// Side of the equal-area domain square.
    pub domain_side: usize,
    /// Relative RMS diffuse irradiance error against the map (ALGORITHMS.md §8), when computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub estimated_error: Option<f64>,
    /// The error target of a `max_error` request, and whether the chosen N meets it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_error: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_error_met: Option<bool>,
    pub timings_ms: Timings,
}

/// Stage times in milliseconds.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct Timings {
    pub decode: f64,
    pub resample: f64,
    pub warp: f64,
    pub assign: f64,
    pub total: f64,
}

/// What a client asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightRequest {
    /// Light count, or the largest allowed with `max_error`.
    pub lights: usize,
    /// `None` = sphere for lat-long input, upper hemisphere otherwise.
    pub domain: Option<Domain>,
    pub method: Method,
    /// Pick the smallest power-of-two count whose diffuse error is ≤ this.
    pub max_error: Option<f64>,
    /// Compute `diagnostics.estimated_error` even without `max_error`.
    pub estimate_error: bool,
    pub sh9: bool,
}

impl Default for LightRequest {
    fn default() -> Self {
        LightRequest {
            lights: 64,
            domain: None,
            method: Method::Voronoi,
            max_error: None,
            estimate_error: true,
            sh9: true,
        }
    }
}

impl LightRequest {
    /// Checks the request's own values; errors are user-facing.
    pub fn validate(&self) -> Result<(), String> {
        if self.lights == 0 || self.lights > N_MAX {
            return Err(format!(
                "lights must be between 1 and {N_MAX}, got {}",
                self.lights
            ));
        }
        if let Some(e) = self.max_error {
            check_max_error(e)?;
        }
        Ok(())
    }
}

/// A `max_error` is a relative RMS error in (0, 1]: the same rule for the CLI, uploads and
/// streams; errors are user-facing.
pub fn check_max_error(e: f64) -> Result<(), String> {
    if e.is_finite() && e > 0.0 && e <= 1.0 {
        Ok(())
    } else {
        Err(format!(
            "max_error must be a relative error in (0, 1] (0.02 for 2 %), got {e}"
        ))
    }
}

/// The domain used when none is asked for (DESIGN.md, "Conventions"): the whole sphere for lat-long input, the upper
/// hemisphere for cameras that only see it.
pub fn default_domain(projection: &Projection) -> Domain {
    match projection {
        Projection::LatLong => Domain::Sphere,
        _ => Domain::Upper,
    }
}

/// Nanoseconds since the Unix epoch.
pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// One map → one LightSet, as the CLI and `POST /v1/lights` compute it.
pub fn lightset_for_map(
    extractor: &mut Extractor,
    map: &EnvMap,
    req: &LightRequest,
    source: &str,
) -> LightSet {
    let start = Instant::now();
    let domain = req
        .domain
        .unwrap_or_else(|| default_domain(&map.projection));
    let t = Instant::now();
    let image = extractor.resample(map, domain, None);
    let resample_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut extract = |n: usize, sh9: bool| {
        let mut frame = extractor.extract_frame(
            map,
            &image,
            &FrameRequest {
                method: req.method,
                counts: &[n],
                sh9,
            },
        );
        let ex = frame
            .extractions
            .pop()
            .expect("one count asked, one extraction");
        (ex, frame.sh9)
    };

    let needs_reference = req.max_error.is_some() || req.estimate_error;
    let reference = needs_reference.then(|| IrradianceReference::from_domain_image(&image));
    let ((ex, sh9), error, met, chosen) = match (req.max_error, &reference) {
        (Some(target), Some(reference)) => {
            // The fewest lights that meet the target; the cap when none does.
            let fewest = fewest_meeting(req.lights, target, |n| {
                let (ex, sh9) = extract(n, req.sh9);
                let err = reference.error(&ex.lights).rel_rms;
                ((ex, sh9), err)
            });
            let chosen = Some(fewest.count);
            (fewest.value, Some(fewest.error), Some(fewest.met), chosen)
        }
        _ => {
            let (ex, sh9) = extract(req.lights, req.sh9);
            let err = reference.as_ref().map(|r| r.error(&ex.lights).rel_rms);
            ((ex, sh9), err, None, None)
        }
    };
    // `lights_short` counts the lights the map could not give of those extracted (the count
    // chosen, with `max_error`), as a stream's sets do.
    let extracted = chosen.unwrap_or(req.lights);
    let mut set = LightSet::new(
        ex.lights, map, req.method, domain, source, extracted, ex.side,
    );
    set.sh9 = sh9;
    let d = &mut set.diagnostics;
    d.lights_requested = req.lights;
    d.lights_chosen = chosen;
    d.estimated_error = error;
    d.max_error = req.max_error;
    d.max_error_met = met;
    d.timings_ms = Timings {
        decode: 0.0,
        resample: resample_ms,
        warp: ex.timings.warp_s * 1e3,
        assign: ex.timings.assign_s * 1e3,
        total: start.elapsed().as_secs_f64() * 1e3,
    };
    set
}

/// The set as a glTF 2.0 document with KHR_lights_punctual: one directional light and one node per
/// light. A glTF directional light shines along its node's −Z, so the node's rotation maps −Z onto
/// −to_light. `color` is the irradiance divided by its largest channel and `intensity` that channel
/// (glTF wants colours in [0, 1]).
pub fn to_gltf(set: &LightSet) -> serde_json::Value {
    use serde_json::json;
    let mut lights = Vec::new();
    let mut nodes = Vec::new();
    for (index, l) in set.lights.iter().enumerate() {
        let peak = l.irradiance.iter().cloned().fold(0.0f32, f32::max);
        let color = if peak > 0.0 {
            l.irradiance.map(|c| c / peak)
        } else {
            [1.0; 3]
        };
        lights.push(json!({
            "type": "directional",
            "name": format!("vemlight-{}", l.id),
            "color": color,
            "intensity": peak,
        }));
        let travel = -glam::Vec3::from_array(l.to_light);
        let q = glam::Quat::from_rotation_arc(
            glam::Vec3::NEG_Z,
            travel.normalize_or(glam::Vec3::NEG_Y),
        );
        nodes.push(json!({
            "name": format!("vemlight-{}", l.id),
            "rotation": q.to_array(),
            "extensions": { "KHR_lights_punctual": { "light": index } },
        }));
    }
    json!({
        "asset": { "version": "2.0", "generator": concat!("vemlight ", env!("CARGO_PKG_VERSION")) },
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": { "KHR_lights_punctual": { "lights": lights } },
        "scene": 0,
        "scenes": [{ "name": set.source, "nodes": (0..nodes.len()).collect::<Vec<_>>() }],
        "nodes": nodes,
    })
}
