//! The light itself (DESIGN.md "A light") and what is read off a set of lights: the angular
//! radius of a region (ALGORITHMS.md §12), the primary light (ALGORITHMS.md §6) and the total
//! irradiance. A leaf: every extraction method imports it, it imports none of them.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A directional light (DESIGN.md "A light").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    /// Stable id: the index of the progressive point the light comes from (ordered methods).
    pub id: u32,
    /// Unit vector pointing toward the light, world frame (+Y up, −Z forward).
    pub to_light: [f32; 3],
    /// Radiance integrated over the light's solid angle, linear RGB (map units × sr).
    pub irradiance: [f32; 3],
    /// Solid angle (sr) of the region the light stands for.
    pub solid_angle: f32,
    /// Angular radius (radians) of the uniform disc whose energy has the same RMS spread about
    /// `to_light` as the light's region (ALGORITHMS.md §12): 2·√(1 − |M|/P), P = ∫Y dω and
    /// M = ∫Y ω dω over the region. What a client's soft shadow (a disc light, PCSS, a sun radius)
    /// needs; 0 for a point. Older documents without it read as 0.
    #[serde(default)]
    pub angular_radius: f32,
    /// Where one disc draws a source poorly (a sun in a wider glow): the light's luminance as a
    /// compact core about its own direction and a wider rest about `to_light` (ALGORITHMS.md §12,
    /// "Two-part extent"). A client that draws one disc uses `angular_radius`; absent where one
    /// disc is enough, unless that disc casts its shadow from the sun rather than `to_light`
    /// (§12, "Shadow direction": share 0.999, both discs `angular_radius`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extent: Option<LightExtent>,
    /// With a client's shadow budget (`shadowed=K`, see [`super::budget`]): whether this light is
    /// one of the K worth a shadow map. Absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadowed: Option<bool>,
}

impl Light {
    pub fn dir(&self) -> DVec3 {
        DVec3::from_array(self.to_light.map(f64::from))
    }

    pub fn luminance(&self) -> f64 {
        crate::envmap::luminance64(self.irradiance.map(f64::from))
    }

    /// Whether the light carries any energy (DESIGN.md: every light of a set does).
    pub fn carries_energy(&self) -> bool {
        self.irradiance.iter().any(|&c| c > 0.0)
    }

    /// The region's luminance moment M = ∫Y ω dω, recovered from the luminance and the angular
    /// radius (|M| = P·(1 − r²/4), ALGORITHMS.md §12): lights merged by summing moments keep
    /// the combined region's spread.
    pub fn moment(&self) -> DVec3 {
        let r = self.angular_radius as f64;
        self.dir() * self.luminance() * (1.0 - 0.25 * r * r).max(0.0)
    }

    /// Where a client with one shadow map for this light draws it from: the extent's core
    /// direction when it lies within [`ONE_MAP_CORE_DEG`]`.0` of `to_light`, `to_light` from
    /// [`ONE_MAP_CORE_DEG`]`.1` on, and between them turned from `to_light` toward the core by
    /// the share of the angle that falls linearly from 1 to 0 (ALGORITHMS.md §12, "Two-part
    /// extent"). Continuous in the core's direction, so a core drifting across the band moves
    /// the shadow smoothly instead of switching it degrees in one frame. Shading stays
    /// n·`to_light` either way.
    pub fn one_map_shadow_dir(&self) -> DVec3 {
        let to_light = self.dir().normalize_or(DVec3::Y);
        let Some(core) = self.extent.and_then(|e| e.core_dir()) else {
            return to_light;
        };
        let (full, none) = (
            ONE_MAP_CORE_DEG.0.to_radians(),
            ONE_MAP_CORE_DEG.1.to_radians(),
        );
        let angle = core.angle_between(to_light);
        let share = ((none - angle) / (none - full)).clamp(0.0, 1.0);
        if share >= 1.0 {
            return core;
        }
        // Turned by share · angle in the plane of the two (here under 4° apart).
        let across = (core - to_light * to_light.dot(core)).normalize_or_zero();
        let turn = share * angle;
        (to_light * turn.cos() + across * turn.sin()).normalize_or(to_light)
    }
}

