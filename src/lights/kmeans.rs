//! Converged spherical k-means (Kollig & Keller 2003; LightGen 2001), the floor of ALGORITHMS.md §10.
//!
//! Input: the domain image (texels weighted by Y·Δω, at their moment directions). Output: the
//! lights of a k-means fixed point: every texel's energy in the cell of its nearest centre on the
//! sphere, each centre at its cell's luminance centroid, iterated until no centre moves. Replacing a
//! cell by one light errs, to leading order, by the cell's k-means energy P − |M|, so this is the
//! practical floor of the unshadowed diffuse error at a given N; `vemlight eval` reports every
//! method's ratio to it. Seeds are k-means++ (Arthur & Vassilvitskii 2007) with a fixed generator,
//! so the floor is deterministic. Not a streaming method: it iterates up to [`MAX_ITERATIONS`]
//! assignment passes per frame and its ids follow no progressive point.

use super::light::Light;
use crate::sampling::DomainImage;
use glam::Vec3;

/// Assignment passes at most (the shared maps converge in 20–150).
pub const MAX_ITERATIONS: usize = 300;
/// A centre that moves less than this (radians) counts as still.
const STILL_RAD: f32 = 1e-5;

/// Buffers reused between frames.
#[derive(Default)]
pub struct KMeans {
    /// Which draw of the seeding's generator (0: the evaluation's floor).
    draw: u64,
    centres: Vec<Vec3>,
    dirs: Vec<Vec3>,
    weights: Vec<f64>,
    d2: Vec<f64>,
}

/// SplitMix64: a small deterministic generator, uniform in [0, 1).
fn next_unit(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

impl KMeans {
    /// Seeds from draw `draw` of the generator (default 0, the evaluation's floor): a k-means
    /// fixed point depends on its seeds, and other draws land in other ones, some lower
    /// (tests/floor.rs measures how much).
    pub fn set_draw(&mut self, draw: u64) {
        self.draw = draw;
    }

    /// k-means++ seeds for `n` centres over the lit texels of `image`, from the current draw of
    /// the generator: the first drawn by luminance, each next by luminance × squared chord
    /// distance to the nearest centre so far. With fewer lit texels than `n`, the remaining
    /// centres are spread at unlit texels.
    pub fn seed(&mut self, image: &DomainImage, n: usize) {
        self.dirs.clear();
        self.weights.clear();
        let side = image.side;
        for t in 0..side * side {
            let y = image.luminance[t] as f64;
            if y > 0.0
                && let Some(d) = Vec3::from_array(image.moment[t]).try_normalize()
            {
                self.dirs.push(d);
                self.weights.push(y);
            }
        }
        self.centres.clear();
        let mut rng = 0x5EED_0000_u64 ^ n as u64 ^ (self.draw << 32);
        if !self.dirs.is_empty() {
            self.d2.clear();
            self.d2.resize(self.dirs.len(), f64::INFINITY);
            let pick = |scores: &dyn Fn(usize) -> f64, rng: &mut u64| -> Option<usize> {
                let total: f64 = (0..self.dirs.len()).map(scores).sum();
                if total <= 0.0 || !total.is_finite() {
                    return None;
                }
                let mut target = next_unit(rng) * total;
                for t in 0..self.dirs.len() {
                    target -= scores(t);
                    if target <= 0.0 {
                        return Some(t);
                    }
                }
                Some(self.dirs.len() - 1)
            };
            let first = pick(&|t| self.weights[t], &mut rng).unwrap_or(0);
            let mut chosen = vec![first];
            let mut d2 = std::mem::take(&mut self.d2);
            while chosen.len() < n {
                let c = self.dirs[*chosen.last().expect("one")];
                for (t, d) in self.dirs.iter().enumerate() {
                    d2[t] = d2[t].min((2.0 - 2.0 * d.dot(c) as f64).max(0.0));
                }
                match pick(&|t| self.weights[t] * d2[t], &mut rng) {
                    Some(t) => chosen.push(t),
                    None => break, // every lit texel is a centre
                }
            }
            self.d2 = d2;
            self.centres.extend(chosen.iter().map(|&t| self.dirs[t]));
        }
        // Centres beyond the lit texels: evenly over the domain (they stay without energy).
        let mut k = 0;
        while self.centres.len() < n {
            let p = crate::sampling::progressive_points()[k % crate::sampling::N_MAX];
            self.centres
                .push(image.domain.square_to_dir(p).as_vec3().normalize());
            k += 1;
        }
    }

    /// Lloyd iterations from the seeds until no centre moves: `assign` gives the lights of one
    /// nearest-centre assignment (the default method's own pass), whose directions are the next
    /// centres.
    pub fn converge(&mut self, mut assign: impl FnMut(&[Vec3]) -> Vec<Light>) -> Vec<Light> {
        let mut lights = assign(&self.centres);
        for _ in 1..MAX_ITERATIONS {
            let mut moved = 0.0f32;
            for (c, l) in self.centres.iter_mut().zip(&lights) {
                let d = Vec3::from_array(l.to_light);
                moved = moved.max((*c - d).length());
                *c = d;
            }
            if moved < STILL_RAD {
                break;
            }
            lights = assign(&self.centres);
        }
        lights
    }
}
