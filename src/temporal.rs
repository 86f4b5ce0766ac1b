//! Temporal filtering of light trajectories (ALGORITHMS.md §5).
//!
//! Input: one frame's lights, in id order (light id k is the k-th progressive point, so id k in one
//! frame and id k in the next are the same light). Output: the same lights with direction and
//! irradiance low-pass filtered over the last M frames by a FIR kernel: flicker above a few hertz —
//! where temporal contrast sensitivity peaks — is suppressed, at the price of (M−1)/2 frames of delay.
//!
//! The direction is filtered as a 3-D vector and renormalised (no angle wrap-around); irradiance per
//! channel. The default kernel is binomial (non-negative: power can never go negative and a step
//! never overshoots); a Hamming-windowed sinc is available for a sharper cut-off, with its negative
//! taps clamped away from the output power.

use crate::lights::{Light, LightExtent};
use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

/// The kernel family.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
#[value(rename_all = "lowercase")]
pub enum FilterKind {
    /// No filtering: each frame's lights as they are.
    #[value(help = "no filtering")]
    None,
    /// Binomial coefficients C(M−1, n)/2^(M−1): response cos^(M−1)(πf), never negative.
    #[value(help = "binomial FIR, never overshoots (the default)")]
    Binomial,
    /// Hamming-windowed sinc, h\[n\] = w\[n\]·2f_c·sinc(2f_c(n − (M−1)/2)), normalised to Σh = 1.
    #[value(help = "Hamming-windowed sinc, sharper cut-off (--cutoff-hz)")]
    Sinc,
}

impl std::str::FromStr for FilterKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        <FilterKind as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown filter '{s}' (expected none, binomial or sinc)"))
    }
}

/// A filter's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterSpec {
    pub kind: FilterKind,
    /// Number of taps M (odd keeps the delay a whole number of frames).
    pub taps: usize,
    /// Cut-off of the sinc kernel in cycles per frame (f_c / frame rate), in (0, 0.5).
    pub cutoff: f64,
}

impl Default for FilterSpec {
    /// 9 binomial taps: −10 dB at 1/6 of the frame rate (5 Hz at 30 frames/s), −48 dB at 1/3
    /// (10 Hz at 30 frames/s), 4 frames of delay.
    fn default() -> Self {
        FilterSpec {
            kind: FilterKind::Binomial,
            taps: 9,
            cutoff: 0.1,
        }
    }
}