/// Degrees: how far a core's direction may lie from its light for one shadow map drawn from the
/// core to stand for both discs (`.0`), and from where the light's own direction is drawn
/// (`.1`); between, [`Light::one_map_shadow_dir`] turns part way. Drawn from the core, the rest's
/// disc is drawn about the core too: on low suns, whose cells hold much sky, the core lies 4–11°
/// from the light and the rest's soft shadow moved that far made the shadowed error worse (the
/// 2° hazy sun at 16 lights 1.08 → 1.61 × median cut's); every core within 2.6° drew better or
/// within noise on the 72 skies, and the band drew as well as a cut at 3° (EVALUATION.md, "The
/// core's own direction").
pub const ONE_MAP_CORE_DEG: (f64, f64) = (2.0, 4.0);

/// A light's two-part extent (ALGORITHMS.md §12, "Two-part extent"): a share of its luminance
/// in a compact core's disc about the core's own direction and the rest in a wider disc about
/// the light's. Its shadow is the two discs' visibilities weighed by their shares: the hard
/// shadow of a sun and the soft one of its glow, which one disc of the half-energy radius draws
/// as neither; the sun's where the sun is, though the light (the cell's centroid, with its sky)
/// is a little aside.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightExtent {
    /// The core's share of the light's luminance, in (0, 1).
    pub core_share: f32,
    /// Radians: the core's uniform disc of the same RMS spread.
    pub core_radius: f32,
    /// Radians: the uniform disc with the rest's half-energy radius.
    pub rest_radius: f32,
    /// Unit vector toward the core's centroid; absent (older documents), the light's
    /// `to_light`. Only the core's shadow is drawn from it: shading uses `to_light`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub core_to_light: Option<[f32; 3]>,
}

impl LightExtent {
    /// The smallest share either part must hold, and how much wider than the core the rest must
    /// be, for the two discs to draw a shadow one disc does not: under these the light is one
    /// disc (no more model than the source needs).
    pub const MIN_SHARE: f64 = 0.01;
    pub const MIN_WIDER: f64 = 4.0;

    /// The two-part extent of a cell whose core has (P, |M|) = `core` and whose rest lies in
    /// `rest` (as [`core_rest_radius`] reads them); `None` where one disc is enough.
    pub fn of_core_and_rest(core: (f64, f64), rest: &[f32]) -> Option<LightExtent> {
        let (pc, mc) = core;
        let pr: f64 = rest.iter().map(|&y| y.max(0.0) as f64).sum();
        if !(pc > 0.0 && pr > 0.0 && pc.is_finite() && mc.is_finite() && pr.is_finite()) {
            return None;
        }
        LightExtent {
            core_share: (pc / (pc + pr)) as f32,
            core_radius: angular_radius(pc, mc),
            rest_radius: core_rest_radius((0.0, 0.0), rest),
            core_to_light: None,
        }
        .worth_two_discs()
    }

    /// Both discs at most `max_radius` (the horizon, ALGORITHMS.md §12); `None` where the rest's
    /// disc is then no longer [`Self::MIN_WIDER`] times the core's (one disc draws it).
    pub fn clamped(self, max_radius: f32) -> Option<LightExtent> {
        LightExtent {
            core_radius: self.core_radius.min(max_radius),
            rest_radius: self.rest_radius.min(max_radius),
            ..self
        }
        .worth_two_discs()
    }

    /// `self` where its two discs draw a shadow one disc does not ([`Self::MIN_SHARE`],
    /// [`Self::MIN_WIDER`]), else `None`.
    fn worth_two_discs(self) -> Option<LightExtent> {
        let share = f64::from(self.core_share);
        let two = (Self::MIN_SHARE..=1.0 - Self::MIN_SHARE).contains(&share)
            && f64::from(self.rest_radius) >= Self::MIN_WIDER * f64::from(self.core_radius);
        two.then_some(self)
    }

