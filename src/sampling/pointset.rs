//! The fixed progressive point set of ALGORITHMS.md §3.
//!
//! Output: `N_MAX` points in the unit square, fixed for the whole video, whose every power-of-two
//! prefix is well spread. Light id k is always point k (DESIGN.md), so a client asking for fewer lights
//! gets a stratified prefix, and a filter can follow an id through time.
//!
//! Construction: Halton (2,3) from index 1 (index 0 is a corner, i.e. on the horizon), then nested
//! Lloyd relaxation in blocks 1, 1, 2, 4, … : each block moves to the centroids of its Voronoi cells
//! (clipped to the square, which is not a torus) while every earlier point stays frozen. Cells are
//! measured on a fine raster of the square, which keeps the result deterministic.

use glam::DVec2;
use std::sync::OnceLock;

/// Largest light count served; every request takes a prefix of these points.
pub const N_MAX: usize = 1024;

/// Lloyd iterations per block (ALGORITHMS.md §3 asks for 20–50).
const LLOYD_ITERATIONS: usize = 30;

/// Raster samples per Voronoi cell when measuring centroids.
const SAMPLES_PER_CELL: usize = 256;

/// [`relaxed_halton`]`(N_MAX)`, computed once and stored with the source (little-endian f64 pairs),
/// since relaxing takes about a second; the test `embedded_set_matches_recomputation` keeps the file
/// equal to what the code computes.
const EMBEDDED: &[u8] = include_bytes!("pointset-1024.bin");

/// The process-wide point set.
pub fn progressive_points() -> &'static [DVec2] {
    static POINTS: OnceLock<Vec<DVec2>> = OnceLock::new();
    POINTS.get_or_init(|| {
        let pts = decode_points(EMBEDDED);
        if pts.len() == N_MAX {
            pts
        } else {
            relaxed_halton(N_MAX)
        }
    })
}

fn decode_points(bytes: &[u8]) -> Vec<DVec2> {
    bytes
        .chunks_exact(16)
        .map(|c| {
            let x = f64::from_le_bytes(c[..8].try_into().expect("8 bytes"));
            let y = f64::from_le_bytes(c[8..].try_into().expect("8 bytes"));
            DVec2::new(x, y)
        })
        .collect()
}

#[cfg(test)]
fn encode_points(pts: &[DVec2]) -> Vec<u8> {
    pts.iter()
        .flat_map(|p| p.x.to_le_bytes().into_iter().chain(p.y.to_le_bytes()))
        .collect()
}

/// The radical inverse of `i` in base `b` (van der Corput).
pub fn radical_inverse(mut i: u64, b: u64) -> f64 {
    let inv_b = 1.0 / b as f64;
    let mut f = inv_b;
    let mut r = 0.0;
    while i > 0 {
        r += f * (i % b) as f64;
        i /= b;
        f *= inv_b;
    }
    r
}

/// Plain Halton (2,3) points from index 1: the starting point of the relaxation.
pub fn halton(n: usize) -> Vec<DVec2> {
    (1..=n as u64)
        .map(|i| DVec2::new(radical_inverse(i, 2), radical_inverse(i, 3)))
        .collect()
}

/// Halton (2,3) followed by nested Lloyd relaxation; deterministic.
pub fn relaxed_halton(n: usize) -> Vec<DVec2> {
    let mut pts = halton(n);
    let mut index = NearestIndex::default();
    // Blocks [start, end): [1,4), [4,8), [8,16), … Point 0 stays at Halton's (½, ⅓): relaxed alone
    // it would go to the centre and leave the 2-point prefix closer than Halton's. Points 1–3 are
    // relaxed together: with a frozen 2-point prefix the 16-point prefix ends closer than Halton's
    // (0.153 against 0.161), with this start every power-of-two prefix is farther apart.
    let mut start = 1;
    let mut end = 4;
    while start < n {
        let end_c = end.min(n);
        let raster = ((SAMPLES_PER_CELL * end_c) as f64)
            .sqrt()
            .ceil()
            .clamp(64.0, 512.0) as usize;
        for _ in 0..LLOYD_ITERATIONS {
            index.rebuild(&pts[..end_c]);
            let mut sum = vec![DVec2::ZERO; end_c - start];
            let mut count = vec![0usize; end_c - start];
            for j in 0..raster {
                for i in 0..raster {
                    let p = DVec2::new(
                        (i as f64 + 0.5) / raster as f64,
                        (j as f64 + 0.5) / raster as f64,
                    );
                    let k = index.nearest(&pts[..end_c], p);
                    if k >= start {
                        sum[k - start] += p;
                        count[k - start] += 1;
                    }
                }
            }
            for k in start..end_c {
                if count[k - start] > 0 {
                    pts[k] = sum[k - start] / count[k - start] as f64;
                }
            }
        }
        start = end_c;
        end = (end_c * 2).max(end_c + 1);
    }
    pts
}

/// A uniform bucket grid over the unit square for nearest-point queries.
#[derive(Default)]
struct NearestIndex {
    g: usize,
    starts: Vec<usize>,
    ids: Vec<usize>,
}