impl FilterSpec {
    pub fn none() -> Self {
        FilterSpec {
            kind: FilterKind::None,
            taps: 1,
            cutoff: 0.5,
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        if self.kind != FilterKind::None && !(1..=255).contains(&self.taps) {
            return Err(format!("filter taps must be 1–255, got {}", self.taps));
        }
        if self.kind == FilterKind::Sinc && !(self.cutoff > 0.0 && self.cutoff < 0.5) {
            return Err(format!(
                "sinc cut-off must be in (0, 0.5) cycles per frame, got {}",
                self.cutoff
            ));
        }
        Ok(())
    }

    /// The kernel, h\[0\] applied to the newest frame; Σh = 1.
    pub fn kernel(&self) -> Vec<f64> {
        let m = match self.kind {
            FilterKind::None => 1,
            _ => self.taps.max(1),
        };
        let mut h: Vec<f64> = match self.kind {
            FilterKind::None => vec![1.0],
            FilterKind::Binomial => {
                // Pascal's triangle row m − 1.
                let mut row = vec![1.0f64];
                for _ in 1..m {
                    let mut next = vec![1.0; row.len() + 1];
                    for k in 1..row.len() {
                        next[k] = row[k - 1] + row[k];
                    }
                    row = next;
                }
                row
            }
            FilterKind::Sinc => (0..m)
                .map(|n| {
                    let centre = (m as f64 - 1.0) / 2.0;
                    let x = 2.0 * self.cutoff * (n as f64 - centre);
                    let sinc = if x == 0.0 {
                        1.0
                    } else {
                        (std::f64::consts::PI * x).sin() / (std::f64::consts::PI * x)
                    };
                    let window = if m == 1 {
                        1.0
                    } else {
                        0.54 - 0.46
                            * (2.0 * std::f64::consts::PI * n as f64 / (m as f64 - 1.0)).cos()
                    };
                    window * 2.0 * self.cutoff * sinc
                })
                .collect(),
        };
        let sum: f64 = h.iter().sum();
        for v in &mut h {
            *v /= sum;
        }
        h
    }

    /// Group delay in frames, (M − 1)/2 for these symmetric kernels.
    pub fn delay_frames(&self) -> f64 {
        (self.kernel().len() as f64 - 1.0) / 2.0
    }

    /// Gain |H(f)| at `f` cycles per frame.
    pub fn gain(&self, f: f64) -> f64 {
        let (mut re, mut im) = (0.0, 0.0);
        for (n, h) in self.kernel().iter().enumerate() {
            let w = 2.0 * std::f64::consts::PI * f * n as f64;
            re += h * w.cos();
            im -= h * w.sin();
        }
        (re * re + im * im).sqrt()
    }
}

/// What the LightSet document says about the filter that produced it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FilterInfo {
    pub kind: FilterKind,
    pub taps: usize,
    /// Sinc cut-off in hertz at the nominal frame rate (absent for other kernels).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutoff_hz: Option<f64>,
    /// Group delay: frames, and milliseconds at the nominal frame rate.
    pub delay_frames: f64,
    pub delay_ms: f64,
}

impl FilterInfo {
    pub fn new(spec: &FilterSpec, fps: f64) -> Self {
        let delay = spec.delay_frames();
        FilterInfo {
            kind: spec.kind,
            taps: spec.kernel().len(),
            cutoff_hz: (spec.kind == FilterKind::Sinc).then_some(spec.cutoff * fps),
            delay_frames: delay,
            delay_ms: if fps > 0.0 { delay / fps * 1e3 } else { 0.0 },
        }
    }
}

/// Per-id FIR state over the last M frames.
pub struct TemporalFilter {
    kernel: Vec<f64>,
    /// history[id] = the last frames of that light, newest last (at most M).
    history: Vec<std::collections::VecDeque<Light>>,
}

impl TemporalFilter {
    pub fn new(spec: &FilterSpec) -> Self {
        TemporalFilter {
            kernel: spec.kernel(),
            history: Vec::new(),
        }
    }

    /// Forgets every trajectory (e.g. after a source restart).
    pub fn reset(&mut self) {
        self.history.clear();
    }