    /// The same extent with its core toward `core_moment`'s direction (the core's centroid);
    /// unchanged where that has none.
    pub fn toward(self, core_moment: DVec3) -> LightExtent {
        LightExtent {
            core_to_light: core_moment
                .try_normalize()
                .map(|d| d.as_vec3().to_array())
                .or(self.core_to_light),
            ..self
        }
    }

    /// The core's own direction, a unit vector, where the extent has one (and it is not zero).
    pub fn core_dir(&self) -> Option<DVec3> {
        self.core_to_light
            .map(|d| DVec3::from_array(d.map(f64::from)))
            .and_then(DVec3::try_normalize)
    }

    /// The two discs, (share, radius, direction) each, for a light toward `to_light`.
    pub fn parts(&self, to_light: DVec3) -> [(f64, f32, DVec3); 2] {
        let s = f64::from(self.core_share).clamp(0.0, 1.0);
        let core = self.core_dir().unwrap_or(to_light);
        [
            (s, self.core_radius, core),
            (1.0 - s, self.rest_radius, to_light),
        ]
    }
}

/// The angular radius of a region of luminance energy `energy` whose moment has length
/// `moment_len` (ALGORITHMS.md §12): the radius of the uniform disc with the same RMS spread,
/// 2·√(1 − |M|/P), at most π.
pub fn angular_radius(energy: f64, moment_len: f64) -> f32 {
    if energy <= 0.0 || !energy.is_finite() || !moment_len.is_finite() {
        return 0.0;
    }
    let spread = (1.0 - moment_len / energy).clamp(0.0, 1.0);
    (2.0 * spread.sqrt()).min(std::f64::consts::PI) as f32
}

/// The largest angular radius a light toward `to_light` may have without its disc crossing the
/// horizon (ALGORITHMS.md §12, "Not across the horizon"): the angle between the direction and the
/// horizontal plane.
pub fn horizon_gap(to_light: [f32; 3]) -> f32 {
    to_light[1].clamp(-1.0, 1.0).abs().asin()
}

/// The strongest light or tight cluster of lights (the sun), WebXR's "primary light".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PrimaryLight {
    /// Irradiance-weighted mean direction toward the cluster (unit vector).
    pub to_light: [f32; 3],
    /// Sum of the cluster's irradiance, linear RGB.
    pub irradiance: [f32; 3],
    /// Ids of the lights in the cluster.
    pub light_ids: Vec<u32>,
}

/// Lights within this angle of the brightest light form the primary cluster (ALGORITHMS.md §6: 2–5°).
pub const PRIMARY_CLUSTER_DEG: f64 = 5.0;

/// The brightest light (by luminance) and every light within [`PRIMARY_CLUSTER_DEG`] of it.
pub fn primary_light(lights: &[Light]) -> Option<PrimaryLight> {
    let brightest = lights
        .iter()
        .filter(|l| l.luminance() > 0.0)
        .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))?;
    let axis = brightest.dir();
    let cos_limit = PRIMARY_CLUSTER_DEG.to_radians().cos();
    let mut dir = DVec3::ZERO;
    let mut irr = [0.0f64; 3];
    let mut ids = Vec::new();
    for l in lights.iter().filter(|l| l.dir().dot(axis) >= cos_limit) {
        dir += l.dir() * l.luminance();
        for c in 0..3 {
            irr[c] += l.irradiance[c] as f64;
        }
        ids.push(l.id);
    }
    Some(PrimaryLight {
        to_light: dir.try_normalize().unwrap_or(axis).as_vec3().to_array(),
        irradiance: irr.map(|v| v as f32),
        light_ids: ids,
    })
}

/// Σ irradiance over lights, per channel, in f64.
pub fn total_irradiance(lights: &[Light]) -> [f64; 3] {
    let mut s = [0.0f64; 3];
    for l in lights {
        for c in 0..3 {
            s[c] += l.irradiance[c] as f64;
        }
    }
    s
}

/// Bins of the rest of a cell (outside its core) by angle about its centroid (ALGORITHMS.md
/// §12, "Core and rest"): by x = 1 − cos θ, `ANGLE_BINS_PER_OCTAVE` to an octave of x from 2⁻²⁴
/// (θ = 0.02°) up to 2 (θ = 180°), so a half-energy radius is known to 9 % in θ at any scale.
pub const ANGLE_BINS: usize = 100;
const ANGLE_BINS_PER_OCTAVE: f32 = 4.0;
const ANGLE_SMALLEST_OCTAVE: f32 = -24.0;

