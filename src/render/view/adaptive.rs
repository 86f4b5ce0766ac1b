//! Adaptive light count (`--target-fps`, ALGORITHMS.md §6): draw a shorter prefix of the progressive
//! set when frames are slow, a longer one when there is time to spare.
//!
//! Input: the full [`Light`] list (ids in progressive order) and measured frame times. Output: the
//! prefix to draw, with the energy of the lights left out handed to their nearest kept light, so
//! that Σ irradiance, and with it the image's overall brightness, does not change with the count
//! (DESIGN.md: a prefix of the progressive set is itself well stratified, so the nearest kept light
//! stands for a dropped light's region about as its Voronoi cell would). `LightState` is what the
//! frame loops hold: the newest set, and the prefix of it the [`Renderer`] draws.

use crate::lights::Light;
use crate::render::renderer::Renderer;
use glam::Vec3;

/// The first `n` lights by id, each carrying the irradiance of the dropped lights nearest to it.
pub fn prefix_with_energy(all: &[Light], n: usize, out: &mut Vec<Light>) {
    out.clear();
    out.extend_from_slice(all);
    out.sort_by_key(|l| l.id);
    if n >= out.len() || n == 0 {
        return;
    }
    let (kept, dropped) = out.split_at_mut(n);
    for d in dropped.iter() {
        let dir = Vec3::from_array(d.to_light);
        // Nearest on the sphere = largest dot product.
        let nearest = kept
            .iter_mut()
            .max_by(|a, b| {
                let da = Vec3::from_array(a.to_light).dot(dir);
                let db = Vec3::from_array(b.to_light).dot(dir);
                da.total_cmp(&db)
            })
            .expect("n > 0");
        let moment = nearest.moment() + d.moment();
        for c in 0..3 {
            nearest.irradiance[c] += d.irradiance[c];
        }
        nearest.solid_angle += d.solid_angle;
        // The merged region's spread (ALGORITHMS.md §12), from the summed moments.
        nearest.angular_radius =
            crate::lights::angular_radius(nearest.luminance(), moment.length());
        nearest.extent = None;
    }
    out.truncate(n);
    keep_shadow_budget(all, out);
}

/// A shadow budget survives the cut: when the full set marks K lights `shadowed` and fewer of them
/// are kept, the kept lights are marked again (`budget::mark`, the marks still present kept), so
/// that a prefix still draws min(K, n) lights with shadow maps.
fn keep_shadow_budget(all: &[Light], kept: &mut [Light]) {
    let k = all.iter().filter(|l| l.shadowed == Some(true)).count();
    if !all.iter().any(|l| l.shadowed.is_some()) {
        return;
    }
    let still: Vec<u32> = kept
        .iter()
        .filter(|l| l.shadowed == Some(true))
        .map(|l| l.id)
        .collect();
    if still.len() < k.min(kept.len()) {
        crate::lights::budget::mark(kept, k, &still);
    }
}

/// Chooses the light count from the frame times.
#[derive(Clone, Debug)]
pub struct LightBudget {
    target_ms: f32,
    /// Smoothed frame time (exponential moving average).
    ema_ms: Option<f32>,
    count: usize,
    /// Frames to wait before judging (again): at the start (shader compilation, every shadow map
    /// drawn) and after a change (the new count's maps cost a frame or two to draw).
    cooldown: u32,
}

impl LightBudget {
    /// Light counts are never cut below this.
    pub const MIN_LIGHTS: usize = 4;

    pub fn new(target_fps: f32, start: usize) -> LightBudget {
        LightBudget {
            target_ms: 1000.0 / target_fps.max(0.1),
            ema_ms: None,
            count: start.max(Self::MIN_LIGHTS),
            cooldown: 2,
        }
    }

    pub fn count(&self) -> usize {
        self.count
    }

    /// Records one frame's time; returns the count to draw next (at most `available`).
    pub fn update(&mut self, frame_ms: f32, available: usize) -> usize {
        if self.cooldown > 0 {
            // Frames right after a change say little about the new count; forget the old ones.
            self.cooldown -= 1;
            self.ema_ms = None;
            return self.count.min(available.max(Self::MIN_LIGHTS));
        }
        let ema = match self.ema_ms {
            Some(e) => 0.5 * e + 0.5 * frame_ms,
            None => frame_ms,
        };
        self.ema_ms = Some(ema);
        if ema > 1.1 * self.target_ms && self.count > Self::MIN_LIGHTS {
            // Shading cost is about linear in the count: scale toward the target.
            let scale = (self.target_ms / ema).clamp(0.5, 0.9);
            self.count = ((self.count as f32 * scale) as usize).max(Self::MIN_LIGHTS);
            self.cooldown = 2;
        } else if ema < 0.8 * self.target_ms && self.count < available {
            self.count = (self.count + (self.count / 8).max(1)).min(available);
            self.cooldown = 2;
        }
        self.count = self.count.min(available.max(Self::MIN_LIGHTS));
        self.count
    }
}

