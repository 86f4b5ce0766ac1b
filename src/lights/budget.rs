//! What a stream's client can afford (docs/API.md, `GET /v1/stream`): the fewest lights that meet
//! an error target ([`AdaptiveCount`], `max_error=E`), and a shadow budget ([`mark`],
//! [`remainder_sh`], `shadowed=K`): of a set's lights, the K most worth a shadow map are marked
//! `shadowed`, and the rest are also given as L2 SH (`sh9_unshadowed`), so a client can draw K
//! shadowed lights plus an ambient SH term and still hold the map's energy.
//!
//! The marks follow the lights' contributions ([`worth`]: luminance of their irradiance, weighted
//! toward lights from above) with hysteresis: a marked light keeps its mark until an unmarked one outshines it by
//! [`SWAP_RATIO`], so two lights of nearly equal power do not trade a shadow map every frame.

use super::light::Light;
use super::sh;

/// An adaptive stream steps down to the next smaller count only when that count's estimated
/// error has been at most this fraction of the target for [`STEP_DOWN_FRAMES`] frames in a row,
/// and steps up as soon as its error exceeds the target: the count does not flap between two
/// counts whose errors straddle the target.
pub const STEP_DOWN_MARGIN: f64 = 0.8;
/// See [`STEP_DOWN_MARGIN`]: one second at 30 frames/s.
pub const STEP_DOWN_FRAMES: u32 = 30;

/// The light count of a stream with an error target: the fewest lights, at most `max`, whose
/// estimated diffuse error (ALGORITHMS.md §8) meets the target, held with hysteresis from frame
/// to frame. The counts it moves between are those of [`count_ladder`].
#[derive(Clone, Debug)]
pub struct AdaptiveCount {
    max: usize,
    target: f64,
    /// The count served now; 0 before the first frame.
    count: usize,
    /// Frames in a row in which the next smaller count met the target with margin.
    smaller_met: u32,
}

impl AdaptiveCount {
    pub fn new(max: usize, target: f64) -> Self {
        AdaptiveCount {
            max,
            target,
            count: 0,
            smaller_met: 0,
        }
    }

    /// The counts the next frame must extract (and estimate the error of): the count served and
    /// the next smaller one, or on the first frame every count of the ladder.
    pub fn counts_needed(&self) -> Vec<usize> {
        let ladder = self.ladder();
        if self.count == 0 {
            return ladder;
        }
        let i = self.position();
        let mut out = vec![self.count];
        if i > 0 {
            out.push(ladder[i - 1]);
        }
        out
    }

    /// Takes this frame's error estimates (`error(n)` for each count of
    /// [`counts_needed`](Self::counts_needed)) and returns the count to serve now and its error.
    /// A step up takes effect from the next frame, which extracts the larger count.
    pub fn update(&mut self, error: impl Fn(usize) -> Option<f64>) -> (usize, Option<f64>) {
        let ladder = self.ladder();
        if self.count == 0 {
            // The first frame: the fewest that meet the target, as a single map would.
            self.count = *ladder
                .iter()
                .find(|&&n| error(n).is_some_and(|e| e <= self.target))
                .unwrap_or(&self.max);
            return (self.count, error(self.count));
        }
        let served = self.count;
        let i = self.position();
        let now = error(served);
        if now.is_some_and(|e| e > self.target) && i + 1 < ladder.len() {
            self.smaller_met = 0;
            self.count = ladder[i + 1];
        } else if i > 0 && error(ladder[i - 1]).is_some_and(|e| e <= STEP_DOWN_MARGIN * self.target)
        {
            self.smaller_met += 1;
            if self.smaller_met >= STEP_DOWN_FRAMES {
                self.smaller_met = 0;
                self.count = ladder[i - 1];
                return (self.count, error(self.count));
            }
        } else {
            self.smaller_met = 0;
        }
        (served, now)
    }

    /// The count served now (0 before the first frame).
    pub fn count(&self) -> usize {
        self.count
    }