/// log₂ x to within 0.09, monotone and piecewise linear, from the float's bits: a bin's edges are
/// then exact inverses ([`angle_bin_start`]).
fn rough_log2(x: f32) -> f32 {
    x.to_bits() as f32 / (1u32 << 23) as f32 - 127.0
}

/// The bin that x = 1 − cos θ ≥ 0 falls in.
pub fn angle_bin(x: f32) -> usize {
    // NaN and x ≤ 0 (a texel at the centroid, to rounding) go to the first bin.
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    let b = (rough_log2(x) - ANGLE_SMALLEST_OCTAVE) * ANGLE_BINS_PER_OCTAVE;
    (b.max(0.0) as usize).min(ANGLE_BINS - 1)
}

/// [`angle_bin_start`] of every bin and one past the last.
static ANGLE_BIN_STARTS: std::sync::LazyLock<[f64; ANGLE_BINS + 1]> =
    std::sync::LazyLock::new(|| std::array::from_fn(angle_bin_start));

/// The smallest x of bin `b` (0 for the first, 2 past the last).
fn angle_bin_start(b: usize) -> f64 {
    match b {
        0 => 0.0,
        ANGLE_BINS.. => 2.0,
        _ => {
            let l = b as f32 / ANGLE_BINS_PER_OCTAVE + ANGLE_SMALLEST_OCTAVE;
            f32::from_bits(((l + 127.0) * (1u32 << 23) as f32) as u32) as f64
        }
    }
}