impl NearestIndex {
    fn rebuild(&mut self, pts: &[DVec2]) {
        self.g = ((pts.len() as f64).sqrt().ceil() as usize).max(1);
        let g = self.g;
        let cell = |p: DVec2| {
            let i = ((p.x * g as f64) as usize).min(g - 1);
            let j = ((p.y * g as f64) as usize).min(g - 1);
            j * g + i
        };
        let mut counts = vec![0usize; g * g + 1];
        for &p in pts {
            counts[cell(p) + 1] += 1;
        }
        for c in 1..counts.len() {
            counts[c] += counts[c - 1];
        }
        let mut fill = counts.clone();
        self.ids.resize(pts.len(), 0);
        for (k, &p) in pts.iter().enumerate() {
            let c = cell(p);
            self.ids[fill[c]] = k;
            fill[c] += 1;
        }
        self.starts = counts;
    }

    /// Index of the point nearest to `p`, ties to the lower index.
    fn nearest(&self, pts: &[DVec2], p: DVec2) -> usize {
        let g = self.g as isize;
        let ci = ((p.x * g as f64) as isize).min(g - 1);
        let cj = ((p.y * g as f64) as isize).min(g - 1);
        let cell_w = 1.0 / g as f64;
        let mut best = (f64::INFINITY, usize::MAX);
        // Search rings of cells until the ring's distance exceeds the best found.
        for ring in 0..=g {
            if ring > 0 {
                let ring_dist = (ring - 1) as f64 * cell_w;
                if ring_dist * ring_dist > best.0 {
                    break;
                }
            }
            for dj in -ring..=ring {
                for di in -ring..=ring {
                    if di.abs() != ring && dj.abs() != ring {
                        continue;
                    }
                    let (i, j) = (ci + di, cj + dj);
                    if i < 0 || j < 0 || i >= g || j >= g {
                        continue;
                    }
                    let c = (j * g + i) as usize;
                    for &k in &self.ids[self.starts[c]..self.starts[c + 1]] {
                        let d2 = pts[k].distance_squared(p);
                        if d2 < best.0 || (d2 == best.0 && k < best.1) {
                            best = (d2, k);
                        }
                    }
                }
            }
        }
        best.1
    }
}

/// Id of the nearest of `points` at every cell centre of a `g`×`g` raster of the unit square
/// (the planar Voronoi diagram as a lookup grid).
pub fn voronoi_raster(points: &[DVec2], g: usize) -> Vec<u16> {
    assert!(points.len() <= u16::MAX as usize + 1);
    let mut index = NearestIndex::default();
    index.rebuild(points);
    let mut out = Vec::with_capacity(g * g);
    for j in 0..g {
        for i in 0..g {
            let p = DVec2::new((i as f64 + 0.5) / g as f64, (j as f64 + 0.5) / g as f64);
            out.push(index.nearest(points, p) as u16);
        }
    }
    out
}

/// Smallest pairwise distance among `pts` (brute force; for tests and diagnostics).
pub fn min_pairwise_distance(pts: &[DVec2]) -> f64 {
    let mut best = f64::INFINITY;
    for i in 0..pts.len() {
        for j in i + 1..pts.len() {
            best = best.min(pts[i].distance(pts[j]));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halton_starts_at_index_one() {
        let h = halton(4);
        assert_eq!(h[0], DVec2::new(0.5, 1.0 / 3.0));
        assert_eq!(h[1], DVec2::new(0.25, 2.0 / 3.0));
        assert_eq!(h[2], DVec2::new(0.75, 1.0 / 9.0));
    }

    #[test]
    fn every_power_of_two_prefix_beats_halton() {
        let relaxed = progressive_points();
        let plain = halton(N_MAX);
        let mut n = 2;
        while n <= N_MAX {
            let r = min_pairwise_distance(&relaxed[..n]);
            let h = min_pairwise_distance(&plain[..n]);
            assert!(r > h, "prefix {n}: relaxed {r} vs Halton {h}");
            n *= 2;
        }
        for p in relaxed {
            assert!(
                p.x > 0.0 && p.x < 1.0 && p.y > 0.0 && p.y < 1.0,
                "{p} on the boundary"
            );
        }
    }

    /// Regenerate with `VEMLIGHT_BLESS=1 cargo test --release embedded_set`.
    #[test]
    fn embedded_set_matches_recomputation() {
        let fresh = relaxed_halton(N_MAX);
        if std::env::var_os("VEMLIGHT_BLESS").is_some() {
            let path = concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/src/sampling/pointset-1024.bin"
            );
            std::fs::write(path, encode_points(&fresh)).expect("write the point set");
        }
        assert!(
            decode_points(EMBEDDED) == fresh,
            "stale pointset-1024.bin: regenerate it (see the doc comment)"
        );
    }

    #[test]
    fn deterministic() {
        assert_eq!(relaxed_halton(64), relaxed_halton(64));
        // A prefix of a larger set is the smaller set: blocks never look at later points.
        assert_eq!(&relaxed_halton(128)[..64], &relaxed_halton(64)[..]);
    }
}