    fn ladder(&self) -> Vec<usize> {
        count_ladder(self.max)
    }

    fn position(&self) -> usize {
        self.ladder()
            .iter()
            .position(|&n| n == self.count)
            .unwrap_or(0)
    }
}

/// The light counts a stream's error target moves between ([`AdaptiveCount`]), and the first
/// counts a single map's search tries ([`fewest_meeting`]), at most `max`: the powers of two
/// below it, then `max`.
pub fn count_ladder(max: usize) -> Vec<usize> {
    let mut out: Vec<usize> = std::iter::successors(Some(1usize), |n| Some(n * 2))
        .take_while(|&n| n < max)
        .collect();
    out.push(max);
    out
}

/// What [`fewest_meeting`] found: the count, what `run` gave for it and its error.
#[derive(Clone, Debug)]
pub struct Fewest<T> {
    pub count: usize,
    pub value: T,
    pub error: f64,
    /// Whether `error` meets the target (false only when not even `max` lights do).
    pub met: bool,
}

/// The fewest lights, at most `max`, whose error meets `target` (`vemlight lights --max-error`,
/// `POST /v1/lights?max_error`): `run(n)` extracts n lights and estimates their error. The
/// ladder of powers of two ([`count_ladder`]) finds the first count that meets the target, then
/// halving the gap between it and the power below, which did not, finds the fewest between (about
/// log₂ of the gap more extractions). The estimate falls with the count nearly everywhere but not
/// strictly, so what is certain is that the count returned meets the target and one light fewer
/// does not (a smaller count untried might). A
/// stream keeps to the ladder ([`AdaptiveCount`]): each count it serves is a set of lights
/// followed frame to frame, and fewer, coarser steps change it less often.
pub fn fewest_meeting<T>(
    max: usize,
    target: f64,
    mut run: impl FnMut(usize) -> (T, f64),
) -> Fewest<T> {
    let mut missed = 0;
    let mut found = None;
    for n in count_ladder(max.max(1)) {
        let (value, error) = run(n);
        let met = error <= target;
        if met || n >= max {
            found = Some(Fewest {
                count: n,
                value,
                error,
                met,
            });
            break;
        }
        missed = n;
    }
    let mut best = found.expect("the ladder ends at max");
    if !best.met {
        return best;
    }
    while best.count - missed > 1 {
        let n = missed + (best.count - missed) / 2;
        let (value, error) = run(n);
        if error <= target {
            best = Fewest {
                count: n,
                value,
                error,
                met: true,
            };
        } else {
            missed = n;
        }
    }
    best
}

/// An unmarked light takes a marked one's place only when it is worth this much more.
pub const SWAP_RATIO: f64 = 1.25;

/// How much a shadow map for `light` is worth: its luminance, weighted by (1 + y)/2, the mean
/// clamped cosine it gives surfaces facing up and sideways relative to one facing it (a floor, a
/// table, the tops and sides of objects: what a client shadows). A light from below the horizon
/// (bounce from the ground) lights little of that and is mostly hidden by the floor, so the sun
/// and the bright sky come first.
pub fn worth(light: &Light) -> f64 {
    light.luminance() * (1.0 + light.dir().y).max(0.0) * 0.5
}