/// The frame loop's lights: applies each new set to the renderer, through the light budget when
/// `--target-fps` sets one.
pub(crate) struct LightState {
    all: Vec<Light>,
    drawn: Vec<Light>,
    budget: Option<LightBudget>,
}

impl LightState {
    pub(crate) fn new(target_fps: Option<f32>, lights: usize) -> Self {
        LightState {
            all: Vec::new(),
            drawn: Vec::new(),
            budget: target_fps.map(|f| LightBudget::new(f, lights)),
        }
    }

    /// A new set arrived.
    pub(crate) fn set(&mut self, renderer: &mut Renderer, lights: &[Light]) {
        self.all.clear();
        self.all.extend_from_slice(lights);
        self.apply(renderer);
    }

    fn apply(&mut self, renderer: &mut Renderer) {
        let n = self.budget.as_ref().map_or(self.all.len(), |b| b.count());
        prefix_with_energy(&self.all, n, &mut self.drawn);
        renderer.set_lights(&self.drawn);
    }

    /// A frame took `ms`: maybe change the count.
    pub(crate) fn frame_time(&mut self, renderer: &mut Renderer, ms: f32) {
        let available = self.all.len();
        if let Some(b) = &mut self.budget {
            let before = b.count().min(available);
            if b.update(ms, available) != before {
                self.apply(renderer);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, d: [f32; 3], e: f32) -> Light {
        Light {
            id,
            to_light: Vec3::from_array(d).normalize().to_array(),
            irradiance: [e; 3],
            solid_angle: 0.5,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        }
    }

    #[test]
    fn a_prefix_keeps_the_total_energy_and_gives_it_to_the_nearest() {
        let all = [
            light(2, [0.0, 1.0, 0.1], 3.0),
            light(0, [0.0, 1.0, 0.0], 1.0),
            light(1, [1.0, 0.0, 0.0], 2.0),
        ];
        let mut out = Vec::new();
        prefix_with_energy(&all, 2, &mut out);
        assert_eq!(out.iter().map(|l| l.id).collect::<Vec<_>>(), [0, 1]);
        assert_eq!(out[0].irradiance, [4.0; 3], "light 2 is nearest to light 0");
        let total: f32 = out.iter().map(|l| l.irradiance[0]).sum();
        assert_eq!(total, 6.0);
    }

    #[test]
    fn a_prefix_keeps_as_many_shadowed_lights_as_the_set_marked() {
        let mut all = [
            light(0, [0.0, 1.0, 0.0], 1.0),
            light(1, [1.0, 0.2, 0.0], 2.0),
            light(2, [0.0, 1.0, 0.1], 9.0),
            light(3, [-1.0, 0.2, 0.0], 0.5),
        ];
        crate::lights::budget::mark(&mut all, 1, &[]);
        assert_eq!(all[2].shadowed, Some(true));
        // Light 2 is cut; its energy goes to light 0, which now carries the mark.
        let mut out = Vec::new();
        prefix_with_energy(&all, 2, &mut out);
        let marked: Vec<u32> = out
            .iter()
            .filter(|l| l.shadowed == Some(true))
            .map(|l| l.id)
            .collect();
        assert_eq!(marked, [0]);
        assert!(out.iter().all(|l| l.shadowed.is_some()));
    }

    #[test]
    fn the_budget_cuts_when_slow_and_grows_when_fast() {
        let mut b = LightBudget::new(30.0, 72);
        // The first frames (compilation, every map drawn) are not judged.
        assert_eq!(b.update(800.0, 72), 72);
        assert_eq!(b.update(300.0, 72), 72);
        let n = b.update(100.0, 72);
        assert!(n < 72, "{n}");
        for _ in 0..200 {
            b.update(5.0, 72);
        }
        assert_eq!(b.count(), 72);
    }
}