/// The angular radius of a cell (ALGORITHMS.md §12, "Core and rest"): the uniform disc with the
/// cell's half-energy radius √2·θ₅₀ about its centroid, its core (its brightest texels) taken as a
/// uniform disc of its RMS spread, `core` = (P, |M|) over it, and the rest as it lies, `rest` its
/// luminance by `angle_bin` of 1 − cos θ, each bin even in x. A median, unlike an RMS, is
/// carried off neither by a sun's faint wide glare (a clear sun keeps about its own radius) nor
/// by the sky far from a sun in a bright glow that its cell also holds (the glow's radius). The
/// core's moments see inside a texel, which a 0.27° sun in 1° texels needs.
pub fn core_rest_radius(core: (f64, f64), rest: &[f32]) -> f32 {
    let (pc, mc) = core;
    let pr: f64 = rest.iter().map(|&y| y as f64).sum();
    if !(pc.is_finite() && mc.is_finite() && pr.is_finite()) {
        return 0.0;
    }
    let pc = pc.max(0.0);
    if pc + pr <= 0.0 {
        return 0.0;
    }
    // A uniform disc of radius r is even in x = 1 − cos θ ≈ θ²/2 up to r²/2, and its 1 − |M|/P
    // is the mean x, r²/4.
    let x_core = if pc > 0.0 {
        2.0 * (1.0 - mc / pc).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let core_within = |x: f64| {
        if x >= x_core { pc } else { pc * x / x_core }
    };
    let half = 0.5 * (pc + pr);
    // Walk the bins, the core's edge a kink inside one, to where half the energy lies within x.
    let starts = &*ANGLE_BIN_STARTS;
    let mut rest_below = 0.0;
    let mut x50 = 2.0;
    'bins: for (b, &y) in rest.iter().enumerate().take(ANGLE_BINS) {
        let y = if y > 0.0 { y as f64 } else { 0.0 };
        let (lo, hi) = (starts[b], starts[b + 1]);
        if core_within(hi) + rest_below + y < half {
            rest_below += y;
            continue;
        }
        let within = |x: f64| core_within(x) + rest_below + y * (x - lo) / (hi - lo);
        let kink = x_core.clamp(lo, hi);
        for (x0, x1) in [(lo, kink), (kink, hi)] {
            let (e0, e1) = (within(x0), within(x1));
            if e0 >= half {
                x50 = x0;
                break 'bins;
            }
            if e1 >= half {
                x50 = x0 + (x1 - x0) * (half - e0) / (e1 - e0);
                break 'bins;
            }
        }
        rest_below += y;
    }
    let theta50 = 2.0 * (x50.clamp(0.0, 2.0) / 2.0).sqrt().asin();
    // A uniform disc of radius R holds half its energy within R/√2.
    (std::f64::consts::SQRT_2 * theta50).min(std::f64::consts::PI) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `p` spread evenly in x = 1 − cos θ over [x0, x1) (a uniform cap from x0 = 0, a ring
    /// beyond), added into a cell's bins.
    fn add_even(bins: &mut [f32], p: f64, x0: f64, x1: f64) {
        for (b, y) in bins.iter_mut().enumerate() {
            let (lo, hi) = (angle_bin_start(b).max(x0), angle_bin_start(b + 1).min(x1));
            if hi > lo {
                *y += (p * (hi - lo) / (x1 - x0)) as f32;
            }
        }
    }

    fn x_of(theta: f64) -> f64 {
        1.0 - theta.cos()
    }

    /// The disc radius √2·θ₅₀ of an energy profile `within(x)`, by bisection on x.
    fn median_disc(within: impl Fn(f64) -> f64, total: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 2.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if within(mid) < 0.5 * total {
                lo = mid
            } else {
                hi = mid
            }
        }
        std::f64::consts::SQRT_2 * 2.0 * (lo / 2.0).sqrt().asin()
    }

    /// (P, |M|) of a uniform disc of radius `r` (radians) holding `p`: |M| = P·(1 − r²/4)
    /// (ALGORITHMS.md §12), so that `angular_radius` gives back `r`.
    fn disc(p: f64, r: f64) -> (f64, f64) {
        (p, p * (1.0 - r * r / 4.0))
    }

    /// A core of `share` on a disc of radius `rc` (by its moments) and the rest on a uniform cap
    /// of radius `rh` (by its bins): the radius, and the bisected median's.
    fn core_and_cap(share: f64, rc: f64, rh: f64) -> (f32, f64) {
        let mut bins = vec![0.0; ANGLE_BINS];
        add_even(&mut bins, 1.0 - share, 0.0, x_of(rh));
        let x_core = rc * rc / 2.0;
        let within =
            |x: f64| share * (x / x_core).min(1.0) + (1.0 - share) * (x / x_of(rh)).min(1.0);
        (
            core_rest_radius(disc(share, rc), &bins),
            median_disc(within, 1.0),
        )
    }

    #[test]
    fn the_radius_is_the_half_energy_disc_of_core_and_rest() {
        let (rc, rh) = (0.5f64.to_radians(), 4f64.to_radians());
        for share in [0.0, 0.05, 0.2, 0.3, 0.45, 0.6, 0.8, 0.95, 1.0] {
            let (got, expected) = core_and_cap(share, rc, rh);
            assert!(
                (got as f64 - expected).abs() <= 1e-4 * expected,
                "share {share}: {got} vs {expected}"
            );
        }
        // All rest: the cap's radius (√2·θ₅₀ of a cap is its radius to second order); all core:
        // the core's.
        assert!((core_and_cap(0.0, rc, rh).0 as f64 - rh).abs() < 1e-3 * rh);
        assert!((core_and_cap(1.0, rc, rh).0 as f64 - rc).abs() < 1e-3 * rc);
    }

    #[test]
    fn the_radius_runs_from_the_rests_to_the_cores_without_a_jump() {
        let (rc, rh) = (0.3f64.to_radians(), 6f64.to_radians());
        let radius = |s: f64| core_and_cap(s, rc, rh).0 as f64;
        // Monotone in the core's share, and continuous: no step between shares 10⁻⁷ apart
        // (a threshold between the two radii would step by up to rh − rc anywhere).
        let mut last = radius(0.001);
        for i in 2..1000 {
            let s = i as f64 / 1000.0;
            let r = radius(s);
            assert!(r <= last + 1e-7, "not monotone at share {s}");
            assert!(
                (radius(s + 1e-7) - r).abs() < 1e-3 * rh,
                "step at share {s}"
            );
            last = r;
        }
    }

    #[test]
    fn a_faint_wide_halo_leaves_a_clear_sun_its_own_radius() {
        // A 0.27° sun holding 80 % of its cell, the rest spread over 20°: the cell's RMS disc
        // would be degrees wide; the half-energy disc is about √(2·0.5/0.8) = 1.118 × the sun's.
        let (rc, rh) = (0.27f64.to_radians(), 20f64.to_radians());
        let r = core_and_cap(0.8, rc, rh).0 as f64;
        assert!(
            r > rc && r < 1.12 * rc,
            "{} vs sun {}",
            r.to_degrees(),
            rc.to_degrees()
        );
    }

    #[test]
    fn a_little_far_sky_does_not_carry_a_glare_off() {
        // A 0.27° sun (40 %) in a uniform 2° glare (57 %), and 3 % of sky 20–40° away, as a
        // sun's cell at 16 lights holds: about the glare's median, where the rest taken as one
        // disc of its RMS spread (the sky's 3 % over 30° and the glare's 2°) gave 4.3°.
        let (rc, rg) = (0.27f64.to_radians(), 2f64.to_radians());
        let (s0, s1) = (x_of(20f64.to_radians()), x_of(40f64.to_radians()));
        let mut bins = vec![0.0; ANGLE_BINS];
        add_even(&mut bins, 0.57, 0.0, x_of(rg));
        add_even(&mut bins, 0.03, s0, s1);
        let within = |x: f64| {
            0.4 * (x / (rc * rc / 2.0)).min(1.0)
                + 0.57 * (x / x_of(rg)).min(1.0)
                + 0.03 * ((x - s0) / (s1 - s0)).clamp(0.0, 1.0)
        };
        let expected = median_disc(within, 1.0);
        let got = core_rest_radius(disc(0.4, rc), &bins) as f64;
        assert!(
            (got - expected).abs() <= 1e-4 * expected,
            "{got} vs {expected}"
        );
        assert!(got < rg, "{}°", got.to_degrees());
    }

    #[test]
    fn the_bins_cover_every_angle_in_order() {
        assert_eq!(angle_bin(0.0), 0);
        assert_eq!(angle_bin(f32::NAN), 0);
        assert_eq!(angle_bin(2.0), ANGLE_BINS - 1);
        for b in 0..ANGLE_BINS {
            assert!(angle_bin_start(b) < angle_bin_start(b + 1), "bin {b}");
        }
        for i in 0..20_000 {
            let x = (2.0f64).powf(-26.0 + 27.0 * i as f64 / 20_000.0).min(2.0) as f32;
            let b = angle_bin(x);
            let x = x as f64;
            assert!(
                (b == 0 || angle_bin_start(b) <= x)
                    && (b == ANGLE_BINS - 1 || x < angle_bin_start(b + 1)),
                "x {x} in bin {b}"
            );
        }
    }

    #[test]
    fn bad_input_gives_a_finite_radius() {
        let bins = |y: f32| vec![y; ANGLE_BINS];
        for (core, rest) in [
            ((0.0, 0.0), bins(0.0)),
            ((1.0, f64::NAN), bins(0.1)),
            ((0.0, 0.0), bins(0.1)),
            ((1.0, 1.2), bins(0.0)),
            ((1.0, 0.5), bins(f32::INFINITY)),
            ((1.0, 0.5), bins(f32::NAN)),
            ((-1.0, 0.5), bins(-0.1)),
        ] {
            let r = core_rest_radius(core, &rest);
            assert!(
                r.is_finite() && (0.0..=std::f32::consts::PI).contains(&r),
                "{core:?} {:?}: {r}",
                rest[0]
            );
        }
    }

    /// ALGORITHMS.md §12, "Two-part extent": a core of 40 % on a 0.5° disc in a uniform 5° cap
    /// gives back the core's share and radius and the cap's radius (a uniform disc's √2·θ₅₀ is its
    /// radius); one disc stands for a lone core, a core with a sliver of rest, and a rest only three
    /// times as wide as the core (and a horizon clamp that leaves it so).
    #[test]
    fn a_core_in_a_wider_rest_gets_a_two_part_extent_and_no_more() {
        let (rc, rh) = (0.5f64.to_radians(), 5f64.to_radians());
        let extent = |share: f64, rh: f64| {
            let mut bins = vec![0.0; ANGLE_BINS];
            add_even(&mut bins, 1.0 - share, 0.0, x_of(rh));
            LightExtent::of_core_and_rest(disc(share, rc), &bins)
        };
        let e = extent(0.4, rh).expect("a core in a wider rest");
        assert!((e.core_share as f64 - 0.4).abs() < 1e-6, "{e:?}");
        assert!((e.core_radius as f64 - rc).abs() < 1e-3 * rc, "{e:?}");
        assert!((e.rest_radius as f64 - rh).abs() < 0.02 * rh, "{e:?}");
        let [(s0, r0, d0), (s1, r1, d1)] = e.parts(DVec3::Y);
        assert!((s0 + s1 - 1.0).abs() < 1e-12 && r0 == e.core_radius && r1 == e.rest_radius);
        assert!(
            d0 == DVec3::Y && d1 == DVec3::Y,
            "no core direction: both about the light's"
        );
        let aside = DVec3::new(0.01, 1.0, 0.0);
        let [(_, _, d0), (_, _, d1)] = e.toward(aside * 3.0).parts(DVec3::Y);
        assert!(
            d0.abs_diff_eq(aside.normalize(), 1e-6) && d1 == DVec3::Y,
            "the core's own"
        );
        let mut light = Light {
            id: 0,
            to_light: [0.0, 1.0, 0.0],
            irradiance: [1.0; 3],
            solid_angle: 0.01,
            angular_radius: 0.02,
            extent: None,
            shadowed: None,
        };
        assert_eq!(light.one_map_shadow_dir(), DVec3::Y, "no extent");
        // The core's own within 2°, the light's from 4°, and between turned part way in the
        // plane of the two: the angle from the light is a·(4° − a)/2°, continuous, so a core
        // moving 0.01° moves the map's direction by at most 0.02° (the slope at 4° is −2).
        let (full, none) = ONE_MAP_CORE_DEG;
        let mut last: Option<DVec3> = None;
        for step in 0..=600 {
            let deg = step as f64 * 0.01;
            let t = deg.to_radians();
            let core = DVec3::new(t.sin(), t.cos(), 0.0);
            light.extent = Some(e.toward(core));
            let got = light.one_map_shadow_dir();
            let share = ((none - deg) / (none - full)).clamp(0.0, 1.0);
            let want_deg = deg * share;
            let got_deg = got.angle_between(DVec3::Y).to_degrees();
            assert!(
                (got_deg - want_deg).abs() < 1e-4,
                "{deg}°: {got_deg}° from the light"
            );
            assert!(
                got.z.abs() < 1e-9 && got.x >= 0.0,
                "{deg}°: in the plane, toward the core"
            );
            if deg <= full {
                assert!(got.abs_diff_eq(core, 1e-6), "{deg}°: the core's own");
            }
            if deg >= none {
                assert!(got.abs_diff_eq(DVec3::Y, 1e-6), "{deg}°: the light's own");
            }
            if let Some(prev) = last {
                let jump = got.angle_between(prev).to_degrees();
                assert!(jump <= 0.02 + 1e-6, "{deg}°: jumped {jump}°");
            }
            last = Some(got);
        }
        assert_eq!(extent(1.0, rh), None, "a lone core");
        assert_eq!(extent(0.995, rh), None, "a sliver of rest");
        assert_eq!(
            extent(0.4, 3.0 * rc),
            None,
            "a rest three times as wide as the core"
        );
        let clamped = e
            .clamped(3f32.to_radians())
            .expect("the rest still 6 × the core");
        assert_eq!(clamped.core_radius, e.core_radius);
        assert_eq!(clamped.rest_radius, 3f32.to_radians());
        assert_eq!(
            e.clamped(1f32.to_radians()),
            None,
            "the rest clamped to 2 × the core"
        );
    }
}