/// Marks `k` of `lights` (`shadowed = Some(true)`, the others `Some(false)`): the ids of
/// `previous` that are still present first, filled with the brightest, then swapped while an
/// unmarked light is worth [`SWAP_RATIO`] times the least marked one. Returns the ids
/// marked, for the next set.
pub fn mark(lights: &mut [Light], k: usize, previous: &[u32]) -> Vec<u32> {
    let k = k.min(lights.len());
    // Indices by contribution, largest first (ties by id, so the order is deterministic).
    let mut order: Vec<usize> = (0..lights.len()).collect();
    order.sort_by(|&a, &b| {
        worth(&lights[b])
            .total_cmp(&worth(&lights[a]))
            .then(lights[a].id.cmp(&lights[b].id))
    });
    let mut marked: Vec<usize> = order
        .iter()
        .copied()
        .filter(|&i| previous.contains(&lights[i].id))
        .take(k)
        .collect();
    for &i in &order {
        if marked.len() >= k {
            break;
        }
        if !marked.contains(&i) {
            marked.push(i);
        }
    }
    // Swap while the best unmarked light is worth SWAP_RATIO times the least marked one.
    while let (Some(at), Some(&best)) = (
        (0..marked.len())
            .min_by(|&a, &b| worth(&lights[marked[a]]).total_cmp(&worth(&lights[marked[b]]))),
        order.iter().find(|i| !marked.contains(i)),
    ) {
        if worth(&lights[best]) > SWAP_RATIO * worth(&lights[marked[at]]) {
            marked[at] = best;
        } else {
            break;
        }
    }
    for (i, l) in lights.iter_mut().enumerate() {
        l.shadowed = Some(marked.contains(&i));
    }
    let mut ids: Vec<u32> = marked.iter().map(|&i| lights[i].id).collect();
    ids.sort_unstable();
    ids
}