    /// Pushes one frame's lights and returns the filtered lights, in the same order. Until M frames
    /// have been seen, the kernel is truncated to the frames available and renormalised, so a new
    /// stream starts at its first frame's values instead of ramping up from zero.
    pub fn filter(&mut self, lights: &[Light]) -> Vec<Light> {
        let m = self.kernel.len();
        if m == 1 {
            return lights.to_vec();
        }
        if self.history.len() < lights.len() {
            self.history.resize_with(lights.len(), || {
                std::collections::VecDeque::with_capacity(m)
            });
        }
        lights
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let hist = &mut self.history[k];
                if hist.len() == m {
                    hist.pop_front();
                }
                hist.push_back(*l);
                // h[0] weighs the newest frame.
                let taps = &self.kernel[..hist.len()];
                let norm: f64 = taps.iter().sum();
                let mut dir = Vec3::ZERO;
                let mut irr = [0.0f64; 3];
                let mut sr = 0.0f64;
                let mut radius = 0.0f64;
                // The two-part extent is filtered as the mixture of the window's discs: the
                // share is the mean share, each disc's radius the mean over the luminance it
                // holds. A frame without an extent is one disc of its `angular_radius`, counted
                // whole with the part whose radius it is nearer (in ratio), so a light whose
                // extent comes or goes fades between two discs and one instead of switching.
                let parts = ExtentParts::of_window(hist.iter());
                let mut mixture = ExtentSums::default();
                for (h, past) in taps.iter().zip(hist.iter().rev()) {
                    let w = (h / norm) as f32;
                    dir += Vec3::from_array(past.to_light) * w;
                    for c in 0..3 {
                        irr[c] += h / norm * past.irradiance[c] as f64;
                    }
                    sr += h / norm * past.solid_angle as f64;
                    radius += h / norm * past.angular_radius as f64;
                    if let Some(parts) = parts {
                        parts.add(past, h / norm, &mut mixture);
                    }
                }
                Light {
                    id: l.id,
                    to_light: dir
                        .try_normalize()
                        .unwrap_or(Vec3::from_array(l.to_light))
                        .to_array(),
                    // Negative sinc taps can undershoot: power is never negative.
                    irradiance: irr.map(|v| v.max(0.0) as f32),
                    solid_angle: sr.max(0.0) as f32,
                    angular_radius: radius.max(0.0) as f32,
                    extent: parts.map(|parts| parts.extent(mixture)),
                    shadowed: None,
                }
            })
            .collect()
    }
}

/// The two parts' mean radii over the extents in a filter's window, which frames without an
/// extent are sorted against and which stand in for a part that holds no luminance.
#[derive(Clone, Copy)]
struct ExtentParts {
    core_radius: f64,
    rest_radius: f64,
}

impl ExtentParts {
    /// `None` where no frame in the window has an extent (the light is one disc).
    fn of_window<'a>(window: impl Iterator<Item = &'a Light>) -> Option<ExtentParts> {
        let (mut n, mut core, mut rest) = (0usize, 0.0f64, 0.0f64);
        for e in window.filter_map(|l| l.extent) {
            n += 1;
            core += e.core_radius as f64;
            rest += e.rest_radius as f64;
        }
        (n > 0).then(|| ExtentParts {
            core_radius: core / n as f64,
            rest_radius: rest / n as f64,
        })
    }

    /// Adds one frame of weight `w` to `sums`.
    fn add(self, l: &Light, w: f64, sums: &mut ExtentSums) {
        let (core_share, core_radius, rest_radius) = match l.extent {
            Some(e) => (
                e.core_share as f64,
                e.core_radius as f64,
                e.rest_radius as f64,
            ),
            None => {
                let r = l.angular_radius as f64;
                // Nearer in ratio: r² < r_core · r_rest.
                let core = r * r < self.core_radius * self.rest_radius;
                (if core { 1.0 } else { 0.0 }, r, r)
            }
        };
        let own = l.extent.and_then(|e| e.core_to_light);
        sums.any_core_dir |= own.is_some();
        let core_dir = own.unwrap_or(l.to_light);
        let sum = &mut sums.parts;
        sum[0] += w * core_share;
        sum[1] += w * core_share * core_radius;
        sum[2] += w * (1.0 - core_share);
        sum[3] += w * (1.0 - core_share) * rest_radius;
        sums.core_dir += DVec3::from_array(core_dir.map(f64::from)) * (w * core_share);
    }

    fn extent(self, sums: ExtentSums) -> LightExtent {
        const EMPTY: f64 = 1e-9;
        let [core, core_r, rest, rest_r] = sums.parts;
        let share = (core / (core + rest)).clamp(0.0, 1.0);
        LightExtent {
            core_share: if share.is_finite() { share as f32 } else { 0.0 },
            core_radius: if core > EMPTY {
                core_r / core
            } else {
                self.core_radius
            }
            .max(0.0) as f32,
            rest_radius: if rest > EMPTY {
                rest_r / rest
            } else {
                self.rest_radius
            }
            .max(0.0) as f32,
            core_to_light: None,
        }
        .toward(if core > EMPTY && sums.any_core_dir {
            sums.core_dir
        } else {
            DVec3::ZERO
        })
    }
}