/// The L2 radiance SH (27 floats, the layout of `sh9`) of the map less the lights marked
/// shadowed: `sh9 − Σ_shadowed irradiance_k · Y(to_light_k)`, each marked light taken as a
/// delta of its region's energy, which its region's projection approaches at L2 when the region
/// is small (a sun, a lamp: what is worth a shadow map).
pub fn remainder_sh(sh9: &[f32], lights: &[Light]) -> Vec<f32> {
    let mut out: Vec<f64> = sh9.iter().map(|&c| c as f64).collect();
    for l in lights.iter().filter(|l| l.shadowed == Some(true)) {
        let y = sh::basis(l.dir());
        for (k, yk) in y.iter().enumerate() {
            for c in 0..3 {
                out[3 * k + c] -= l.irradiance[c] as f64 * yk;
            }
        }
    }
    out.into_iter().map(|c| c as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With an error that falls as 1/n, the search finds exactly the fewest count, trying the
    /// ladder up to the first power that meets the target and then about log₂ of the gap.
    #[test]
    fn the_fewest_count_that_meets_a_falling_error() {
        for (max, fewest) in [
            (256, 37),
            (256, 33),
            (256, 64),
            (256, 65),
            (100, 100),
            (64, 1),
        ] {
            let target = 1.0 / fewest as f64;
            let mut tried = Vec::new();
            let f = fewest_meeting(max, target, |n| {
                tried.push(n);
                (n, 1.0 / n as f64)
            });
            assert_eq!(
                (f.count, f.value, f.met),
                (fewest, fewest, true),
                "{tried:?}"
            );
            assert_eq!(f.error, target);
            let ladder = count_ladder(max)
                .iter()
                .take_while(|&&n| n < fewest)
                .count()
                + 1;
            let gap = fewest.next_power_of_two().min(max) - fewest.next_power_of_two() / 2;
            let most = ladder + (usize::BITS - gap.leading_zeros()) as usize;
            assert!(tried.len() <= most, "{} tries: {tried:?}", tried.len());
            // Each count is extracted once.
            let mut unique = tried.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(unique.len(), tried.len(), "{tried:?}");
        }
    }

    /// Where not even `max` lights meet the target, `max` is returned, marked unmet.
    #[test]
    fn the_cap_when_no_count_meets_the_target() {
        let f = fewest_meeting(48, 1e-6, |n| (n, 1.0 / n as f64));
        assert_eq!((f.count, f.met), (48, false));
        assert_eq!(f.error, 1.0 / 48.0);
    }

    /// An error that does not fall everywhere (as a real estimate may not): the count returned
    /// meets the target, one fewer was tried and misses it, as does every smaller count tried.
    #[test]
    fn a_count_that_meets_the_target_where_the_error_is_not_monotone() {
        // Falls as 1/n, with every third count raised by half.
        let error = |n: usize| (1.0 + 0.5 * f64::from(n.is_multiple_of(3))) / n as f64;
        for target in [0.1, 0.03, 0.02, 0.011, 0.007] {
            let mut tried = Vec::new();
            let f = fewest_meeting(256, target, |n| {
                tried.push(n);
                (n, error(n))
            });
            assert!(f.met && error(f.count) <= target, "{target}: {f:?}");
            // One light fewer was tried, and missed.
            assert!(f.count == 1 || tried.contains(&(f.count - 1)), "{tried:?}");
            for &n in tried.iter().filter(|&&n| n < f.count) {
                assert!(
                    error(n) > target,
                    "{target}: {n} met it, {} returned",
                    f.count
                );
            }
            // No worse than the ladder alone.
            let ladder = count_ladder(256)
                .into_iter()
                .find(|&n| error(n) <= target)
                .unwrap();
            assert!(f.count <= ladder, "{target}: {} > {ladder}", f.count);
        }
    }

    fn light(id: u32, lum: f32, dir: [f32; 3]) -> Light {
        Light {
            id,
            to_light: dir,
            irradiance: [lum; 3],
            solid_angle: 0.01,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        }
    }

    fn set(lums: &[f32]) -> Vec<Light> {
        lums.iter()
            .enumerate()
            .map(|(i, &y)| light(i as u32, y, [0.0, 1.0, 0.0]))
            .collect()
    }

    /// Errors halving with each doubling of the count, as a smooth map gives: 8 % at one light.
    fn halving(n: usize) -> Option<f64> {
        Some(0.08 / n as f64)
    }

    #[test]
    fn the_first_frame_takes_the_fewest_lights_that_meet_the_target() {
        let mut a = AdaptiveCount::new(64, 0.01);
        assert_eq!(a.counts_needed(), vec![1, 2, 4, 8, 16, 32, 64]);
        assert_eq!(a.update(halving), (8, Some(0.01)));
        assert_eq!(a.counts_needed(), vec![8, 4]);
        // Nothing meets it: the most allowed.
        let mut b = AdaptiveCount::new(48, 1e-6);
        assert_eq!(b.counts_needed(), vec![1, 2, 4, 8, 16, 32, 48]);
        assert_eq!(b.update(halving).0, 48);
    }

    #[test]
    fn the_count_steps_up_at_once_and_down_only_after_a_second_of_margin() {
        let mut a = AdaptiveCount::new(64, 0.01);
        a.update(halving);
        // The map gets harder: 8 lights miss; the next frame serves 16.
        let harder = |n: usize| Some(0.2 / n as f64);
        assert_eq!(a.update(harder).0, 8);
        assert_eq!(a.count(), 16);
        assert_eq!(a.update(harder).0, 16);
        assert_eq!(a.count(), 32);
        // Easier again: 16 meets 0.8 × target, but only after STEP_DOWN_FRAMES frames in a row.
        let easier = |n: usize| Some(0.08 / n as f64);
        for _ in 0..STEP_DOWN_FRAMES - 1 {
            assert_eq!(a.update(easier).0, 32);
        }
        assert_eq!(a.update(easier).0, 16);
        // An error that hovers at the target (between 0.8 E and E at the smaller count) never
        // steps down, and one frame just over the margin restarts the wait.
        let mut b = AdaptiveCount::new(64, 0.01);
        b.update(halving);
        let hover = |n: usize| Some(if n == 4 { 0.0085 } else { 0.009 });
        for _ in 0..10 * STEP_DOWN_FRAMES {
            assert_eq!(b.update(hover).0, 8);
        }
    }

    #[test]
    fn the_brightest_k_are_marked_first() {
        let mut lights = set(&[1.0, 5.0, 3.0, 0.5, 4.0]);
        let ids = mark(&mut lights, 2, &[]);
        assert_eq!(ids, vec![1, 4]);
        let marked = lights.iter().filter(|l| l.shadowed == Some(true)).count();
        assert_eq!(marked, 2);
        assert!(lights.iter().all(|l| l.shadowed.is_some()));
    }

    #[test]
    fn a_mark_is_kept_until_another_light_outshines_it_by_the_swap_ratio() {
        // Light 2 was marked; light 4 is brighter, but by less than the ratio: 2 keeps it.
        let mut lights = set(&[1.0, 5.0, 3.0, 0.5, 3.6]);
        assert_eq!(mark(&mut lights, 2, &[1, 2]), vec![1, 2]);
        // Past the ratio (3.0 × 1.25 = 3.75), light 4 takes it.
        let mut lights = set(&[1.0, 5.0, 3.0, 0.5, 3.8]);
        assert_eq!(mark(&mut lights, 2, &[1, 2]), vec![1, 4]);
        // A marked id that is gone is replaced by the brightest unmarked.
        let mut lights = set(&[1.0, 5.0]);
        assert_eq!(mark(&mut lights, 2, &[7, 1]), vec![0, 1]);
    }

    #[test]
    fn light_from_below_the_horizon_is_worth_less() {
        // Ground bounce twice as bright as a sky patch, from 37° below the horizon: the sky
        // patch gets the one shadow map.
        let mut lights = vec![
            light(0, 2.0, [0.0, -0.6, 0.8]),
            light(1, 1.0, [0.0, 0.6, 0.8]),
        ];
        assert_eq!(mark(&mut lights, 1, &[]), vec![1]);
        assert!((worth(&lights[1]) - 0.8 * lights[1].luminance()).abs() < 1e-6);
    }

    #[test]
    fn more_marks_than_lights_marks_them_all() {
        let mut lights = set(&[1.0, 2.0]);
        assert_eq!(mark(&mut lights, 5, &[]), vec![0, 1]);
        let mut none = set(&[1.0, 2.0]);
        assert!(mark(&mut none, 0, &[]).is_empty());
        assert!(none.iter().all(|l| l.shadowed == Some(false)));
    }

    /// SH of the marked lights plus the remainder is the whole: the irradiance RH01 gives at any
    /// normal from `sh9` equals the marked lights' clamped-cosine sum plus the remainder's SH
    /// irradiance, up to the L2 truncation of the marked deltas (tested here with the remainder
    /// of a map made of the same deltas, where it is exact: the remainder is the unmarked ones).
    #[test]
    fn the_remainder_is_the_sh_of_the_unmarked_lights() {
        let dirs = [
            [0.0, 1.0, 0.0],
            [0.6, 0.8, 0.0],
            [0.0, 0.0, -1.0],
            [-0.48, 0.6, 0.64],
        ];
        let mut lights: Vec<Light> = dirs
            .iter()
            .enumerate()
            .map(|(i, &d)| light(i as u32, 1.0 + i as f32, d))
            .collect();
        let project = |ls: &[Light]| {
            let mut c = vec![0.0f32; 27];
            for l in ls {
                for (k, y) in sh::basis(l.dir()).iter().enumerate() {
                    for ch in 0..3 {
                        c[3 * k + ch] += (l.irradiance[ch] as f64 * y) as f32;
                    }
                }
            }
            c
        };
        let whole = project(&lights);
        mark(&mut lights, 2, &[]);
        let rest: Vec<Light> = lights
            .iter()
            .copied()
            .filter(|l| l.shadowed == Some(false))
            .collect();
        let expected = project(&rest);
        let got = remainder_sh(&whole, &lights);
        for (g, e) in got.iter().zip(&expected) {
            assert!((g - e).abs() < 1e-5, "{got:?} vs {expected:?}");
        }
        // The DC term is the energy: the remainder holds exactly the unmarked lights' share.
        let dc = |c: &[f32]| c[0] as f64 / 0.282_094_791;
        let unmarked: f64 = rest.iter().map(|l| l.irradiance[0] as f64).sum();
        assert!((dc(&got) - unmarked).abs() < 1e-4);
    }
}