/// A window's sums for the extent's mixture: `parts` = [core luminance, core luminance × radius,
/// rest luminance, rest luminance × radius] (as shares of the light's), and the core's
/// directions weighed by the core's luminance (renormalised, as `to_light` is). The filtered
/// extent has a core direction only where some frame in the window had one: a window of
/// extents without one (a horizon-guarded core, an older producer) stays without one.
#[derive(Default)]
struct ExtentSums {
    parts: [f64; 4],
    core_dir: DVec3,
    any_core_dir: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, dir: Vec3, power: f32) -> Light {
        Light {
            id,
            to_light: dir.normalize().to_array(),
            irradiance: [power; 3],
            solid_angle: 0.1,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        }
    }

    #[test]
    fn kernels_sum_to_one_and_are_symmetric() {
        for spec in [
            FilterSpec::default(),
            FilterSpec {
                kind: FilterKind::Sinc,
                taps: 9,
                cutoff: 0.1,
            },
        ] {
            let h = spec.kernel();
            assert!((h.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            for n in 0..h.len() {
                assert!((h[n] - h[h.len() - 1 - n]).abs() < 1e-12);
            }
            assert_eq!(spec.delay_frames(), 4.0);
        }
    }

    /// A light switched on (step in power): the output settles within M − 1 frames after the
    /// step (the documented delay is (M−1)/2), never goes negative and never overshoots.
    #[test]
    fn step_response_settles_without_going_negative() {
        for spec in [
            FilterSpec::default(),
            FilterSpec {
                kind: FilterKind::Sinc,
                taps: 9,
                cutoff: 0.1,
            },
        ] {
            let mut f = TemporalFilter::new(&spec);
            let m = spec.kernel().len();
            let mut outputs = Vec::new();
            for frame in 0..30 {
                let p = if frame < 10 { 0.0 } else { 5.0 };
                outputs.push(f.filter(&[light(0, Vec3::Y, p)])[0].irradiance[0]);
            }
            assert!(outputs.iter().all(|&o| o >= 0.0), "{spec:?}: {outputs:?}");
            // Settled: exactly the new value from frame 10 + (M − 1) on.
            for &o in &outputs[10 + m - 1..] {
                assert!((o - 5.0).abs() < 1e-5, "{spec:?}: {outputs:?}");
            }
            // Half-way at the group delay (symmetric kernel).
            let half = outputs[10 + (m - 1) / 2];
            assert!(half > 1.0 && half < 4.0, "{spec:?}: {outputs:?}");
            if spec.kind == FilterKind::Binomial {
                assert!(
                    outputs.iter().all(|&o| o <= 5.0 + 1e-5),
                    "overshoot {outputs:?}"
                );
            }
        }
    }

    /// Jitter at 10 Hz in a 30 frames/s stream is attenuated by at least 20 dB (the daemon's target), measured
    /// on a light's direction and power, not just on the kernel's formula.
    #[test]
    fn ten_hertz_jitter_at_thirty_fps_is_attenuated_20_db() {
        let spec = FilterSpec::default();
        assert!(20.0 * spec.gain(10.0 / 30.0).log10() < -20.0);
        let mut f = TemporalFilter::new(&spec);
        let (mut in_amp, mut out_amp) = (0.0f32, 0.0f32);
        let (mut in_dir, mut out_dir) = (0.0f32, 0.0f32);
        for frame in 0..120 {
            let phase = 2.0 * std::f32::consts::PI * 10.0 * frame as f32 / 30.0;
            let jitter = phase.sin();
            let dir = Vec3::new(0.05 * jitter, 1.0, 0.0);
            let out = f.filter(&[light(0, dir, 10.0 + jitter)])[0];
            if frame >= 20 {
                in_amp = in_amp.max(jitter.abs());
                out_amp = out_amp.max((out.irradiance[0] - 10.0).abs());
                in_dir = in_dir.max(dir.normalize().x.abs());
                out_dir = out_dir.max(out.to_light[0].abs());
            }
        }
        assert!(
            20.0 * (out_amp / in_amp).log10() < -20.0,
            "{out_amp} / {in_amp}"
        );
        assert!(
            20.0 * (out_dir / in_dir).log10() < -20.0,
            "{out_dir} / {in_dir}"
        );
    }

    #[test]
    fn none_passes_through_and_ids_are_kept() {
        let mut f = TemporalFilter::new(&FilterSpec::none());
        let ls = [light(0, Vec3::X, 1.0), light(1, Vec3::Y, 2.0)];
        assert_eq!(f.filter(&ls), ls.to_vec());
        let mut g = TemporalFilter::new(&FilterSpec::default());
        let out = g.filter(&ls);
        assert_eq!(out, ls.to_vec(), "first frame passes unchanged");
        assert!(out.iter().enumerate().all(|(k, l)| l.id == k as u32));
    }

    /// A light's two-part extent is filtered part by part like its radius: a constant extent
    /// passes unchanged and a step in the core's share settles on the new share.
    #[test]
    fn a_two_part_extent_is_filtered_part_by_part() {
        let spec = FilterSpec::default();
        let m = spec.kernel().len();
        let mut f = TemporalFilter::new(&spec);
        for _ in 0..m {
            let out = f.filter(&[two_part(0.4)])[0]
                .extent
                .expect("every frame has one");
            assert!((out.core_share - 0.4).abs() < 1e-6 && (out.rest_radius - 0.1).abs() < 1e-7);
        }
        let shares: Vec<f32> = (0..m)
            .map(|_| {
                f.filter(&[two_part(0.8)])[0]
                    .extent
                    .expect("extent")
                    .core_share
            })
            .collect();
        assert!(shares.windows(2).all(|w| w[1] >= w[0]), "{shares:?}");
        assert!((shares[m - 1] - 0.8).abs() < 1e-5, "{shares:?}");
    }

    /// The core's direction is filtered as the mixture's: a constant one passes unchanged; one
    /// that steps 1° turns monotonically onto the new direction; a frame without one counts the
    /// light's own direction (a core on the light).
    #[test]
    fn the_cores_direction_is_filtered_with_its_share() {
        let spec = FilterSpec::default();
        let m = spec.kernel().len();
        let toward = |deg: f32| {
            let mut l = two_part(0.5);
            let d = Vec3::new(deg.to_radians().sin(), deg.to_radians().cos(), 0.0);
            l.extent = l.extent.map(|e| LightExtent {
                core_to_light: Some(d.to_array()),
                ..e
            });
            l
        };
        let core = |l: &Light| {
            Vec3::from_array(
                l.extent
                    .expect("extent")
                    .core_to_light
                    .expect("a core direction"),
            )
        };
        let mut f = TemporalFilter::new(&spec);
        for _ in 0..m {
            let out = f.filter(&[toward(0.5)]);
            let angle = core(&out[0]).angle_between(Vec3::new(
                0.5f32.to_radians().sin(),
                0.5f32.to_radians().cos(),
                0.0,
            ));
            assert!(angle < 1e-5, "constant: {angle}");
        }
        let angles: Vec<f32> = (0..m)
            .map(|_| core(&f.filter(&[toward(1.5)])[0]).x.asin().to_degrees())
            .collect();
        assert!(angles.windows(2).all(|w| w[1] >= w[0] - 1e-4), "{angles:?}");
        assert!((angles[m - 1] - 1.5).abs() < 1e-3, "{angles:?}");
        // A frame with no core direction: its core is the light (+Y, 0°), pulling toward it.
        let mixed = core(&f.filter(&[two_part(0.5)])[0]).x.asin().to_degrees();
        assert!(mixed < 1.5 - 1e-3 && mixed > 0.0, "{mixed}");
        // Once no frame in the window has one, the filtered extent has none either.
        for _ in 0..m - 1 {
            f.filter(&[two_part(0.5)]);
        }
        let last = f.filter(&[two_part(0.5)])[0].extent.expect("extent");
        assert_eq!(last.core_to_light, None);
        let mut fresh = TemporalFilter::new(&spec);
        let first = fresh.filter(&[two_part(0.5)])[0].extent.expect("extent");
        assert_eq!(first.core_to_light, None);
    }

    /// A light whose extent goes (and comes back) fades between two discs and one: the shadow
    /// it draws across an edge changes per frame by no more than the kernel's largest tap times
    /// the whole change (a switch would move it by the whole change at once), and the light is
    /// one disc again once no frame in the window has an extent.
    #[test]
    fn an_extent_that_comes_and_goes_fades_instead_of_switching() {
        let spec = FilterSpec::default();
        let kernel = spec.kernel();
        let m = kernel.len();
        let max_tap = kernel.iter().cloned().fold(0.0, f64::max);
        let one_disc = Light {
            angular_radius: 0.05,
            ..light(0, Vec3::Y, 1.0)
        };
        let with = Light {
            angular_radius: 0.05,
            ..two_part(0.6)
        };
        // Lit share across a straight edge at angular offsets x from the light's direction.
        let edge = |l: &Light| -> Vec<f64> {
            (-8..=8)
                .map(|k| {
                    let x = k as f64 * 0.015;
                    match l.extent {
                        Some(e) => {
                            e.core_share as f64 * lit_beyond(x, e.core_radius as f64)
                                + (1.0 - e.core_share as f64) * lit_beyond(x, e.rest_radius as f64)
                        }
                        None => lit_beyond(x, l.angular_radius as f64),
                    }
                })
                .collect()
        };
        let (full_with, full_without) = (edge(&with), edge(&one_disc));
        let whole = full_with
            .iter()
            .zip(&full_without)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(whole > 0.05, "the two shadows differ: {whole}");
        let mut f = TemporalFilter::new(&spec);
        let frames = [vec![with; m], vec![one_disc; m], vec![with; m]].concat();
        let drawn: Vec<(Light, Vec<f64>)> = frames
            .iter()
            .map(|l| {
                let out = f.filter(&[*l])[0];
                (out, edge(&out))
            })
            .collect();
        for (k, w) in drawn.windows(2).enumerate() {
            let step = w[0].1.iter().zip(&w[1].1).map(|(a, b)| (a - b).abs());
            let step = step.fold(0.0, f64::max);
            assert!(
                step <= max_tap * whole + 1e-6,
                "frame {}: {step} of {whole}",
                k + 1
            );
        }
        assert_eq!(
            drawn[2 * m - 1].0.extent,
            None,
            "one disc once the window has none"
        );
        assert!(drawn[m].0.extent.is_some(), "fades out, not switched off");
        let last = &drawn[3 * m - 1].0;
        let e = last.extent.expect("back to two discs");
        assert!((e.core_share - 0.6).abs() < 1e-6 && (e.core_radius - 0.01).abs() < 1e-6);
    }

    fn two_part(share: f32) -> Light {
        Light {
            extent: Some(LightExtent {
                core_share: share,
                core_radius: 0.01,
                rest_radius: 0.1,
                core_to_light: None,
            }),
            ..light(0, Vec3::Y, 1.0)
        }
    }

    /// The share of a uniform disc of radius `r` lying beyond a straight edge at offset `x` from
    /// its centre (small angles: flat).
    fn lit_beyond(x: f64, r: f64) -> f64 {
        let d = (x / r).clamp(-1.0, 1.0);
        // Circular segment on the far side of the chord at distance d (in radii).
        let segment = (d.acos() - d * (1.0 - d * d).sqrt()) / std::f64::consts::PI;
        1.0 - segment
    }
}
