//! Light power and direction: a domain image → a set of directional lights.
//!
//! Input: an [`EnvMap`] (resampled here into the equal-area [`DomainImage`]). Output: [`Light`]s whose
//! irradiance sums exactly to ∫L dω over the domain (DESIGN.md), plus the L2 SH and the primary light.
//! Methods (ALGORITHMS.md §4, §7):
//! - [`Method::Voronoi`] (default): lights seeded at the warped progressive points, every texel's
//!   energy given to the nearest light on the sphere, each light moved to its cell's
//!   luminance-weighted centroid;
//! - [`Method::Paper`]: lights at the warped points, energy from the Voronoi cells of the fixed
//!   points in the unit square (HSKMS05 as described);
//! - [`Method::MedianCut`]: Debevec 2005 on a lat-long map, the baseline;
//! - [`Method::InverseCdf`]: the discontinuous textbook inverse CDF (pbrt-v3 `Distribution2D` on the
//!   lat-long map) with the same fixed points and the same spherical cells as the default: only
//!   the warp differs, so it measures what bicontinuity buys (baseline, ALGORITHMS.md §7).

pub mod budget;
pub mod error;
pub mod inverse_cdf;
pub mod kmeans;
mod light;
pub mod median_cut;
pub mod sh;
pub mod shadow;
pub mod sun_shadow;
mod tilt;
pub mod vmlps;

use light::{ANGLE_BINS, angle_bin};
pub use light::{
    Light, LightExtent, PRIMARY_CLUSTER_DEG, PrimaryLight, angular_radius, core_rest_radius,
    horizon_gap, primary_light, total_irradiance,
};

use crate::envmap::EnvMap;
use crate::mapping::Domain;
use crate::sampling::pointset::voronoi_raster;
use crate::sampling::{Distribution2D, DomainImage, N_MAX, Resampler, progressive_points};
use error::IrradianceReference;
use glam::{DVec3, Vec3};
use multiversion::multiversion;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::time::Instant;

/// How lights are computed from a map.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
#[value(rename_all = "kebab-case")]
pub enum Method {
    /// Spherical Voronoi cells around the warped progressive points (our default, ALGORITHMS.md §4).
    #[default]
    #[value(
        alias = "default",
        help = "spherical Voronoi cells of the warped points (the default)"
    )]
    Voronoi,
    /// The paper's variant: Voronoi cells of the fixed points in the warped unit square.
    #[value(help = "the paper's cells in the warped unit square")]
    Paper,
    /// Debevec's median cut on a lat-long map (baseline, ALGORITHMS.md §7).
    #[value(alias = "mediancut", help = "Debevec's median cut (baseline)")]
    MedianCut,
    /// The discontinuous inverse CDF on the lat-long map (pbrt-v3 `Distribution2D`), same fixed
    /// points; lights then exactly as [`Method::Voronoi`] (nearest light on the sphere, centroid).
    /// Baseline, ALGORITHMS.md §7.
    #[value(alias = "inversecdf", help = "the lat-long inverse CDF (baseline)")]
    InverseCdf,
    /// Converged spherical k-means (Kollig & Keller 2003), k-means++ seeds: the practical floor of
    /// the unshadowed diffuse error (ALGORITHMS.md §10). A baseline: slow, ids not stable.
    #[value(
        alias = "kmeans",
        help = "converged spherical k-means, the diffuse floor (baseline; slow, single maps only)"
    )]
    KMeans,
    /// Variance-minimising cuts (Viriyothai & Debevec 2009, ALGORITHMS.md §10). A baseline, ids
    /// not stable.
    #[value(help = "variance-minimising cuts (baseline)")]
    Vmlps,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Voronoi => "voronoi",
            Method::Paper => "paper",
            Method::MedianCut => "median-cut",
            Method::InverseCdf => "inverse-cdf",
            Method::KMeans => "k-means",
            Method::Vmlps => "vmlps",
        }
    }

    /// Every method, the default first.
    pub const ALL: [Method; 6] = [
        Method::Voronoi,
        Method::Paper,
        Method::MedianCut,
        Method::InverseCdf,
        Method::Vmlps,
        Method::KMeans,
    ];

    /// The methods fast enough for a video stream (k-means iterates to convergence).
    pub const STREAMING: [Method; 5] = [
        Method::Voronoi,
        Method::Paper,
        Method::MedianCut,
        Method::InverseCdf,
        Method::Vmlps,
    ];

    /// Whether light id k is the same progressive point in every frame.
    pub fn ids_are_stable(self) -> bool {
        !matches!(self, Method::MedianCut | Method::KMeans | Method::Vmlps)
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    /// The names `--method` takes (and the query parameter `method=`), aliases included.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        <Method as clap::ValueEnum>::from_str(s, false).map_err(|_| {
            format!(
                "unknown method '{s}' (expected voronoi, paper, median-cut, inverse-cdf, vmlps or k-means)"
            )
        })
    }
}

/// What to extract.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtractOptions {
    pub lights: usize,
    pub domain: Domain,
    pub method: Method,
    /// Side of the domain square; `None` = chosen from the source resolution.
    pub side: Option<usize>,
}

/// The result of one extraction, before it is wrapped into a LightSet document.
#[derive(Clone, Debug)]
pub struct Extraction {
    pub lights: Vec<Light>,
    /// ∫ L dω over the domain (equals Σ irradiance).
    pub total: [f64; 3],
    pub side: usize,
    pub timings: StageTimings,
}

/// What one [`Extractor::extract_frame`] call computes from a frame's domain image.
#[derive(Clone, Copy, Debug)]
pub struct FrameRequest<'a> {
    pub method: Method,
    /// Light counts, each extracted from the same image.
    pub counts: &'a [usize],
    /// Whether to project the L2 SH (the LightSet's `sh9`) as well.
    pub sh9: bool,
}

/// What [`Extractor::extract_frame`] gives: one extraction per count asked for, in that order.
#[derive(Clone, Debug)]
pub struct FrameLights {
    pub extractions: Vec<Extraction>,
    pub sh9: Option<Vec<f32>>,
    /// Seconds spent on the SH.
    pub sh9_s: f64,
}

/// Wall-clock time of each stage, in seconds.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimings {
    pub resample_s: f64,
    pub warp_s: f64,
    pub assign_s: f64,
}

/// Smallest side of the half-resolution image the Lloyd steps run on; below it they run at full
/// resolution.
const MIN_COARSE_SIDE: usize = 16;

/// Whether `image` has a half-resolution copy (even side, at least twice [`MIN_COARSE_SIDE`]).
fn has_coarse_copy(image: &DomainImage) -> bool {
    image.side.is_multiple_of(2) && image.side >= 2 * MIN_COARSE_SIDE
}

/// Makes `half` the half-resolution copy of `image` unless `current` says it already is: the
/// Lloyd steps and `sh9` share one downsampling per frame.
fn refresh_half(image: &DomainImage, half: &mut DomainImage, current: &mut bool) {
    if !*current {
        image.downsample_into(half);
        *current = true;
    }
}

/// Lloyd steps the voronoi method takes after its first assignment unless told otherwise (see
/// [`Extractor::set_refine`]): two, the fewest with which its diffuse error is at most median
/// cut's at every N ≥ 16 and its glossy error at every N ≥ 64 (docs/EVALUATION.md).
pub const DEFAULT_REFINE: usize = 2;

/// Turns maps into lights, keeping every table and buffer between frames so that a video stream of
/// same-sized maps allocates nothing per frame in the hot loop.
pub struct Extractor {
    /// The resampler and image of [`extract`](Extractor::extract) and
    /// [`extract_many`](Extractor::extract_many), which resample the map themselves.
    resampler: Option<Resampler>,
    own_image: DomainImage,
    dist: Distribution2D,
    grid: Option<CandidateGrid>,
    /// The Lloyd steps' half-resolution image and its grid (see `assign_spherical`).
    half_image: DomainImage,
    /// Whether `half_image` is the half-resolution copy of the current `image`.
    half_is_current: bool,
    half_grid: Option<CandidateGrid>,
    paper_cells: HashMap<usize, Vec<u16>>,
    seeds: Vec<Vec3>,
    accum: Vec<CellAccum>,
    /// Each cell's rest (its texels outside its core) by angle about its centroid,
    /// [`ANGLE_BINS`] per cell, and the centroids: the lights' radii (ALGORITHMS.md §12, "Core
    /// and rest").
    rest_bins: Vec<f32>,
    centroids: Vec<DVec3>,
    median_cut: median_cut::MedianCut,
    /// Extra Lloyd steps of the voronoi method (0: the one step of ALGORITHMS.md §4).
    refine: usize,
    inverse_cdf: inverse_cdf::InverseCdf,
    /// How the voronoi method shapes its warp's density; `None`: by [`Placement::for_lights`].
    placement: Option<Placement>,
    /// The warp's density per texel (the luminance reshaped by `placement`).
    density: Vec<f32>,
    /// The light each texel went to in the last full-resolution assignment (for the repair of
    /// lights left without energy).
    owner: Vec<u16>,
    /// The same for the half-resolution image of the Lloyd steps (for the swap rounds).
    half_owner: Vec<u16>,
    kmeans: kmeans::KMeans,
    vmlps: vmlps::Vmlps,
    /// Video mode (see [`set_video`](Self::set_video)): the default method starts each frame's
    /// Lloyd steps from the previous frame's lights of the same count, domain and side.
    video: bool,
    previous: HashMap<(usize, Domain, usize), Vec<Vec3>>,
    /// Each light's tilt in the previous frame of a stream, as its elevation's change (radians),
    /// by the same key as `previous`.
    previous_tilt: HashMap<(usize, Domain, usize), StreamTilt>,
    /// Where `warp_seeds` took the current seeds from (it decides the Lloyd steps).
    seed_origin: SeedOrigin,
    /// How far a light may move in one frame of video mode.
    tracking: VideoTracking,
    /// The lights' moves toward their centroids in the current frame (radians), and a copy to
    /// take their median from; reused.
    moves: Vec<f32>,
    moves_scratch: Vec<f32>,
    /// Swap rounds of a single map's Lloyd steps (see [`set_swap_rounds`](Self::set_swap_rounds)).
    swap_rounds: usize,
    /// Whether a single map's lights are also made without the swap rounds and the better kept
    /// (see [`set_unswapped_check`](Self::set_unswapped_check)).
    unswapped_check: bool,
    /// Whether a single map also starts from the warps of [`other_starts`] (see
    /// [`set_other_starts`](Self::set_other_starts)).
    other_starts: bool,
    /// Whether a single map's lights are tilted toward the horizon ([`Extractor::set_tilt`]).
    tilt: bool,
    /// Whether a single map splits a compact core off its cell ([`Extractor::set_core_split`]).
    core_split: bool,
    /// Whether a single map's compact cores' lights turn in azimuth onto their core
    /// ([`Extractor::set_core_azimuth`]).
    core_azimuth: bool,
    /// Whether a single map's sun casts its shadow from the source pixels
    /// ([`Extractor::set_sun_shadow`]).
    sun_shadow: bool,
    /// Whether a stream's lights are tilted as a single map's are ([`Extractor::set_stream_tilt`]).
    stream_tilt: bool,
    /// Whether a single map of many lights takes Lloyd steps until its energy settles
    /// ([`Extractor::set_converge`]).
    converge: bool,
    /// A stream frame's lights before the tilt, which the next frame starts from (the tilt is
    /// what a client is given, not where the cells are tracked).
    untilted: Option<Vec<Vec3>>,
}

/// How far a light of the default method may move in one frame of video mode (ALGORITHMS.md
/// §4.3; the measured choice is in docs/EVALUATION.md, "Video mode still jumped").
///
/// A light moves from last frame's direction toward its cell's new centroid by at most
/// `max_step_deg`, and is reported where it stopped: when a dim light loses the edge of a compact
/// source to a neighbour, its centroid swings across its large cell within a frame or two (a
/// k-means fixed point vanishing), and the cap spreads that swing over frames. Two exceptions keep
/// the lights on their energy: a light carrying a share s of the frame's luminance stops at most
/// `lag_budget / s` degrees short of its centroid (a light that takes over a lamp switched on goes
/// to it at once), and the cap is at least `follow_factor` × the median of all lights' moves (a
/// fast turn of the whole map is followed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoTracking {
    /// Largest step toward its centroid a light takes in one frame, degrees; infinite: none.
    pub max_step_deg: f32,
    /// Share of the frame's luminance × degrees a light may be left short of its centroid.
    pub lag_budget: f32,
    /// The cap is at least this × the median of the lights' moves to their centroids.
    pub follow_factor: f32,
}

impl VideoTracking {
    /// Every light goes to its centroid each frame (one plain Lloyd step).
    pub const UNLIMITED: VideoTracking = VideoTracking {
        max_step_deg: f32::INFINITY,
        lag_budget: 0.0,
        follow_factor: 0.0,
    };
}

impl Default for VideoTracking {
    fn default() -> Self {
        VideoTracking {
            max_step_deg: 3.0,
            lag_budget: 0.03,
            follow_factor: 2.0,
        }
    }
}

/// Where a frame's seeds came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SeedOrigin {
    /// The warp of the fixed points (a single map, or a baseline): `refine` Lloyd steps.
    Warp,
    /// The warp, as the first frame of a video stream: [`VIDEO_START_STEPS`] steps, so the stream
    /// starts near its steady state.
    StreamStart,
    /// The previous frame's lights (video mode): one full-resolution step.
    LastFrame,
}

/// Swap rounds a single map's lights take after their Lloyd steps (ALGORITHMS.md §4.2, "Swaps"),
/// up to [`SWAP_MAX_LIGHTS`] lights: the largest worst-map gain per millisecond measured
/// (docs/EVALUATION.md "Swaps").
pub const SWAP_ROUNDS: usize = 4;
/// How much lower the `--max-error` reference must estimate a single map's lights made without
/// the swap rounds for them to replace the swapped ones (ALGORITHMS.md §4.2, "Swaps"). The swap
/// rounds were kept for their worst case over many maps on the sphere, and that reference errs
/// by several per cent itself (7 % on pm-lab's final lights): with no margin two sphere cases
/// were replaced by lights with more shadowed error (EVALUATION.md, "The upper hemisphere").
const UNSWAPPED_MARGIN: f64 = 0.1;

/// Above this many lights the swap rounds are skipped: a poor basin costs little there (every map
/// within 1.1 × the k-means floor at 256 lights without them) and a round costs the most.
pub const SWAP_MAX_LIGHTS: usize = 64;

/// The density exponent of a single map's second start (ALGORITHMS.md §4.2, "Starts"): Y^½, the
/// density converged k-means places its centres by, beside the default's Y^0.625.
pub const SECOND_START_EXPONENT: f32 = 0.5;

/// Two more starts, one on each side of the first two, up to [`MORE_STARTS_MAX_LIGHTS`] lights
/// (ALGORITHMS.md §4.2, "Starts").
pub const MORE_START_EXPONENTS: [f32; 2] = [0.375, 0.75];

/// The most lights that take [`MORE_START_EXPONENTS`]: the estimate that chooses between starts
/// has at least 32 of its `CHECK_GRID`² bins per light there. At 64 lights (16 bins a light) a
/// third start lowered the median error but twice chose a start that was 1.3 × worse.
pub const MORE_STARTS_MAX_LIGHTS: usize = CHECK_GRID * CHECK_GRID / 32;

/// The third start of a single map of more than [`MORE_STARTS_MAX_LIGHTS`] and at most
/// [`SWAP_MAX_LIGHTS`] lights (ALGORITHMS.md §4.2, "Starts"): Y¹ (capped), the paper's importance,
/// beside the Y^¾ of [`Placement::for_lights`] and Y^½. With it, chosen on the finer
/// 48² estimate (`WIDE_CHECK_GRID`), no map of tests/data or the hard skies, as they are or turned,
/// was left over median cut's shadowed error at 64 lights (three were), and the diffuse error fell.
pub const WIDE_START_EXPONENT: f32 = 1.0;

/// The starts of a single map of more than [`SWAP_MAX_LIGHTS`] and at most `STEPS_MAX_LIGHTS`
/// lights beside the Y^¾ of [`Placement::for_lights`] (ALGORITHMS.md §4.2, "Starts"): one on each
/// side. Chosen on the 48² estimate, they took the worst diffuse error at 128 lights over the 13
/// maps and the 18 held out from 1.27 to 1.18 × k-means (studio.exr 1.15 → 0.87); Y^½ and Y^⅝
/// instead left it at 1.29.
pub const STEPS_START_EXPONENTS: [f32; 2] = [0.625, 0.875];

/// The starts of a single map of `n` lights after the default's own (ALGORITHMS.md §4.2).
fn other_starts(n: usize) -> &'static [f32] {
    const FEW: [f32; 3] = [
        SECOND_START_EXPONENT,
        MORE_START_EXPONENTS[0],
        MORE_START_EXPONENTS[1],
    ];
    const MANY: [f32; 2] = [SECOND_START_EXPONENT, WIDE_START_EXPONENT];
    match n {
        0..=MORE_STARTS_MAX_LIGHTS => &FEW,
        _ if n <= SWAP_MAX_LIGHTS => &MANY,
        _ if n <= STEPS_MAX_LIGHTS => &STEPS_START_EXPONENTS,
        _ => &[],
    }
}

/// A single map of more than [`SWAP_MAX_LIGHTS`] and at most [`STEPS_MAX_LIGHTS`] lights takes
/// this many times the Lloyd steps asked for (ALGORITHMS.md §4.2, "Steps"): it has no swaps to
/// leave a poor fixed point, and at 128 lights two more half-resolution steps took
/// night.exr turned 200° from 1.28 to 1.03 × the k-means floor for 0.2 ms. At 256 a step costs
/// 0.18 ms, and the default is level with median cut's time there.
const STEPS_FACTOR: usize = 2;
/// The most lights that take the starts of [`STEPS_START_EXPONENTS`] and [`STEPS_FACTOR`] times
/// the steps: the 48² estimate that chooses between them has at least 12 bins a light up to here
/// (18 at 128). Measured at 128 first; at 129 and 192 lights, where a lone Y^⅞ start was the
/// rule, studio.exr was 1.60 and 1.45 × the k-means floor and a held-out warehouse 1.34 × at 129;
/// with the three starts the worst of the 13 maps and the 18 held out went to 1.10 and 1.13 ×
/// (EVALUATION.md, "Counts between the powers of two"). At 256 (9 bins a light) the estimate
/// chose starts that were worse in truth (a low hazy sun 0.65 → 0.95 ×), so above this a single
/// map keeps one start.
const STEPS_MAX_LIGHTS: usize = WIDE_CHECK_GRID * WIDE_CHECK_GRID / 12;

/// A single map of more than [`STEPS_MAX_LIGHTS`] lights whose last Lloyd step asked for still
/// lowered the k-means energy P − |M| (ALGORITHMS.md §10) by this fraction or more is far from its
/// fixed point, and takes more steps (ALGORITHMS.md §4.2, "Steps"). At 256 lights the second
/// step lowers it by 4–18 % on the hard skies and 29 of the 31 real maps; by 23 % on night.exr
/// and studio.exr, and by 26–63 % on studios of large, even softboxes, where the warp's Y^⅞
/// crowds the boxes and two steps left the diffuse error at up to 1.73 × the k-means floor
/// (EVALUATION.md, "Steps until the energy settles").
const CONVERGE_TRIGGER: f64 = 0.2;
/// The further steps stop once one lowers the energy by less than this fraction.
const CONVERGE_TOLERANCE: f64 = 0.02;
/// The most Lloyd steps a single map of more than [`STEPS_MAX_LIGHTS`] lights takes in all.
const CONVERGE_MAX_STEPS: usize = 8;

/// A single map of more lights than this splits its brightest cell (ALGORITHMS.md §4.2,
/// "Split"). At 65–128 lights the split's second light cut a 60° sun along the domain's texels
/// into two or three lights whose discs left its penumbra lopsided: 4 of 72 synthetic skies over
/// median cut's shadowed error at 128 lights (worst 1.48 ×), none without it; turned 37°, 3 → 2
/// (worst 1.21 → 1.25 ×); on the 13 maps and the 18 held out, each turned four ways, 1 → 0
/// (EVALUATION.md, "The split from 129 lights").
const SPLIT_ABOVE_LIGHTS: usize = 128;
/// The least share of the brightest cell's luminance a neighbouring cell on the same source
/// must hold for the split to leave that source alone ([`Extractor::source_is_shared`]): near
/// halves. At a quarter, a sun cut 2 : 1 was left so, where the third light evens the cut (the
/// clear and very hazy 60° suns turned 37°: 0.73 → 0.97 and 0.92 → 1.12 × median cut's
/// shadowed error at 256 lights).
const SPLIT_SHARED_SHARE: f64 = 0.75;
/// The widest disc, degrees, of the two halves [`Extractor::source_is_shared`] looks for: a source
/// within a domain texel or two, whose cells the texels cut, not the source. Without it, two
/// neighbouring cells of a softbox (1.4° discs, held-out pm-studio) or of a bright overcast
/// (4°, pm-venice) went unsplit at 256 lights: 1.22 → 1.27 × k-means' diffuse error and
/// 0.86 → 1.02 × median cut's shadowed error.
const SPLIT_SHARED_MAX_DEG: f64 = 1.0;

/// The diffuse error that decides between starts is estimated from the map binned into
/// `CHECK_GRID`² emitters (first moments kept, so the error is second order in the bin size) at
/// `CHECK_NORMALS` Fibonacci normals: the irradiance is smooth, and the starts it tells apart
/// differ by tens of percent where it matters.
const CHECK_GRID: usize = 32;
const CHECK_NORMALS: usize = 128;

/// The bins of the estimate that chooses between the starts of more than
/// [`MORE_STARTS_MAX_LIGHTS`] lights: 36 a light at 64 lights (18 at 128), where the 32² grid's
/// 16 a light chose between the three starts no better than between two (two maps over median
/// cut's shadowed error at 64 lights against none, ALGORITHMS.md §4.2, "Starts"). The tilt keeps
/// the 32² estimate it was measured with.
const WIDE_CHECK_GRID: usize = 48;

/// The most lights a single map tilts (ALGORITHMS.md §4.2, "Tilt"): the reference's bins stand
/// for points too, with an excess of their own that grows with their size, and it is small
/// beside the lights' only while a bin is at most an eighth of a light's cell. With 256 lights
/// the 32² reference (at 64 normals) chose tilts that raised the true diffuse error on five maps,
/// and the floor rule's tilt left overcast's shadowed miss in place while raising studio's error.
const TILT_MAX_LIGHTS: usize = CHECK_GRID * CHECK_GRID / 8;

/// The most lights a single map tilts on the [`WIDE_CHECK_GRID`]² reference (its bins an eighth
/// of a light's cell again, up to 288 lights), above [`TILT_MAX_LIGHTS`] (ALGORITHMS.md §4.2,
/// "Tilt").
const WIDE_TILT_MAX_LIGHTS: usize = WIDE_CHECK_GRID * WIDE_CHECK_GRID / 8;

/// The largest fraction of the way a set of more than [`TILT_MAX_LIGHTS`] lights tilts. At 256
/// lights the whole way let through tilts that raised the true diffuse error by up to 5 % (studio.exr
/// 1.02 → 1.07 × k-means, a held-out studio 1.19 → 1.25 ×), which the 48² estimate did not
/// see; half the way took the same shadowed miss away (a held-out square, 1.21 → 0.86 × median
/// cut's) and left the diffuse error of the 13 maps, turned four ways, where it was.
const WIDE_TILT_MAX_FRACTION: f64 = 0.5;

/// A light tilts only if its core's spread 1 − |M|/P (ALGORITHMS.md §12) is at least this share
/// of its whole cell's (the spread goes as the radius squared: the core at least 0.7 of the
/// cell's radius). A single light on an 8° disc in a dim sky, a core a third of its cell's spread,
/// otherwise moved 0.3° off the disc; on tests/data, shares of 0.25 and 0.5 tilt the same lights.
const TILT_CORE_SHARE: f64 = 0.5;

/// The least share of its cell a core holds for its light to turn onto the core's azimuth
/// (ALGORITHMS.md §4.2, "Core azimuth"): a core holding less is a lamp in a wide glow, whose
/// light stands for the glow as much.
const CORE_AZIMUTH_MIN_SHARE: f64 = 0.5;

/// How much the turns onto cores' azimuths may raise the estimated diffuse error. Unguarded they
/// raised the true error of a 9° sun through haze and cloud at 32 lights from 1.00 to 1.70 ×
/// k-means; 2 % kept none of the turns that took 60° suns at 16 and 32 lights from 1.9 to 0.5 ×
/// median cut's shadowed error, 6 % kept those (EVALUATION.md, "Core azimuth").
const CORE_AZIMUTH_ALLOWANCE: f64 = 0.06;

/// The most lights whose cores turn onto their azimuth. With more, a sun's cell holds little
/// beside it and the turns did harm: on the 13 maps turned four ways, three over median cut's
/// shadowed error at 64 lights (a clear high sun turned 200°, 0.88 → 1.41 ×) and the worst
/// diffuse ratio at 256 lights 1.05 → 1.25 × k-means (EVALUATION.md, "Core azimuth").
const CORE_AZIMUTH_MAX_LIGHTS: usize = 32;

/// The binned reference a single map's choices are made by (the starts up to
/// [`MORE_STARTS_MAX_LIGHTS`] lights, the tilt; above, the starts take [`WIDE_CHECK_GRID`]): the
/// domain square (its half-resolution copy, the same bins' energies and moments from a quarter of
/// the texels) binned `CHECK_GRID`² at [`CHECK_NORMALS`] normals.
fn check_reference(image: &DomainImage) -> IrradianceReference {
    check_reference_at(image, CHECK_GRID)
}

/// [`check_reference`] binned `grid`².
fn check_reference_at(image: &DomainImage, grid: usize) -> IrradianceReference {
    IrradianceReference::from_domain_image_at(image, grid, error::fibonacci_sphere(CHECK_NORMALS))
}

/// Lloyd steps of the first frame of a video stream (see [`Extractor::set_video`]): the later
/// frames carry on from it, and with only the usual two steps the first frames' lights still
/// travel 5–17° a frame toward the fixed point.
pub const VIDEO_START_STEPS: usize = 32;

/// How far a stream light's tilt may change in one frame (ALGORITHMS.md §4.3, "Tilt in a
/// stream"): the fraction a single map takes is chosen in eighths, and from one frame to the
/// next it may jump an eighth or switch between descending and rising.
pub const STREAM_TILT_STEP_DEG: f32 = 0.5;

/// How many frames of a stream take the tilt's fraction chosen in the first of them (ALGORITHMS.md
/// §4.3, "Tilt in a stream"): choosing it takes the binned estimate, the larger part of the
/// tilt's cost, and the step limit lets a light's tilt change only slowly anyway.
pub const STREAM_TILT_CHOOSE_EVERY: u32 = 8;

/// The fraction of the way a set tilted (ALGORITHMS.md §4.2, "Tilt"), and which way.
#[derive(Clone, Copy, Debug)]
struct TiltChoice {
    fraction: f64,
    descending: bool,
}

/// The map's own floor irradiance ∫ L·max(0, ω_y) dω as a share of its energy, from the texels'
/// moments (a half-size image holds means: the same share).
fn floor_share(image: &DomainImage) -> f64 {
    let (up, all) = image
        .moment
        .iter()
        .zip(&image.luminance)
        .fold((0.0f64, 0.0f64), |(u, a), (m, &y)| {
            (u + m[1].max(0.0) as f64, a + y as f64)
        });
    if all > 0.0 { up / all } else { 0.0 }
}

/// A stream's tilt in its last frame: each light's, as its elevation's change (radians), the
/// fraction the set took, and how many frames that fraction has served (at
/// [`STREAM_TILT_CHOOSE_EVERY`] or more, the next frame chooses afresh).
struct StreamTilt {
    tilts: Vec<f32>,
    choice: Option<TiltChoice>,
    age: u32,
}

/// The elevation of a unit direction above the horizon, radians.
fn elevation(d: Vec3) -> f32 {
    d.y.clamp(-1.0, 1.0).asin()
}

/// `d` at elevation `e` (radians), its azimuth kept; a direction without one (a pole) as it is.
fn at_elevation(d: Vec3, e: f32) -> Vec3 {
    let Some(h) = glam::Vec2::new(d.x, d.z).try_normalize() else {
        return d;
    };
    let (s, c) = e.sin_cos();
    Vec3::new(h.x * c, s, h.y * c)
}

/// How the default method turns luminance into the density its progressive points are warped by
/// (ALGORITHMS.md §4, design; the measured choice is in docs/EVALUATION.md "Placement").
///
/// The density is Y^`exponent`, water-filled at a cap so that no texel expects more than
/// `max_seeds_per_texel` of the N seeds: a compact source (the sun covers a quarter of a texel)
/// then gets a light of its own instead of tens of seeds that share one texel and leave all but
/// one light without energy, and the budget it would have taken goes to its surroundings (the
/// glare that a shadow needs resolved) and to the rest of the sky. The cap level solves
/// C = c·Σ_t min(d_t, C)/N (continuous in the data, so the warp stays continuous over a video).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub exponent: f32,
    pub max_seeds_per_texel: f32,
    /// A share of uniform density mixed in (d + β·mean d): bounds how fast a point warped into a
    /// dark region moves when the data change (its speed is ∝ 1/density), so a seed in a dark
    /// corner cannot swing across it between frames.
    pub uniform_share: f32,
}

impl Default for Placement {
    fn default() -> Self {
        Placement {
            exponent: 0.625,
            max_seeds_per_texel: 0.5,
            uniform_share: 0.1,
        }
    }
}

impl Placement {
    /// A single map's placement for `n` lights (ALGORITHMS.md §4.1, "By count"): the default up
    /// to [`MORE_STARTS_MAX_LIGHTS`], where four starts choose among exponents; Y^¾ without the
    /// uniform share up to `STEPS_MAX_LIGHTS` (192, with two more starts above 64), and Y^⅞
    /// above. With more lights a steeper density does better: on the 13 maps as they are and
    /// turned three ways, the geometric mean ratio to the k-means floor went 0.99 → 0.95 at 64 lights, 0.93 → 0.83 at 128 and 0.97 → 0.76 at 256, the worst
    /// 1.17 → 1.13, 1.21 → 1.19 and 1.33 → 1.05, and the worst shadowed ratio at 64 from 1.82 to
    /// 1.34 × median cut's, at 256 from 1.41 to 1.03 (docs/EVALUATION.md "By count"). The uniform
    /// share bounds how fast a seed crosses a dark region between frames; a single map has none.
    pub fn for_lights(n: usize) -> Placement {
        match n {
            0..=MORE_STARTS_MAX_LIGHTS => Placement::default(),
            _ if n <= STEPS_MAX_LIGHTS => Placement {
                exponent: 0.75,
                uniform_share: 0.0,
                ..Placement::default()
            },
            _ => Placement {
                exponent: 0.875,
                uniform_share: 0.0,
                ..Placement::default()
            },
        }
    }

    /// `density` = `luminance` reshaped for `n` seeds (see [`Placement`]).
    pub fn density(&self, luminance: &[f32], n: usize, density: &mut Vec<f32>) {
        density.clear();
        let e = self.exponent;
        // Exponents in eighths (the swept ones) by square roots, which vectorise; powf does not.
        let eighths = e * 8.0;
        if eighths.fract() == 0.0 && (1.0..=8.0).contains(&eighths) {
            match eighths as u32 {
                1 => eighth_powers::<1>(luminance, density),
                2 => eighth_powers::<2>(luminance, density),
                3 => eighth_powers::<3>(luminance, density),
                4 => eighth_powers::<4>(luminance, density),
                5 => eighth_powers::<5>(luminance, density),
                6 => eighth_powers::<6>(luminance, density),
                7 => eighth_powers::<7>(luminance, density),
                _ => eighth_powers::<8>(luminance, density),
            }
        } else {
            density.extend(luminance.iter().map(|&y| clean_luminance(y).powf(e)));
        }
        if self.uniform_share > 0.0 && !density.is_empty() {
            let mean = sum_f64(density) / density.len() as f64;
            let add = (self.uniform_share as f64 * mean) as f32;
            for d in density.iter_mut() {
                *d += add;
            }
        }
        let c = self.max_seeds_per_texel as f64;
        if c <= 0.0 || n == 0 {
            return;
        }
        let nf = n as f64;
        // g(C) = c·S(C)/N − C with S(C) = Σ min(d, C): concave, g(0) = 0; Newton from the right
        // converges monotonically to its positive root.
        let total = sum_f64(density);
        let max = max_f32(density, 0.0);
        if total <= 0.0 || c * total / nf >= max as f64 {
            return; // no texel over the cap
        }
        // The root is at most c·D/N (S ≤ D). Texels below a floor an eighth of that enter S(C)
        // whole while C stays above the floor, so the Newton passes run over the few texels above
        // it (the bright ones); should the root fall below the floor, every texel takes part.
        let floor = (c * total / nf / 8.0) as f32;
        let bright: Vec<f32> = density.iter().copied().filter(|&d| d > floor).collect();
        let base = total - bright.iter().map(|&d| d as f64).sum::<f64>();
        let mut cap = max as f64;
        for _ in 0..64 {
            let (values, mut s) = if cap > floor as f64 {
                (&bright[..], base)
            } else {
                (&density[..], 0.0)
            };
            let mut above = 0usize;
            let cf = cap as f32;
            for &d in values {
                if d > cf {
                    above += 1;
                    s += cap;
                } else {
                    s += d as f64;
                }
            }
            let g = c * s / nf - cap;
            let slope = c * above as f64 / nf - 1.0;
            if g >= -1e-9 * cap || slope >= 0.0 {
                break;
            }
            let next = cap - g / slope;
            if next.is_nan() || next <= 0.0 || next >= cap {
                break;
            }
            cap = next;
        }
        let cf = cap as f32;
        for d in density.iter_mut() {
            *d = d.min(cf);
        }
    }
}

/// A luminance as a density's input: NaN, infinities and negatives count as 0.
fn clean_luminance(y: f32) -> f32 {
    // Two comparisons (false for NaN), which vectorise as a select.
    if y > 0.0 && y <= f32::MAX { y } else { 0.0 }
}

/// `density` = clean(`luminance`)^(K/8), by products of the first three square roots; K is a
/// constant so that the loop has no branch and vectorises. Compiled twice, as [`assign_texels`].
#[multiversion(targets("x86_64+avx2+fma"))]
fn eighth_powers<const K: u32>(luminance: &[f32], density: &mut Vec<f32>) {
    density.resize(luminance.len(), 0.0);
    for (d, &y) in density.iter_mut().zip(luminance) {
        *d = eighth_power::<K>(clean_luminance(y));
    }
}

/// y^(K/8) for a clean (finite, non-negative) luminance.
fn eighth_power<const K: u32>(y: f32) -> f32 {
    if K == 8 {
        return y;
    }
    let s1 = y.sqrt();
    let s2 = s1.sqrt();
    let s3 = s2.sqrt();
    let mut v = 1.0;
    if K & 4 != 0 {
        v *= s1;
    }
    if K & 2 != 0 {
        v *= s2;
    }
    if K & 1 != 0 {
        v *= s3;
    }
    v
}

/// Σ `values` in f64, in eight lanes: every term is added in f64 as a sequential sum's would be,
/// only the order differs, and the loop vectorises (LLVM keeps a float sum's order, so one running
/// sum does not).
fn sum_f64(values: &[f32]) -> f64 {
    let mut lanes = [0.0f64; 8];
    let chunks = values.chunks_exact(8);
    let tail: f64 = chunks.remainder().iter().map(|&v| v as f64).sum();
    for c in chunks {
        for (l, &v) in lanes.iter_mut().zip(c) {
            *l += v as f64;
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// The largest of `values` (at least `floor`), in eight lanes, so that the loop vectorises.
fn max_f32(values: &[f32], floor: f32) -> f32 {
    let mut lanes = [floor; 8];
    let chunks = values.chunks_exact(8);
    let tail = chunks
        .remainder()
        .iter()
        .fold(floor, |m, &v| if v > m { v } else { m });
    for c in chunks {
        for (l, &v) in lanes.iter_mut().zip(c) {
            *l = if v > *l { v } else { *l };
        }
    }
    lanes.iter().fold(tail, |m, &v| if v > m { v } else { m })
}

/// How far lit texel `t` lies from a cell's centroid direction `centre`, as its share of the
/// cell's k-means energy, Y·(1 − cos) = Y − M·c (ALGORITHMS.md §4.2, "Swaps"); `None` when unlit.
fn farness(image: &DomainImage, t: usize, centre: DVec3) -> Option<f64> {
    let y = image.luminance[t] as f64;
    (y > 0.0).then(|| y - Vec3::from_array(image.moment[t]).as_dvec3().dot(centre))
}

/// Per-light sums over its cell.
#[derive(Clone, Copy, Debug, Default)]
struct CellAccum {
    energy: DVec3,
    /// Σ luminance moment: f64, because the angular radius of a compact cell (the sun's is
    /// 1 − |M|/P ≈ 10⁻⁵) is a difference of nearly equal sums.
    weighted_dir: DVec3,
    /// Σ luminance over the cell (the P of ALGORITHMS.md §12).
    lum: f64,
    /// Texels whose nearest seed this is.
    texels: u32,
    /// The cell's brightest texel luminance, and P and |M| over its core (the texels of at least
    /// [`CORE_FRACTION`] of it), for the angular radius and the tilt.
    peak: f32,
    core_lum: f64,
    core_moment: DVec3,
    /// Σ radiance over the core (the colour of a core split off as a light of its own).
    core_energy: DVec3,
}

impl CellAccum {
    /// The cell's k-means energy P − |M| (ALGORITHMS.md §10): what one light standing for it
    /// costs, and so where a light without energy helps most.
    fn spread(&self) -> f64 {
        self.lum - self.weighted_dir.length()
    }

    /// Adds texel `t` of `image` to the cell's sums (the core's are a second pass, once the
    /// cell's peak is known: [`add_core_texel`](Self::add_core_texel)).
    #[inline(always)]
    fn add_texel(&mut self, image: &DomainImage, t: usize) {
        let y = image.luminance[t];
        self.energy += Vec3::from_array(image.radiance[t]).as_dvec3();
        self.weighted_dir += Vec3::from_array(image.moment[t]).as_dvec3();
        self.lum += y as f64;
        self.peak = self.peak.max(y);
        self.texels += 1;
    }

    /// Adds texel `t` to the core's sums if it is in the core (at least `fraction` of the
    /// cell's peak: [`CORE_FRACTION`] or [`STREAM_CORE_FRACTION`]).
    #[inline(always)]
    fn add_core_texel(&mut self, image: &DomainImage, t: usize, fraction: f32) -> bool {
        let y = image.luminance[t];
        let core = self.in_core(y, fraction);
        if core {
            self.core_lum += y as f64;
            self.core_moment += Vec3::from_array(image.moment[t]).as_dvec3();
            self.core_energy += Vec3::from_array(image.radiance[t]).as_dvec3();
        }
        core
    }

    /// Whether a texel of luminance `y` belongs to the cell's core: lit and at least `fraction`
    /// of the cell's peak.
    #[inline(always)]
    fn in_core(&self, y: f32, fraction: f32) -> bool {
        y > 0.0 && y >= fraction * self.peak
    }

    /// Whether the cell's core is compact in it: its spread 1 − |M|/P under [`TILT_CORE_SHARE`]
    /// of the whole cell's (a sun in its glare, a lamp), which the tilt leaves alone and the core
    /// azimuth turns (ALGORITHMS.md §4.2). False for an empty cell or core.
    fn core_is_compact(&self) -> bool {
        let spread = |p: f64, m: DVec3| 1.0 - m.length() / p;
        spread(self.core_lum, self.core_moment)
            < TILT_CORE_SHARE * spread(self.lum, self.weighted_dir)
    }

    /// Whether the cell could spare a texel to a light without energy.
    fn can_donate(&self) -> bool {
        self.lum > 0.0 && self.texels >= 2
    }
}

/// Light counts (with their domain and side) whose last lights video mode keeps at most.
const MAX_VIDEO_COUNTS: usize = 32;

/// Texels of at least this fraction of their cell's peak luminance form the cell's core: its
/// moments give the disc of a compact bright source (a sun in its glare, a lamp) inside a texel,
/// beside the rest of the cell binned by angle (ALGORITHMS.md §12, "Core and rest"); and the tilt
/// leaves a light whose core is compact in a wider cell alone (§4.2, "Tilt"; `TILT_CORE_SHARE`).
pub const CORE_FRACTION: f32 = 0.25;

/// The core's fraction of its cell's peak in a stream (ALGORITHMS.md §12, "The core in a
/// stream"). The sun (0.53°) lies on up to 2 × 2 texels of about 1° in shares that change as it
/// moves; with [`CORE_FRACTION`] up to a fifth of it fell out of the core on some frames, and the
/// light's two-part extent came and went. A tenth leaves out at most 9 % (f/(1 + f)). A single
/// map keeps the quarter its core split and core azimuth, which a stream does not take, were
/// tuned on.
pub const STREAM_CORE_FRACTION: f32 = 0.1;

/// The widest core split off its cell (ALGORITHMS.md §12, "Core split"), degrees.
const CORE_SPLIT_MAX_DEG: f32 = 2.0;
/// How much wider than its core a cell's rest must be for the split.
const CORE_SPLIT_WIDER: f32 = 4.0;
/// The least share of its cell the rest must hold for the split.
const CORE_SPLIT_MIN_REST: f64 = 0.2;
/// How much the split may raise the estimated diffuse error (the light given up costs it): on
/// night.exr at 16 lights an unguarded split took the true error from 1.06 to 1.29 × k-means.
const CORE_SPLIT_ALLOWANCE: f64 = 0.05;
/// The most lights that split a core: above, the gain measured was within 1 % (the geometric
/// mean over 66 turned maps at 256 lights) and the extra assignment costs the 256-light map's
/// time, which is held to median cut's.
const CORE_SPLIT_MAX_LIGHTS: usize = TILT_MAX_LIGHTS;
/// The light counts at which a core lying aside of its light is also split (ALGORITHMS.md §12,
/// "Core aside"), whatever share of its cell the rest holds. Measured at 4, 16 and 32 lights: at
/// 16 it mended shadowed misses on the synthetic skies; at 32 it mended none and put three skies
/// over 1.25 × k-means' diffuse error; at 4 (the eval's client budget) it took the low clear sun's
/// shadowed error from 11 % to 21 %, one light of four given up. Counts between are not measured.
const CORE_ASIDE_LIGHTS: std::ops::RangeInclusive<usize> = 16..=16;
/// How much that split may raise the estimated diffuse error: the one light of 16 given up costs
/// 10–25 % of it, and the worst sky of the sweep turned 37°, a 35° sun through haze and cloud,
/// needs 17 % (1.99 → 0.45 × median cut's shadowed error, 1.13 → 1.36 × k-means' diffuse).
const CORE_ASIDE_ALLOWANCE: f64 = 0.2;

impl Default for Extractor {
    fn default() -> Self {
        Extractor {
            resampler: None,
            own_image: DomainImage::empty(),
            dist: Distribution2D::default(),
            grid: None,
            half_image: DomainImage::empty(),
            half_is_current: false,
            half_grid: None,
            paper_cells: HashMap::new(),
            seeds: Vec::new(),
            accum: Vec::new(),
            rest_bins: Vec::new(),
            centroids: Vec::new(),
            median_cut: Default::default(),
            refine: DEFAULT_REFINE,
            inverse_cdf: Default::default(),
            placement: None,
            density: Vec::new(),
            owner: Vec::new(),
            half_owner: Vec::new(),
            kmeans: Default::default(),
            vmlps: Default::default(),
            video: false,
            previous: HashMap::new(),
            previous_tilt: HashMap::new(),
            seed_origin: SeedOrigin::Warp,
            tracking: VideoTracking::default(),
            moves: Vec::new(),
            moves_scratch: Vec::new(),
            swap_rounds: SWAP_ROUNDS,
            unswapped_check: true,
            other_starts: true,
            tilt: true,
            core_split: true,
            core_azimuth: true,
            sun_shadow: true,
            stream_tilt: true,
            converge: true,
            untilted: None,
        }
    }
}

impl Extractor {
    pub fn new() -> Self {
        Self::default()
    }

    /// Extra Lloyd steps for [`Method::Voronoi`] (default [`DEFAULT_REFINE`]): after the first
    /// assignment, re-seed each light at its centroid and assign again, `steps` times. Each step
    /// costs one more assignment pass; two is the fewest with which the diffuse error is at most
    /// median cut's at every N ≥ 16 (docs/EVALUATION.md, docs/PERFORMANCE.md). A single map of 65
    /// to 192 lights takes twice as many (`STEPS_FACTOR`).
    pub fn set_refine(&mut self, steps: usize) {
        self.refine = steps.min(8);
    }

    /// Swap rounds of a single map's default lights, up to [`SWAP_MAX_LIGHTS`] lights (default
    /// [`SWAP_ROUNDS`]; 0: none, and no split above that count either). A stream's later frames
    /// take none: a swap is a jump.
    pub fn set_swap_rounds(&mut self, rounds: usize) {
        self.swap_rounds = rounds;
    }

    /// Whether a single map's default lights of up to [`SWAP_MAX_LIGHTS`] are also made without
    /// the swap rounds, and those kept where the `--max-error` reference estimates them at least
    /// 10 % better (ALGORITHMS.md §4.2, "Swaps"; default on).
    pub fn set_unswapped_check(&mut self, on: bool) {
        self.unswapped_check = on;
    }

    /// A single map of at most `STEPS_MAX_LIGHTS` default lights also starts from other warps
    /// (`other_starts`): up to [`MORE_STARTS_MAX_LIGHTS`] by Y^[`SECOND_START_EXPONENT`] and
    /// [`MORE_START_EXPONENTS`], up to [`SWAP_MAX_LIGHTS`] by Y^[`SECOND_START_EXPONENT`] and
    /// Y^[`WIDE_START_EXPONENT`], above that by [`STEPS_START_EXPONENTS`]; each start takes the
    /// same Lloyd steps and swap rounds, and the one whose lights' diffuse error (estimated from
    /// the reduced map, as for `--max-error`) is lowest goes on to the final assignment
    /// (ALGORITHMS.md §4.2, "Starts"; default on). `false`: one start. Streams start once.
    pub fn set_other_starts(&mut self, on: bool) {
        self.other_starts = on;
    }

    /// Whether a single map's default lights above the horizon are tilted toward it by the
    /// fraction that lowers the estimated diffuse error (ALGORITHMS.md §4.2, "Tilt"; default on).
    /// Streams take none.
    pub fn set_tilt(&mut self, tilt: bool) {
        self.tilt = tilt;
    }

    /// The draw of converged k-means' seeding generator (`Method::KMeans`; default 0, the
    /// evaluation's floor), see [`kmeans::KMeans::set_draw`].
    pub fn set_kmeans_draw(&mut self, draw: u64) {
        self.kmeans.set_draw(draw);
    }

    /// Whether a single map's default lights split a compact core (a sun, a lamp) in a wider
    /// cell off as a light of its own, the light cheapest to merge giving way (ALGORITHMS.md
    /// §12, "Core split"; default on). Streams split none.
    pub fn set_core_split(&mut self, split: bool) {
        self.core_split = split;
    }

    /// Whether a single map's light of a compact core (a sun, a lamp) holding most of its cell
    /// turns about the vertical onto its core's azimuth, its elevation kept, after the tilt
    /// (ALGORITHMS.md §4.2, "Core azimuth"; default on, up to 32 lights). Streams turn none.
    pub fn set_core_azimuth(&mut self, on: bool) {
        self.core_azimuth = on;
    }

    /// Whether a single map's brightest compact light casts its shadow from the centroid of the
    /// source pixels around it, carried in its extent's core ([`sun_shadow`]; ALGORITHMS.md §12,
    /// "Shadow direction"; default on). Streams keep their lights' own directions.
    pub fn set_sun_shadow(&mut self, on: bool) {
        self.sun_shadow = on;
    }

    /// Whether a stream's lights are tilted toward the floor they should give, as a single map's
    /// are (ALGORITHMS.md §4.3, "Tilt in a stream"); the next frame starts from the untilted ones.
    pub fn set_stream_tilt(&mut self, on: bool) {
        self.stream_tilt = on;
    }

    /// Whether a single map of more than 192 lights whose Lloyd steps still lower the k-means
    /// energy fast takes more of them, up to eight in all (ALGORITHMS.md §4.2, "Steps"; default
    /// on). Streams take their own steps.
    pub fn set_converge(&mut self, on: bool) {
        self.converge = on;
    }

    /// Video mode, for a stream of frames of one scene (the daemon, the temporal evaluation): the
    /// default method seeds each frame with the previous frame's lights of the same count instead
    /// of warping the fixed points afresh, and takes one full-resolution Lloyd step from them, so
    /// that each light follows what its cell holds and moves only as far as that moves. Warping
    /// afresh, a lamp that slides from one row of the warp's conditional CDFs to the next drags
    /// the points of that row across it (the warp is continuous but far from smooth there), and
    /// light ids jump tens of degrees in one frame (ALGORITHMS.md §11). How far a light may move
    /// in one frame is [`VideoTracking`]'s to say (see [`Self::set_video_tracking`]).
    /// A steady scene converges toward a k-means fixed point (ALGORITHMS.md §10), one step a
    /// frame. The first frame, and any frame of another size or count, starts from the warp and
    /// takes [`VIDEO_START_STEPS`] Lloyd steps.
    pub fn set_video(&mut self, video: bool) {
        self.video = video;
        if !video {
            self.previous.clear();
            self.previous_tilt.clear();
        }
    }

    /// How far a light may move in one frame of video mode (see [`VideoTracking`]).
    pub fn set_video_tracking(&mut self, tracking: VideoTracking) {
        self.tracking = tracking;
    }

    /// The fraction of its cell's peak a texel needs to be in the cell's core: a stream's
    /// ([`STREAM_CORE_FRACTION`], its first frame included) or a single map's ([`CORE_FRACTION`]).
    fn core_fraction(&self) -> f32 {
        if self.seed_origin == SeedOrigin::Warp {
            CORE_FRACTION
        } else {
            STREAM_CORE_FRACTION
        }
    }

    /// The density the voronoi method warps its points by (see [`Placement`]), in place of
    /// [`Placement::for_lights`].
    pub fn set_placement(&mut self, placement: Placement) {
        self.placement = Some(placement);
    }

    /// The placement of `n` seeds: the one set, or a single map's by its count; a stream's first
    /// frame takes the default's (its later frames follow their lights).
    fn placement_for(&self, n: usize) -> Placement {
        match self.placement {
            Some(p) => p,
            None if self.seed_origin == SeedOrigin::Warp => Placement::for_lights(n),
            None => Placement::default(),
        }
    }

    /// Extracts lights from one map: resamples it into the domain square (the table is cached
    /// between calls for maps of one size and projection), then [`extract_frame`](Self::extract_frame).
    pub fn extract(&mut self, map: &EnvMap, opts: &ExtractOptions) -> Extraction {
        let (image, resample_s) = self.resample_own(map, opts.domain, opts.side);
        let mut frame = self.extract_frame(
            map,
            &image,
            &FrameRequest {
                method: opts.method,
                counts: &[opts.lights],
                sh9: false,
            },
        );
        self.own_image = image;
        let mut ex = frame
            .extractions
            .pop()
            .expect("one count asked, one extraction");
        ex.timings.resample_s = resample_s;
        ex
    }

    /// Several light counts from one map (see [`extract_frame`](Self::extract_frame)), resampled
    /// here at the side chosen from its resolution. Results are in the order of `counts`.
    pub fn extract_many(
        &mut self,
        map: &EnvMap,
        domain: Domain,
        method: Method,
        counts: &[usize],
    ) -> Vec<Extraction> {
        let (image, resample_s) = self.resample_own(map, domain, None);
        let frame = self.extract_frame(
            map,
            &image,
            &FrameRequest {
                method,
                counts,
                sh9: false,
            },
        );
        self.own_image = image;
        let mut out = frame.extractions;
        for ex in &mut out {
            ex.timings.resample_s = resample_s;
        }
        out
    }

    /// Resamples `map` into a new domain image for [`extract_frame`](Self::extract_frame), with
    /// the extractor's cached table (kept between calls for maps of one size and projection).
    pub fn resample(&mut self, map: &EnvMap, domain: Domain, side: Option<usize>) -> DomainImage {
        Resampler::reuse(&mut self.resampler, map, domain, side, 1).resample(map)
    }

    /// Resamples `map` into the extractor's own image (for [`extract`](Self::extract) and
    /// [`extract_many`](Self::extract_many)), which the caller hands back after use.
    fn resample_own(
        &mut self,
        map: &EnvMap,
        domain: Domain,
        side: Option<usize>,
    ) -> (DomainImage, f64) {
        let t0 = Instant::now();
        let r = Resampler::reuse(&mut self.resampler, map, domain, side, 1);
        let mut image = std::mem::replace(&mut self.own_image, DomainImage::empty());
        r.resample_into(map, &mut image);
        (image, t0.elapsed().as_secs_f64())
    }

    /// The one extraction call: lights for each of `req.counts` (and, if asked, the L2 SH) from
    /// `image`, the domain image of `map` (resampled by the caller: the daemon resamples a frame on
    /// its capture thread as the frame arrives). The counts share the frame's work: the seeds of N
    /// lights are the first N of the seeds of the largest count (ALGORITHMS.md §4), so the paper
    /// and inverse-CDF warps run once, and the half-resolution image of the Lloyd steps and the SH
    /// is made once. Results are in the order of `req.counts`; `resample_s` is 0 in their timings.
    pub fn extract_frame(
        &mut self,
        map: &EnvMap,
        image: &DomainImage,
        req: &FrameRequest,
    ) -> FrameLights {
        // A new image: its half-resolution copy is made again when first needed.
        self.half_is_current = false;
        let max_n = req
            .counts
            .iter()
            .copied()
            .max()
            .unwrap_or(1)
            .clamp(1, N_MAX);
        let total = image.integral();
        let mut warp_s = 0.0;
        // The paper and inverse-CDF warps do not depend on N: one warp serves every count. The
        // default's density is capped for its N (see `Placement`), so it warps per count.
        let shared_warp = matches!(req.method, Method::Paper | Method::InverseCdf);
        if shared_warp {
            let t = Instant::now();
            self.warp_seeds(map, image, req.method, max_n);
            warp_s = t.elapsed().as_secs_f64();
        }
        let all_seeds = std::mem::take(&mut self.seeds);
        let extractions = req
            .counts
            .iter()
            .map(|&n| {
                let n = n.clamp(1, N_MAX);
                let mut timings = StageTimings {
                    warp_s,
                    ..StageTimings::default()
                };
                let lights = if shared_warp {
                    let t = Instant::now();
                    self.seeds.clear();
                    self.seeds.extend_from_slice(&all_seeds[..n]);
                    let l = self.assign_seeds(image, req.method);
                    timings.assign_s = t.elapsed().as_secs_f64();
                    l
                } else if req.method == Method::Voronoi {
                    let t = Instant::now();
                    self.warp_seeds(map, image, req.method, n);
                    timings.warp_s = t.elapsed().as_secs_f64();
                    let t = Instant::now();
                    let mut l = self.assign_seeds(image, req.method);
                    if self.sun_shadow && self.seed_origin == SeedOrigin::Warp {
                        sun_shadow::aim_sun_shadow(map, &mut l);
                    }
                    timings.assign_s = t.elapsed().as_secs_f64();
                    l
                } else {
                    let t = Instant::now();
                    let l = self.lights_for(map, image, req.method, n);
                    timings.assign_s = t.elapsed().as_secs_f64();
                    l
                };
                Extraction {
                    lights,
                    total,
                    side: image.side,
                    timings,
                }
            })
            .collect();
        self.seeds = all_seeds;
        let t = Instant::now();
        let sh9 = req.sh9.then(|| self.sh9(image));
        FrameLights {
            extractions,
            sh9,
            sh9_s: t.elapsed().as_secs_f64(),
        }
    }

    /// L2 radiance SH of `image` (see [`sh`]), as the 27 floats of `sh9`: projected at the
    /// texels' moment directions on the half-resolution image (the one the Lloyd steps already
    /// made for this frame, else made here), see [`sh::project_at_moments`].
    fn sh9(&mut self, image: &DomainImage) -> Vec<f32> {
        let coeffs = if has_coarse_copy(image) {
            refresh_half(image, &mut self.half_image, &mut self.half_is_current);
            sh::project_at_moments(&self.half_image)
        } else {
            sh::project_at_moments(image)
        };
        coeffs.iter().map(|&c| c as f32).collect()
    }

    /// `n` lights by a method that warps per count or not at all (the default, median cut,
    /// k-means, VMLPS).
    fn lights_for(
        &mut self,
        map: &EnvMap,
        image: &DomainImage,
        method: Method,
        n: usize,
    ) -> Vec<Light> {
        match method {
            Method::MedianCut => self.median_cut.lights(map, image, n),
            Method::Vmlps => self.vmlps.lights(map, image, n),
            Method::KMeans => {
                let mut km = std::mem::take(&mut self.kmeans);
                km.seed(image, n);
                let lights = km.converge(|seeds| {
                    self.seeds.clear();
                    self.seeds.extend_from_slice(seeds);
                    self.assign_spherical_once(image, false)
                });
                self.kmeans = km;
                lights
            }
            Method::Voronoi | Method::Paper | Method::InverseCdf => {
                self.warp_seeds(map, image, method, n);
                self.assign_seeds(image, method)
            }
        }
    }

    /// Lights from the seeds [`warp_seeds`](Self::warp_seeds) left: the paper variant's planar
    /// cells, or the spherical cells of the default and the inverse CDF; in video mode the
    /// default's lights are kept as the next frame's seeds.
    fn assign_seeds(&mut self, image: &DomainImage, method: Method) -> Vec<Light> {
        let lights = if method == Method::Paper {
            self.assign_paper(image)
        } else {
            let mut lights = self.assign_spherical(image, method == Method::Voronoi);
            if method == Method::Voronoi {
                self.keep_unswapped_if_better(image, &mut lights);
            }
            // A cell's disc stays on its side of the horizon (ALGORITHMS.md §12).
            for l in &mut lights {
                let gap = horizon_gap(l.to_light);
                l.angular_radius = l.angular_radius.min(gap);
                l.extent = l.extent.and_then(|e| e.clamped(gap));
            }
            lights
        };
        self.remember(method, image, &lights);
        lights
    }

    /// A single map's lights of up to [`SWAP_MAX_LIGHTS`] are also made without the swap rounds,
    /// and those lights kept where the finer reference of `--max-error` (64² bins of the
    /// full-resolution square, 256 normals) estimates their diffuse error lower by at least
    /// [`UNSWAPPED_MARGIN`] (ALGORITHMS.md §4.2, "Swaps"). A swap is kept when the k-means energy falls, and the starts are chosen on
    /// the half-resolution fixed points; neither sees a merge of two compact sources a few degrees
    /// apart, whose one light errs along both terminators (first order in their separation where
    /// the energy is second order), nor what the final assignment and the tilt make of a start.
    fn keep_unswapped_if_better(&mut self, image: &DomainImage, lights: &mut Vec<Light>) {
        let single = self.seed_origin == SeedOrigin::Warp;
        if !(self.unswapped_check
            && single
            && self.swap_rounds > 0
            && (3..=SWAP_MAX_LIGHTS).contains(&lights.len()))
        {
            return;
        }
        let rounds = std::mem::replace(&mut self.swap_rounds, 0);
        let unswapped = self.assign_spherical(image, true);
        self.swap_rounds = rounds;
        let reference = IrradianceReference::from_domain_image(image);
        let kept = reference.error(lights).rel_rms;
        if reference.error(&unswapped).rel_rms < (1.0 - UNSWAPPED_MARGIN) * kept {
            *lights = unswapped;
        }
    }

    /// In video mode, keeps the default method's lights as the next frame's seeds.
    fn remember(&mut self, method: Method, image: &DomainImage, lights: &[Light]) {
        if self.video && method == Method::Voronoi {
            // Counts no longer asked for keep their seeds; past a bound, all start afresh.
            if self.previous.len() >= MAX_VIDEO_COUNTS
                && !self
                    .previous
                    .contains_key(&(lights.len(), image.domain, image.side))
            {
                self.previous.clear();
                self.previous_tilt.clear();
            }
            let seeds = self
                .previous
                .entry((lights.len(), image.domain, image.side))
                .or_default();
            seeds.clear();
            match self.untilted.take() {
                Some(untilted) if untilted.len() == lights.len() => seeds.extend(untilted),
                _ => seeds.extend(lights.iter().map(|l| Vec3::from_array(l.to_light))),
            }
        }
    }

    /// Builds the warp over the luminance and pushes the first `n` progressive points through it:
    /// the continuous warp of the domain square (ALGORITHMS.md §2–3), or for
    /// [`Method::InverseCdf`] the discontinuous one of the lat-long map. In video mode the default
    /// takes the previous frame's lights instead, when it has them.
    fn warp_seeds(&mut self, map: &EnvMap, image: &DomainImage, method: Method, n: usize) {
        // Set for every method, so that no origin is left over from another method's call.
        self.seed_origin = SeedOrigin::Warp;
        let points = &progressive_points()[..n];
        if method == Method::InverseCdf {
            self.inverse_cdf.seeds(map, image, points, &mut self.seeds);
            return;
        }
        if method == Method::Voronoi
            && self.video
            && let Some(prev) = self.previous.get(&(n, image.domain, image.side))
        {
            self.seeds.clear();
            self.seeds.extend_from_slice(prev);
            self.seed_origin = SeedOrigin::LastFrame;
            return;
        }
        self.seed_origin = if self.video && method == Method::Voronoi {
            SeedOrigin::StreamStart
        } else {
            SeedOrigin::Warp
        };
        if method == Method::Voronoi {
            self.warp_by(image, self.placement_for(n), n);
            return;
        }
        self.dist.build(&image.luminance, image.side, image.side);
        self.warp_points(image, points);
    }

    /// The default's seeds: the first `n` fixed points warped by `placement`'s density.
    fn warp_by(&mut self, image: &DomainImage, placement: Placement, n: usize) {
        placement.density(&image.luminance, n, &mut self.density);
        self.dist.build(&self.density, image.side, image.side);
        self.warp_points(image, &progressive_points()[..n]);
    }

    /// Seeds at `points` warped by the distribution built last.
    fn warp_points(&mut self, image: &DomainImage, points: &[glam::DVec2]) {
        self.seeds.clear();
        self.seeds.extend(
            points
                .iter()
                .map(|&p| image.domain.square_to_dir(self.dist.sample(p)).as_vec3()),
        );
    }

    /// Default method: spherical Voronoi cells of the seeds, lights at luminance-weighted centroids.
    /// `may_restart`: the default's own seeds, which may take other starts; the inverse-CDF
    /// baseline shares the rest but keeps its own warp.
    fn assign_spherical(&mut self, image: &DomainImage, may_restart: bool) -> Vec<Light> {
        // A stream's later frames take one full-resolution Lloyd step each, from the last frame's
        // lights (the final assignment below): the half-resolution steps have a fixed point of
        // their own, and alternating the two kept the lights of a static scene moving 0.5–1.5° a
        // frame without end.
        let steps = match self.seed_origin {
            SeedOrigin::Warp
                if (SWAP_MAX_LIGHTS + 1..=STEPS_MAX_LIGHTS).contains(&self.seeds.len()) =>
            {
                self.refine * STEPS_FACTOR
            }
            SeedOrigin::Warp => self.refine,
            SeedOrigin::StreamStart => self.refine.max(VIDEO_START_STEPS),
            SeedOrigin::LastFrame => 0,
        };
        if steps == 0 {
            let lights = self.assign_spherical_once(image, false);
            // Lights the repair re-seeds go to their new place at once (empty unless any).
            let dead: Vec<usize> = (0..lights.len())
                .filter(|&k| self.accum[k].lum <= 0.0)
                .collect();
            let mut lights = self.repair_dead(image, lights);
            if self.seed_origin == SeedOrigin::LastFrame {
                self.limit_steps(image, &mut lights, &dead);
            }
            self.tilt_stream_frame(image, &mut lights);
            return lights;
        }
        // Lloyd steps on the sphere: assign, re-seed at the centroids, `refine` times, then the
        // final assignment. The steps only move the seeds, so they run on the image at half
        // resolution (2 × 2 texels of equal area summed: the same energy and first moments), a
        // quarter of the texels; only the final assignment, which gives the lights their energy
        // and centroids, runs at full resolution.
        let coarse = has_coarse_copy(image);
        let mut half = std::mem::replace(&mut self.half_image, DomainImage::empty());
        if coarse {
            refresh_half(image, &mut half, &mut self.half_is_current);
        }
        let warped = self.seeds.clone();
        let steps_image = if coarse { &half } else { image };
        let first = self.settle(steps_image, coarse, steps);
        let n = self.seeds.len();
        // The binned reference that the starts and the tilt choose by, built once.
        let mut check: Option<IrradianceReference> = None;
        let starts: &[f32] =
            if self.other_starts && may_restart && self.seed_origin == SeedOrigin::Warp {
                other_starts(n)
            } else {
                &[]
            };
        if !starts.is_empty() {
            // Starts (ALGORITHMS.md §4.2): the Lloyd steps and swaps end in the fixed point
            // nearest their start, and on a few maps the default's start lies in a poor one.
            // Above 32 lights the 32² bins are too few a light to choose between three starts.
            let wide;
            let check = if n > MORE_STARTS_MAX_LIGHTS {
                wide = check_reference_at(steps_image, WIDE_CHECK_GRID);
                &wide
            } else {
                check.get_or_insert_with(|| check_reference(steps_image))
            };
            let mut best = (check.error(&first).rel_rms, self.seeds.clone());
            let own = self.placement_for(n);
            for &exponent in starts.iter().filter(|&&e| e != own.exponent) {
                let placement = Placement { exponent, ..own };
                self.warp_by(image, placement, n);
                let lights = self.settle(steps_image, coarse, steps);
                let error = check.error(&lights).rel_rms;
                if error < best.0 {
                    best = (error, self.seeds.clone());
                }
            }
            self.seeds = best.1;
        }
        if n > SPLIT_ABOVE_LIGHTS && self.swap_rounds > 0 {
            self.seed_split(image, coarse, &first);
        }
        let lights = self.assign_spherical_once(image, false);
        let mut lights = self.repair_dead(image, lights);
        let single = may_restart && self.seed_origin == SeedOrigin::Warp;
        let core_split = if self.core_split && single && n <= CORE_SPLIT_MAX_LIGHTS {
            let check = check.get_or_insert_with(|| check_reference(steps_image));
            self.make_room_for_core(image, &mut lights, check)
        } else {
            None
        };
        if self.tilt && single {
            self.tilt_set(
                image,
                steps_image,
                &mut lights,
                &mut check,
                None,
                steps_image,
            );
        }
        if self.core_azimuth && single && n <= CORE_AZIMUTH_MAX_LIGHTS {
            let check = check.get_or_insert_with(|| check_reference(steps_image));
            self.turn_to_core_azimuth(&mut lights, check);
        }
        if let Some(k) = core_split {
            self.split_core(image, &mut lights, k);
        }
        self.seeds = warped;
        self.half_image = half;
        self.tilt_stream_frame(image, &mut lights);
        lights
    }

    /// A stream frame's tilt (ALGORITHMS.md §4.3, "Tilt in a stream"): a single map's, given to
    /// the client while the next frame starts from the untilted lights, each light's tilt
    /// changing by at most [`STREAM_TILT_STEP_DEG`] a frame. Nothing outside a stream (a single
    /// map without Lloyd steps shares the stream's final assignment, not its tilt).
    fn tilt_stream_frame(&mut self, image: &DomainImage, lights: &mut [Light]) {
        let in_stream = self.seed_origin != SeedOrigin::Warp;
        if !(in_stream && self.tilt && self.stream_tilt && lights.len() <= WIDE_TILT_MAX_LIGHTS) {
            return;
        }
        // The key holds the count, so a kept tilt has a value for every light.
        let key = (lights.len(), image.domain, image.side);
        let last = self
            .previous_tilt
            .remove(&key)
            .filter(|_| self.seed_origin == SeedOrigin::LastFrame);
        // The fraction is chosen afresh every few frames; in between the last one is taken.
        let given = last
            .as_ref()
            .filter(|t| t.age < STREAM_TILT_CHOOSE_EVERY)
            .and_then(|t| t.choice);
        let untilted: Vec<Vec3> = lights
            .iter()
            .map(|l| Vec3::from_array(l.to_light))
            .collect();
        let mut half = std::mem::replace(&mut self.half_image, DomainImage::empty());
        // The half-resolution copy serves the estimate and the floor, wanted only to choose.
        let coarse = given.is_none() && has_coarse_copy(image);
        if coarse {
            refresh_half(image, &mut half, &mut self.half_is_current);
        }
        let mut check = None;
        let steps_image = if coarse { &half } else { image };
        // The floor's share from the full-resolution texels every frame: taken from the frame
        // that chose the fraction, it jolted the tilt every eighth frame (EVALUATION.md, "The
        // stream's shadows").
        let choice = self.tilt_set(image, steps_image, lights, &mut check, given, image);
        self.half_image = half;
        let step = STREAM_TILT_STEP_DEG.to_radians();
        let tilts = lights
            .iter_mut()
            .zip(&untilted)
            .enumerate()
            .map(|(k, (l, u))| {
                let want = elevation(Vec3::from_array(l.to_light)) - elevation(*u);
                let tilt = match &last {
                    Some(last) => last.tilts[k] + (want - last.tilts[k]).clamp(-step, step),
                    None => want,
                };
                if tilt != want {
                    l.to_light = at_elevation(*u, elevation(*u) + tilt).to_array();
                }
                tilt
            })
            .collect();
        let age = match (given, choice) {
            // The lights now tilt the other way: the fraction was not taken, choose afresh.
            (Some(g), Some(c)) if g.descending != c.descending => STREAM_TILT_CHOOSE_EVERY,
            (Some(_), _) => last.as_ref().map_or(1, |t| t.age + 1),
            (None, _) => 1,
        };
        self.previous_tilt
            .insert(key, StreamTilt { tilts, choice, age });
        self.untilted = Some(untilted);
    }

    /// The tilt of a set of `lights.len()` lights (ALGORITHMS.md §4.2, "Tilt"): up to
    /// [`TILT_MAX_LIGHTS`] on the 32² reference (`check`, built only when a fraction is to be
    /// tried), the whole way; up to [`WIDE_TILT_MAX_LIGHTS`] on the 48² one, at most
    /// [`WIDE_TILT_MAX_FRACTION`] of it; above, none. The map's floor is summed on
    /// `floor_image`.
    fn tilt_set(
        &self,
        image: &DomainImage,
        steps_image: &DomainImage,
        lights: &mut [Light],
        check: &mut Option<IrradianceReference>,
        given: Option<TiltChoice>,
        floor_image: &DomainImage,
    ) -> Option<TiltChoice> {
        let n = lights.len();
        if n > WIDE_TILT_MAX_LIGHTS {
            return None;
        }
        let share = floor_share(floor_image);
        Some(if n <= TILT_MAX_LIGHTS {
            self.tilt_toward_floor(
                image,
                lights,
                move || &*check.get_or_insert_with(|| check_reference(steps_image)),
                1.0,
                given,
                share,
            )
        } else {
            let wide = || check_reference_at(steps_image, WIDE_CHECK_GRID);
            let max_fraction = WIDE_TILT_MAX_FRACTION;
            self.tilt_toward_floor(image, lights, wide, max_fraction, given, share)
        })
    }

    /// The tilt of a single map's lights toward the floor it should give (ALGORITHMS.md §4.2,
    /// "Tilt"): down toward M_y/P where they give the open ground too much, up toward their
    /// cell's own floor G/P where cells across the horizon leave it too little. Reads the final
    /// assignment's cells (`accum`, `owner`); energies and ids are untouched.
    fn tilt_toward_floor<C>(
        &self,
        image: &DomainImage,
        lights: &mut [Light],
        check: impl FnOnce() -> C,
        max_fraction: f64,
        given: Option<TiltChoice>,
        floor_share: f64,
    ) -> TiltChoice
    where
        C: std::borrow::Borrow<IrradianceReference>,
    {
        // The map's own floor irradiance in the lights' units.
        let energy: f64 = lights.iter().map(|l| l.luminance()).sum();
        let mut floor = floor_share * energy;
        // The lights that may move: above the horizon, and not a compact core in a wider,
        // dimmer cell (a sun in its glare, a lamp), whose shadows' direction is its core's
        // and whose cell's excess is its halo's. One that stays answers for its own excess
        // over its cell's floor M_y: the others do not move to make up for it.
        let mut movable = vec![false; lights.len()];
        for ((a, l), m) in self.accum[..lights.len()]
            .iter()
            .zip(lights.iter())
            .zip(&mut movable)
        {
            if a.lum <= 0.0 || l.to_light[1] <= 0.0 {
                continue;
            }
            *m = a.core_lum > 0.0 && !a.core_is_compact();
            if !*m {
                floor += l.luminance() * (l.to_light[1] as f64 - a.weighted_dir.y / a.lum);
            }
        }
        let descending = tilt::floor_bias(lights, floor) > 0.0;
        if given.is_some_and(|g| g.descending != descending) {
            // The stream's lights now tilt the other way: none this frame (the caller chooses
            // afresh next).
            return TiltChoice {
                fraction: 0.0,
                descending,
            };
        }
        // A fraction chosen in an earlier frame of a stream is taken again.
        let given = given.map(|g| g.fraction);
        let targets: Vec<Option<f64>> = if descending {
            // Too much floor: each light descends toward M_y/P, where a point of power P
            // gives a floor exactly its cell's first moment (ALGORITHMS.md §4.2, "Tilt").
            self.accum[..lights.len()]
                .iter()
                .zip(&movable)
                .map(|(a, &m)| m.then(|| a.weighted_dir.y / a.lum))
                .collect()
        } else {
            // Too little: the lights of cells across the horizon rise toward G/P, their
            // cell's own floor G = Σ max(0, m_y) over its texels (the last full-resolution
            // owners).
            let mut g = vec![0.0f64; lights.len()];
            for (t, &k) in self.owner.iter().enumerate() {
                if let Some(gk) = g.get_mut(k as usize) {
                    *gk += image.moment[t][1].max(0.0) as f64;
                }
            }
            self.accum[..lights.len()]
                .iter()
                .zip(&g)
                .zip(&movable)
                .zip(lights.iter())
                .map(|(((a, gk), &m), l)| {
                    let t = gk / a.lum;
                    (m && t > l.to_light[1] as f64).then_some(t)
                })
                .collect()
        };
        let fraction = match given {
            Some(fraction) => tilt::tilt_at(lights, &targets, floor, max_fraction, fraction),
            None => {
                let allowance = if descending {
                    tilt::DESCENT_ALLOWANCE
                } else {
                    tilt::RISE_ALLOWANCE
                };
                tilt::tilt_toward_floor(lights, &targets, floor, allowance, max_fraction, check)
            }
        };
        TiltChoice {
            fraction,
            descending,
        }
    }

    /// Turns each light of a compact core about the vertical onto its core's azimuth, its
    /// elevation kept (ALGORITHMS.md §4.2, "Core azimuth"): the light of a sun whose cell also
    /// holds some sky sits at the cell's centroid, off the sun, and its shadow falls off the sun's
    /// by as much; the elevation, which sets the floor it gives (the tilt's), stays. Brightest
    /// core first, each turn kept only while the estimated diffuse error at `check` stays within
    /// [`CORE_AZIMUTH_ALLOWANCE`] of the lights' own. Reads the final assignment's cells.
    fn turn_to_core_azimuth(&self, lights: &mut [Light], check: &IrradianceReference) {
        let limit = check.error(lights).rel_rms * (1.0 + CORE_AZIMUTH_ALLOWANCE);
        let mut order: Vec<usize> = (0..lights.len()).collect();
        order.sort_by(|&i, &j| self.accum[j].core_lum.total_cmp(&self.accum[i].core_lum));
        for k in order {
            let (a, before) = (&self.accum[k], lights[k]);
            let y = before.to_light[1] as f64;
            // The tilt's compact core (it leaves these alone), holding most of its cell.
            let compact = a.core_lum >= CORE_AZIMUTH_MIN_SHARE * a.lum && a.core_is_compact();
            if !(compact && y > 0.0) {
                continue;
            }
            let Some(across) = DVec3::new(a.core_moment.x, 0.0, a.core_moment.z).try_normalize()
            else {
                continue;
            };
            let d = across * (1.0 - y * y).max(0.0).sqrt() + DVec3::new(0.0, y, 0.0);
            lights[k].to_light = d.as_vec3().to_array();
            // A NaN estimate (it cannot arise from finite lights) fails the comparison.
            let kept = check.error(lights).rel_rms <= limit;
            if !kept {
                lights[k] = before;
            }
        }
    }

    /// The light whose core is best split off as a light of its own, and how much the split may
    /// raise the estimated diffuse error (ALGORITHMS.md §12, "Core split", "Core aside"): of the
    /// cells whose core is compact (radius at most [`CORE_SPLIT_MAX_DEG`]) inside a rest at least
    /// [`CORE_SPLIT_WIDER`] times wider, those whose rest holds at least [`CORE_SPLIT_MIN_REST`]
    /// of the cell ([`CORE_SPLIT_ALLOWANCE`]) and, at [`CORE_ASIDE_LIGHTS`] lights, those
    /// whose core lies farther from the cell's centroid than its own radius
    /// ([`CORE_ASIDE_ALLOWANCE`]); the one with the brightest core.
    /// `asked` is the number of lights asked for (`lights` may hold one fewer, one given up).
    fn core_to_split(&self, lights: &[Light], asked: usize) -> Option<(usize, f64)> {
        let mean = self.accum[..lights.len()]
            .iter()
            .map(|a| a.lum)
            .sum::<f64>()
            / lights.len() as f64;
        (0..lights.len())
            .filter_map(|k| {
                let a = &self.accum[k];
                // Both parts need energy and a direction (an all-black map has neither).
                let parts = a.core_moment.try_normalize().is_some()
                    && (a.weighted_dir - a.core_moment).try_normalize().is_some();
                if !(parts && a.core_lum > 0.0 && a.core_lum >= mean) {
                    return None;
                }
                let core_r = angular_radius(a.core_lum, a.core_moment.length());
                let compact = core_r <= CORE_SPLIT_MAX_DEG.to_radians()
                    && self.rest_radius(k) >= CORE_SPLIT_WIDER * core_r;
                if !compact {
                    return None;
                }
                if a.lum - a.core_lum >= CORE_SPLIT_MIN_REST * a.lum {
                    return Some((k, CORE_SPLIT_ALLOWANCE));
                }
                // The light sits at the cell's centroid; its shadow falls off the core's by more
                // than the core's own radius.
                let aside = a.core_moment.angle_between(a.weighted_dir) > f64::from(core_r);
                (aside && CORE_ASIDE_LIGHTS.contains(&asked)).then_some((k, CORE_ASIDE_ALLOWANCE))
            })
            .max_by(|i, j| {
                self.accum[i.0]
                    .core_lum
                    .total_cmp(&self.accum[j.0].core_lum)
            })
    }

    /// The half-energy radius of cell `k`'s rest alone (ALGORITHMS.md §12).
    fn rest_radius(&self, k: usize) -> f32 {
        core_rest_radius(
            (0.0, 0.0),
            &self.rest_bins[k * ANGLE_BINS..(k + 1) * ANGLE_BINS],
        )
    }

    /// Frees one of `lights` for a core split: if a cell has a core to split off
    /// ([`core_to_split`](Self::core_to_split)), the light cheapest to merge goes, the texels are
    /// assigned again to the others, and the cell to split is returned (its index in the new
    /// `lights`, one fewer). `None`, with `lights` as they were, where no cell has one or where
    /// the split set's estimated diffuse error at `check` would exceed the lights' own by more
    /// than [`CORE_SPLIT_ALLOWANCE`] (the light given up is missed).
    fn make_room_for_core(
        &mut self,
        image: &DomainImage,
        lights: &mut Vec<Light>,
        check: &IrradianceReference,
    ) -> Option<usize> {
        let (k, _) = self.core_to_split(lights, lights.len())?;
        let before = check.error(lights).rel_rms;
        let gone = self.cheapest_to_merge(lights, &[k])?;
        self.seeds.clear();
        self.seeds.extend(
            lights
                .iter()
                .enumerate()
                .filter(|&(i, _)| i != gone)
                .map(|(_, l)| Vec3::from_array(l.to_light)),
        );
        let fewer = self.assign_spherical_once(image, false);
        let fewer = self.repair_dead(image, fewer);
        // The cells changed around the one given up: the core is chosen again from them
        // (usually the same cell, its seed kept).
        let k = self
            .core_to_split(&fewer, lights.len())
            .filter(|&(k, allowance)| {
                let mut split = fewer.clone();
                self.split_core(image, &mut split, k);
                // A NaN estimate (it cannot arise from finite lights) fails the comparison.
                check.error(&split).rel_rms <= before * (1.0 + allowance)
            })
            .map(|(k, _)| k);
        if k.is_some() {
            *lights = fewer;
        } else {
            // No core left to split, or the split costs the diffuse error too much: the lights
            // as they were, from their own cells (the tilt reads their sums).
            self.seeds.clear();
            self.seeds
                .extend(lights.iter().map(|l| Vec3::from_array(l.to_light)));
            *lights = self.assign_spherical_once(image, false);
            *lights = self.repair_dead(image, std::mem::take(lights));
        }
        k
    }

    /// Splits light `k` into its core (its id kept) and its rest (a new id, last): each at its
    /// own centroid with its own energy; the core's disc from its moments, the rest's its
    /// half-energy disc (ALGORITHMS.md §12, "Core split").
    fn split_core(&self, image: &DomainImage, lights: &mut Vec<Light>, k: usize) {
        let a = &self.accum[k];
        let texel_sr = image.texel_solid_angle();
        let rest_moment = a.weighted_dir - a.core_moment;
        let (Some(core_dir), Some(rest_dir)) =
            (a.core_moment.try_normalize(), rest_moment.try_normalize())
        else {
            return;
        };
        let whole = lights[k];
        let core_sr = whole.solid_angle * (a.core_lum / a.lum) as f32;
        lights[k] = Light {
            to_light: core_dir.as_vec3().to_array(),
            irradiance: (a.core_energy * texel_sr).as_vec3().to_array(),
            solid_angle: core_sr,
            angular_radius: angular_radius(a.core_lum, a.core_moment.length()),
            extent: None,
            ..whole
        };
        lights.push(Light {
            id: lights.len() as u32,
            to_light: rest_dir.as_vec3().to_array(),
            irradiance: ((a.energy - a.core_energy) * texel_sr).as_vec3().to_array(),
            solid_angle: whole.solid_angle - core_sr,
            angular_radius: self.rest_radius(k),
            extent: None,
            ..whole
        });
    }

    /// The light, not one of `skip`, whose loss costs least: its merge cost with its nearest
    /// neighbour j, |M_k| + |M_j| − |M_k + M_j| (ALGORITHMS.md §4.2, "Swaps").
    fn cheapest_to_merge(&self, lights: &[Light], skip: &[usize]) -> Option<usize> {
        let n = lights.len();
        let dirs = DirectionsSoa::from_lights(lights);
        let mut weakest = (f64::INFINITY, None);
        for k in (0..n).filter(|k| !skip.contains(k)) {
            let nearest = nearest_other(&dirs, k);
            let (mk, mj) = (self.accum[k].weighted_dir, self.accum[nearest].weighted_dir);
            let cost = mk.length() + mj.length() - (mk + mj).length();
            if cost < weakest.0 {
                weakest = (cost, Some(k));
            }
        }
        weakest.1
    }

    /// The split of a single map of more than [`SPLIT_ABOVE_LIGHTS`] lights (ALGORITHMS.md §4.2,
    /// "Split"), folded into the final assignment: from the last Lloyd step's cells (`lights`, on
    /// the half-resolution square when `coarse`), the light cheapest to merge is re-seeded at the
    /// full-resolution texel farthest from the centroid of the brightest cell. Point lights err
    /// most where their cell is brightest once the rest is small: on a clear sky at 256 lights the
    /// sun's one light errs along its terminator, where two lights across its disc do not, and a
    /// half-resolution texel is too coarse to tell where inside the disc the second one goes.
    fn seed_split(&mut self, image: &DomainImage, coarse: bool, lights: &[Light]) {
        let n = lights.len();
        let Some(c) = (0..n)
            .filter(|&c| self.accum[c].can_donate())
            .max_by(|&a, &b| self.accum[a].lum.total_cmp(&self.accum[b].lum))
        else {
            return;
        };
        if self.source_is_shared(c) {
            return;
        }
        let Some(k) = self.cheapest_to_merge(lights, &[c]) else {
            return;
        };
        let farthest = if coarse {
            // The cell's centroid is the same at either resolution: a half-resolution texel sums
            // the moments of its four.
            let centre = self.accum[c].weighted_dir.normalize_or_zero();
            let (side, half_side) = (image.side, image.side / 2);
            let mut best: Option<(f64, usize)> = None;
            for (h, _) in self
                .half_owner
                .iter()
                .enumerate()
                .filter(|(_, o)| **o as usize == c)
            {
                let (i, j) = (2 * (h % half_side), 2 * (h / half_side));
                for t in [
                    j * side + i,
                    j * side + i + 1,
                    (j + 1) * side + i,
                    (j + 1) * side + i + 1,
                ] {
                    if let Some(score) = farness(image, t, centre)
                        && best.is_none_or(|b| score > b.0)
                    {
                        best = Some((score, t));
                    }
                }
            }
            best.map(|(_, t)| t)
        } else {
            self.farthest_lit_texels(image, &[c], false)[0].map(|(t, _)| t)
        };
        if let Some(t) = farthest
            && let Some(dir) = Vec3::from_array(image.moment[t]).try_normalize()
        {
            self.seeds[k] = dir;
        }
    }

    /// Whether cell `c`'s compact source already has a second light: another cell of at least
    /// [`SPLIT_SHARED_SHARE`] of its luminance whose centroid lies within twice the two cells'
    /// wider disc, both under [`SPLIT_SHARED_MAX_DEG`] (ALGORITHMS.md §4.2, "Split"). A sun on a
    /// texel boundary is cut in two by the Lloyd steps themselves, and a third light taken from
    /// one half leaves that half's disc lopsided.
    fn source_is_shared(&self, c: usize) -> bool {
        let radius = |a: &CellAccum| angular_radius(a.lum, a.weighted_dir.length()) as f64;
        let compact = SPLIT_SHARED_MAX_DEG.to_radians();
        let cell = &self.accum[c];
        let cell_radius = radius(cell);
        if cell_radius >= compact {
            return false;
        }
        let centre = cell.weighted_dir.normalize_or_zero();
        self.accum.iter().enumerate().any(|(j, other)| {
            if j == c || other.lum < SPLIT_SHARED_SHARE * cell.lum {
                return false;
            }
            let wider = cell_radius.max(radius(other));
            wider < compact
                && centre.angle_between(other.weighted_dir.normalize_or_zero()) < 2.0 * wider
        })
    }

    /// Moves each seed to its light's direction (a Lloyd step's re-seeding).
    fn seed_at(&mut self, lights: &[Light]) {
        for (s, l) in self.seeds.iter_mut().zip(lights) {
            *s = Vec3::from_array(l.to_light);
        }
    }

    /// Σ over the cells of the last assignment of their k-means energy P − |M| (ALGORITHMS.md
    /// §10): the objective the swap rounds lower.
    fn kmeans_energy(&self) -> f64 {
        self.accum.iter().map(|a| a.spread()).sum()
    }

    /// The swap rounds of a single map (ALGORITHMS.md §4.2, "Swaps"), from the seeds the Lloyd
    /// steps left, on `image` (the steps' half-resolution image when `half`). Lloyd steps only
    /// slide lights downhill into the nearest fixed point, and on a map of a few compact lamps that
    /// fixed point can spend several lights on one lamp and none on another (night.exr at 32 lights:
    /// 1.9 × the k-means floor). A round moves the light whose loss costs least (merge cost
    /// |M_k| + |M_j| − |M_k + M_j| with its nearest neighbour j) to the lit texel farthest from the
    /// centroid of the cell of largest energy, takes one Lloyd step, and keeps the move if the total
    /// energy fell; a refused move is undone and the next-cheapest light tried. Three lights or
    /// more ([`settle`](Self::settle) calls it so).
    fn swap(&mut self, image: &DomainImage, half: bool) -> Vec<Light> {
        let n = self.seeds.len();
        let lights = self.assign_spherical_once(image, half);
        self.seed_at(&lights);
        let mut lights = self.assign_spherical_once(image, half);
        let mut energy = self.kmeans_energy();
        let mut failed: Vec<usize> = Vec::new();
        for _ in 0..self.swap_rounds {
            let Some(k) = self.cheapest_to_merge(&lights, &failed) else {
                break;
            };
            let Some(c) = (0..n)
                .filter(|&c| c != k && self.accum[c].can_donate())
                .max_by(|&a, &b| self.accum[a].spread().total_cmp(&self.accum[b].spread()))
            else {
                break;
            };
            let Some((t, _)) = self.farthest_lit_texels(image, &[c], half)[0] else {
                break;
            };
            let Some(dir) = Vec3::from_array(image.moment[t]).try_normalize() else {
                break;
            };
            let before = self.seeds.clone();
            let accum_before = self.accum.clone();
            let owner_before = if half {
                self.half_owner.clone()
            } else {
                self.owner.clone()
            };
            self.seed_at(&lights);
            self.seeds[k] = dir;
            let step = self.assign_spherical_once(image, half);
            self.seed_at(&step);
            let trial = self.assign_spherical_once(image, half);
            let e = self.kmeans_energy();
            if e < energy {
                energy = e;
                lights = trial;
                failed.clear();
            } else {
                self.seeds = before;
                self.accum = accum_before;
                if half {
                    self.half_owner = owner_before;
                } else {
                    self.owner = owner_before;
                }
                failed.push(k);
            }
        }
        self.seed_at(&lights);
        lights
    }

    /// `steps` (at least one) Lloyd steps from the current seeds on `image` (the half-resolution
    /// copy when `half`), more while they still lower the energy fast on a single map of more
    /// than [`STEPS_MAX_LIGHTS`] lights, then, from 3 to [`SWAP_MAX_LIGHTS`] lights, the swap
    /// rounds; the seeds are left at the lights returned, those of the last assignment.
    fn settle(&mut self, image: &DomainImage, half: bool, steps: usize) -> Vec<Light> {
        let mut lights = Vec::new();
        // Past the steps asked for, a single map of many lights goes on while its steps still
        // lower the k-means energy fast (ALGORITHMS.md §4.2, "Steps"; `CONVERGE_*`).
        let may_go_on = self.converge
            && self.seed_origin == SeedOrigin::Warp
            && self.seeds.len() > STEPS_MAX_LIGHTS;
        let (mut energy, mut fall) = (f64::INFINITY, f64::INFINITY);
        let mut taken = 0;
        loop {
            // The step after the ones asked for needs a large fall; each one after it, any fall
            // over the tolerance.
            let needed_fall = if taken == steps {
                CONVERGE_TRIGGER
            } else {
                CONVERGE_TOLERANCE
            };
            let settling =
                may_go_on && taken < CONVERGE_MAX_STEPS && fall.is_finite() && fall >= needed_fall;
            if taken >= steps && !settling {
                break;
            }
            lights = self.assign_spherical_once(image, half);
            let e = self.kmeans_energy();
            fall = (energy - e) / e;
            energy = e;
            self.seed_at(&lights);
            taken += 1;
        }
        if (3..=SWAP_MAX_LIGHTS).contains(&self.seeds.len()) {
            lights = self.swap(image, half);
        }
        lights
    }

    /// Video mode: each light moves from last frame's direction (its seed) toward its cell's
    /// centroid by at most the step [`VideoTracking`] allows, and is reported where it stops;
    /// the lights in `dead` were re-seeded by the repair and keep their centroids.
    fn limit_steps(&mut self, image: &DomainImage, lights: &mut [Light], dead: &[usize]) {
        let t = self.tracking;
        if !(t.max_step_deg.is_finite() && t.max_step_deg >= 0.0) {
            return;
        }
        let Some(prev) = self.previous.get(&(lights.len(), image.domain, image.side)) else {
            return;
        };
        self.moves.clear();
        self.moves.extend(
            lights
                .iter()
                .zip(prev)
                .map(|(l, &p)| angle(p, Vec3::from_array(l.to_light))),
        );
        let median = if self.moves.is_empty() {
            0.0
        } else {
            self.moves_scratch.clear();
            self.moves_scratch.extend_from_slice(&self.moves);
            let mid = self.moves_scratch.len() / 2;
            *self
                .moves_scratch
                .select_nth_unstable_by(mid, f32::total_cmp)
                .1
        };
        let cap = t.max_step_deg.to_radians().max(t.follow_factor * median);
        let budget = t.lag_budget.max(0.0).to_radians();
        let total: f64 = self.accum.iter().map(|a| a.lum).sum();
        for (k, l) in lights.iter_mut().enumerate() {
            let want = self.moves[k];
            if want <= cap || dead.contains(&k) {
                continue;
            }
            let share = if total > 0.0 {
                (self.accum[k].lum / total) as f32
            } else {
                0.0
            };
            let limit = if share > 0.0 {
                cap.max(want - budget / share)
            } else {
                cap
            };
            if want > limit {
                l.to_light = step_toward(prev[k], Vec3::from_array(l.to_light), limit).to_array();
            }
        }
    }

    /// Gives each light left without energy by the last full-resolution assignment a place of
    /// its own (DESIGN.md: every light carries energy; N lights asked for are N lights given while
    /// the map has that many lit texels): the seed moves to the lit texel farthest (luminance ×
    /// (1 − cos)) from the centroid of the cell with the most k-means energy P − |M|
    /// (ALGORITHMS.md §10), the other seeds to their lights, and the texels are assigned again.
    /// A rare path: the capped density of [`Placement`] leaves few such lights.
    fn repair_dead(&mut self, image: &DomainImage, mut lights: Vec<Light>) -> Vec<Light> {
        for _round in 0..3 {
            let dead: Vec<usize> = (0..lights.len())
                .filter(|&k| self.accum[k].lum <= 0.0)
                .collect();
            if dead.is_empty() {
                break;
            }
            let mut donors: Vec<usize> = (0..self.accum.len())
                .filter(|&k| self.accum[k].can_donate())
                .collect();
            if donors.is_empty() {
                break;
            }
            donors.sort_by(|&a, &b| self.accum[b].spread().total_cmp(&self.accum[a].spread()));
            donors.truncate(dead.len());
            let farthest = self.farthest_lit_texels(image, &donors, false);
            let mut moved = false;
            self.seed_at(&lights);
            for (&d, far) in dead.iter().zip(&farthest) {
                if let Some((t, _)) = *far
                    && let Some(dir) = Vec3::from_array(image.moment[t]).try_normalize()
                {
                    self.seeds[d] = dir;
                    moved = true;
                }
            }
            if !moved {
                break;
            }
            lights = self.assign_spherical_once(image, false);
        }
        self.steal_for_dead(image, lights)
    }

    /// For each cell of `donors`, its lit texel farthest from the cell's centroid (luminance ×
    /// (1 − cos), from the texels' moments) and its count of lit texels, by one pass over the
    /// owners of the last full-resolution assignment; `None` for a cell with no lit texel.
    fn farthest_lit_texels(
        &self,
        image: &DomainImage,
        donors: &[usize],
        half: bool,
    ) -> Vec<Option<(usize, usize)>> {
        let owner = if half { &self.half_owner } else { &self.owner };
        let mut slot = vec![usize::MAX; self.accum.len()];
        for (i, &k) in donors.iter().enumerate() {
            slot[k] = i;
        }
        let centres: Vec<DVec3> = donors
            .iter()
            .map(|&k| self.accum[k].weighted_dir.normalize_or_zero())
            .collect();
        let mut best: Vec<Option<(f64, usize)>> = vec![None; donors.len()];
        let mut lit = vec![0usize; donors.len()];
        for (t, &k) in owner.iter().enumerate() {
            let i = slot[k as usize];
            if i == usize::MAX {
                continue;
            }
            let Some(score) = farness(image, t, centres[i]) else {
                continue;
            };
            lit[i] += 1;
            if best[i].is_none_or(|b| score > b.0) {
                best[i] = Some((score, t));
            }
        }
        best.iter()
            .zip(&lit)
            .map(|(b, &n)| b.map(|(_, t)| (t, n)))
            .collect()
    }

    /// The last resort of [`repair_dead`](Self::repair_dead), for a light still without energy
    /// (its new seed lost every texel to a nearer one): it takes the farthest lit texel of the
    /// cell with the most k-means energy outright, so every light carries energy while the map
    /// has as many lit texels as lights, and Σ energy is unchanged.
    fn steal_for_dead(&mut self, image: &DomainImage, lights: Vec<Light>) -> Vec<Light> {
        let mut changed = false;
        let core_fraction = self.core_fraction();
        while let Some(dead) = (0..self.accum.len()).find(|&k| self.accum[k].lum <= 0.0) {
            let Some(donor) = (0..self.accum.len())
                .filter(|&k| self.accum[k].can_donate())
                .max_by(|&a, &b| self.accum[a].spread().total_cmp(&self.accum[b].spread()))
            else {
                break;
            };
            let Some((t, _)) =
                self.farthest_lit_texels(image, &[donor], false)[0].filter(|f| f.1 >= 2)
            else {
                // The donor's texels are one lit texel and unlit ones: it cannot spare any.
                self.accum[donor].texels = 1;
                continue;
            };
            let radiance = Vec3::from_array(image.radiance[t]).as_dvec3();
            let moment = Vec3::from_array(image.moment[t]).as_dvec3();
            let y = image.luminance[t];
            let d = &mut self.accum[donor];
            d.energy -= radiance;
            d.weighted_dir -= moment;
            d.lum -= y as f64;
            d.texels -= 1;
            if d.in_core(y, core_fraction) && d.core_lum > y as f64 {
                d.core_lum -= y as f64;
                d.core_moment -= moment;
                d.core_energy -= radiance;
            }
            self.owner[t] = dead as u16;
            self.accum[dead] = CellAccum {
                energy: radiance,
                weighted_dir: moment,
                lum: y as f64,
                texels: self.accum[dead].texels + 1,
                peak: y,
                core_lum: y as f64,
                core_moment: moment,
                core_energy: radiance,
            };
            changed = true;
        }
        if !changed {
            return lights;
        }
        self.cell_lights(image, |a, seed| {
            a.weighted_dir.as_vec3().try_normalize().unwrap_or(seed)
        })
    }

    /// One assignment of texels to the nearest seed and the cells' centroids; `half` says which
    /// cached grid to use (the Lloyd steps' half-resolution image has its own).
    fn assign_spherical_once(&mut self, image: &DomainImage, half: bool) -> Vec<Light> {
        let side = image.side;
        let slot = if half {
            &mut self.half_grid
        } else {
            &mut self.grid
        };
        if !slot
            .as_ref()
            .is_some_and(|g| g.domain == image.domain && g.side == side)
        {
            *slot = Some(CandidateGrid::new(image.domain, side));
        }
        let grid = slot.as_mut().expect("just set");
        grid.fill_candidates(&self.seeds);

        self.accum.clear();
        self.accum.resize(self.seeds.len(), CellAccum::default());
        if half {
            self.half_owner.resize(side * side, 0);
        } else {
            self.owner.resize(side * side, 0);
        }
        let owner = if half {
            &mut self.half_owner
        } else {
            &mut self.owner
        };
        assign_texels(grid, &self.seeds, image, owner, &mut self.accum);
        if !half {
            // The cores, and each cell's rest by angle about its centroid: a second pass over
            // the texels, by the owners just recorded (ALGORITHMS.md §12). A texel counts at its
            // own mean 1 − cos θ, its farness over its luminance, (Y − M·c)/Y.
            self.centroids.clear();
            self.centroids.extend(
                self.accum
                    .iter()
                    .map(|a| a.weighted_dir.normalize_or_zero()),
            );
            self.rest_bins.clear();
            self.rest_bins.resize(self.accum.len() * ANGLE_BINS, 0.0);
            let core_fraction = self.core_fraction();
            add_cores_and_rest(
                image,
                &self.owner,
                &self.centroids,
                &mut self.accum,
                &mut self.rest_bins,
                core_fraction,
            );
        }
        // Move each light to its cell's luminance-weighted centroid; a dark or empty cell keeps
        // its seed.
        self.cell_lights(image, |a, seed| {
            a.weighted_dir.as_vec3().try_normalize().unwrap_or(seed)
        })
    }

    /// One light per accumulated cell, in id order, pointing where `dir(cell, seed)` says.
    fn cell_lights(
        &self,
        image: &DomainImage,
        dir: impl Fn(&CellAccum, Vec3) -> Vec3,
    ) -> Vec<Light> {
        let texel_sr = image.texel_solid_angle();
        self.accum
            .iter()
            .zip(&self.seeds)
            .enumerate()
            .map(|(k, (a, &seed))| {
                let d = dir(a, seed);
                // Where the cores were measured (the spherical cells): the disc with the cell's
                // half-energy radius, of its core's disc and its rest by angle (ALGORITHMS.md
                // §12). Else the whole cell's spread about the light's direction (the paper
                // variant's lights sit at their seeds): P − M·d.
                let rest = self.rest_bins.get(k * ANGLE_BINS..(k + 1) * ANGLE_BINS);
                let (radius, extent) = if let Some(rest) = rest.filter(|_| a.core_lum > 0.0) {
                    let core = (a.core_lum, a.core_moment.length());
                    (
                        core_rest_radius(core, rest),
                        // The core's shadow from its own direction (ALGORITHMS.md §12,
                        // "Two-part extent"), unless the horizon lies between it and the cell's.
                        LightExtent::of_core_and_rest(core, rest).map(|e| {
                            let same_side = (a.core_moment.y > 0.0) == (a.weighted_dir.y > 0.0);
                            if same_side {
                                e.toward(a.core_moment)
                            } else {
                                e
                            }
                        }),
                    )
                } else {
                    let along = a.weighted_dir.dot(d.as_dvec3().normalize_or_zero());
                    (angular_radius(a.lum, along), None)
                };
                Light {
                    id: k as u32,
                    to_light: d.normalize_or(Vec3::Y).to_array(),
                    irradiance: (a.energy * texel_sr).as_vec3().to_array(),
                    solid_angle: (a.texels as f64 * texel_sr) as f32,
                    angular_radius: radius,
                    extent,
                    shadowed: None,
                }
            })
            .collect()
    }

    /// Paper variant: texel → T(texel) in the unit square → the fixed point whose planar Voronoi cell
    /// contains it; the light stays at its warped point (ALGORITHMS.md §4 "paper").
    fn assign_paper(&mut self, image: &DomainImage) -> Vec<Light> {
        let n = self.seeds.len();
        let cells = self
            .paper_cells
            .entry(n)
            .or_insert_with(|| voronoi_raster(&progressive_points()[..n], PAPER_GRID));
        let side = image.side;
        self.accum.clear();
        self.accum.resize(n, CellAccum::default());
        for j in 0..side {
            for i in 0..side {
                let t = j * side + i;
                let p = self.dist.forward(DomainImage::texel_centre(side, i, j));
                let gi = ((p.x * PAPER_GRID as f64) as usize).min(PAPER_GRID - 1);
                let gj = ((p.y * PAPER_GRID as f64) as usize).min(PAPER_GRID - 1);
                let k = cells[gj * PAPER_GRID + gi] as usize;
                let a = &mut self.accum[k];
                a.energy += Vec3::from_array(image.radiance[t]).as_dvec3();
                a.weighted_dir += Vec3::from_array(image.moment[t]).as_dvec3();
                a.lum += image.luminance[t] as f64;
                a.texels += 1;
            }
        }
        self.cell_lights(image, |_, seed| seed)
    }
}

/// Each texel of `grid` to its nearest seed among its cell's candidates: `owner[t]` and the
/// seed's [`CellAccum`] sums. Compiled twice, the second time for CPUs with AVX2 and FMA (chosen
/// at run time), whose eight-lane registers take a block of texels in one instruction.
#[multiversion(targets("x86_64+avx2+fma"))]
fn assign_texels(
    grid: &CandidateGrid,
    seeds: &[Vec3],
    image: &DomainImage,
    owner: &mut [u16],
    accum: &mut [CellAccum],
) {
    for cell in 0..grid.cell_count() {
        let cands = grid.candidates(cell);
        let start = grid.cell_starts[cell];
        let end = grid.cell_starts[cell + 1];
        // Eight texels at a time against every candidate: eight independent running maxima
        // the compiler keeps in vector registers.
        for block in (start..end).step_by(LANES) {
            let (bx, by, bz) = (
                &grid.dx[block..block + LANES],
                &grid.dy[block..block + LANES],
                &grid.dz[block..block + LANES],
            );
            let mut best_dot = [f32::NEG_INFINITY; LANES];
            let mut best = [0u16; LANES];
            for &k in cands {
                let sd = seeds[k as usize];
                for l in 0..LANES {
                    let dot = bx[l] * sd.x + by[l] * sd.y + bz[l] * sd.z;
                    let better = dot > best_dot[l];
                    best_dot[l] = if better { dot } else { best_dot[l] };
                    best[l] = if better { k } else { best[l] };
                }
            }
            for l in 0..LANES {
                let t = grid.texels[block + l];
                if t == u32::MAX {
                    continue; // padding
                }
                let t = t as usize;
                owner[t] = best[l];
                accum[best[l] as usize].add_texel(image, t);
            }
        }
    }
}

/// The second pass over the texels of a full-resolution assignment, by their `owner`s: each
/// cell's core sums, and its rest binned by angle about its centroid (ALGORITHMS.md §12). Compiled
/// twice, as [`assign_texels`].
#[multiversion(targets("x86_64+avx2+fma"))]
fn add_cores_and_rest(
    image: &DomainImage,
    owner: &[u16],
    centroids: &[DVec3],
    accum: &mut [CellAccum],
    rest_bins: &mut [f32],
    core_fraction: f32,
) {
    for (t, &k) in owner.iter().enumerate() {
        let k = k as usize;
        if !accum[k].add_core_texel(image, t, core_fraction)
            && let Some(far) = farness(image, t, centroids[k])
        {
            let y = image.luminance[t];
            rest_bins[k * ANGLE_BINS + angle_bin((far / y as f64) as f32)] += y;
        }
    }
}

/// Angle between two unit vectors, radians (accurate near 0, unlike acos of the dot product).
fn angle(a: Vec3, b: Vec3) -> f32 {
    2.0 * ((a - b).length() * 0.5).clamp(0.0, 1.0).asin()
}

/// `from` turned toward `to` by `step` radians (`to` itself when it is at most that far).
fn step_toward(from: Vec3, to: Vec3, step: f32) -> Vec3 {
    if angle(from, to) <= step {
        return to;
    }
    let Some(u) = (to - from * from.dot(to)).try_normalize() else {
        return to;
    };
    (from * step.cos() + u * step.sin()).normalize()
}

/// Resolution of the cell-id grid of the paper variant's planar Voronoi diagram.
const PAPER_GRID: usize = 512;

/// Unit vectors in structure-of-arrays form, for nearest-direction searches.
#[derive(Default)]
struct DirectionsSoa {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl DirectionsSoa {
    fn clear(&mut self) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
    }

    fn extend(&mut self, dirs: impl Iterator<Item = Vec3>) {
        for d in dirs {
            self.x.push(d.x);
            self.y.push(d.y);
            self.z.push(d.z);
        }
    }

    fn from_lights(lights: &[Light]) -> Self {
        let mut soa = DirectionsSoa::default();
        soa.extend(lights.iter().map(|l| Vec3::from_array(l.to_light)));
        soa
    }

    /// Dot products of every direction with `d`, into `out`.
    fn dots(&self, d: Vec3, out: &mut Vec<f32>) {
        // Into a buffer of the final length, a loop that vectorises (`extend` did not).
        out.resize(self.x.len(), 0.0);
        for (((o, x), y), z) in out.iter_mut().zip(&self.x).zip(&self.y).zip(&self.z) {
            *o = d.x * x + d.y * y + d.z * z;
        }
    }
}

/// The direction of `dirs` nearest to direction `k` of them, other than `k` (the first of
/// equals; `k` itself when it is the only one): a running maximum of the dot product and where it
/// is, in eight lanes so that the loop vectorises. Compiled twice, as [`assign_texels`].
#[multiversion(targets("x86_64+avx2+fma"))]
fn nearest_other(dirs: &DirectionsSoa, k: usize) -> usize {
    const LANES: usize = 8;
    let d = Vec3::new(dirs.x[k], dirs.y[k], dirs.z[k]);
    let dot = |j: usize| {
        if j == k {
            f32::NEG_INFINITY
        } else {
            d.x * dirs.x[j] + d.y * dirs.y[j] + d.z * dirs.z[j]
        }
    };
    let n = dirs.x.len();
    let whole = n - n % LANES;
    let (mut best, mut at) = ([f32::NEG_INFINITY; LANES], [k as u32; LANES]);
    for (c, ((x, y), z)) in dirs.x[..whole]
        .as_chunks::<LANES>()
        .0
        .iter()
        .zip(dirs.y[..whole].as_chunks::<LANES>().0)
        .zip(dirs.z[..whole].as_chunks::<LANES>().0)
        .enumerate()
    {
        for l in 0..LANES {
            let j = c * LANES + l;
            let v = d.x * x[l] + d.y * y[l] + d.z * z[l];
            let v = if j == k { f32::NEG_INFINITY } else { v };
            if v > best[l] {
                (best[l], at[l]) = (v, j as u32);
            }
        }
    }
    // Lane by lane each holds the first of its equals; across lanes the lowest index wins a tie.
    let mut nearest = (f32::NEG_INFINITY, k as u32);
    for (v, j) in best
        .into_iter()
        .zip(at)
        .chain((whole..n).map(|j| (dot(j), j as u32)))
    {
        if v > nearest.0 || (v == nearest.0 && j < nearest.1 && v > f32::NEG_INFINITY) {
            nearest = (v, j);
        }
    }
    nearest.1 as usize
}

/// A cap holding every one of `dirs` (not empty): their normalised sum and the angle to the
/// farthest of them, padded by float error so that bounds built on it stay conservative.
fn bounding_cap(dirs: &[Vec3]) -> (Vec3, f32) {
    let c = dirs.iter().sum::<Vec3>().try_normalize().unwrap_or(dirs[0]);
    let min_dot = dirs.iter().map(|d| c.dot(*d)).fold(1.0f32, f32::min);
    (c, min_dot.clamp(-1.0, 1.0).acos() + 1e-4)
}

/// Appends to `out` the lights of `from` that can be nearest to some direction within `radius`
/// of `centre`: those within a_min + 2·radius of it, a_min the angle to the nearest of `from`
/// (see [`CandidateGrid`]). Compiled twice, as [`assign_texels`].
#[multiversion(targets("x86_64+avx2+fma"))]
fn gather_candidates(
    seeds: &DirectionsSoa,
    from: &[u16],
    centre: Vec3,
    radius: f32,
    dots: &mut Vec<f32>,
    out: &mut Vec<u16>,
) {
    dots.clear();
    if from.len() == seeds.x.len() {
        seeds.dots(centre, dots);
    } else {
        dots.extend(from.iter().map(|&k| {
            let k = k as usize;
            centre.x * seeds.x[k] + centre.y * seeds.y[k] + centre.z * seeds.z[k]
        }));
    }
    let best_dot = max_f32(dots, f32::NEG_INFINITY);
    let limit = best_dot.clamp(-1.0, 1.0).acos() + 2.0 * radius;
    let cos_limit = if limit >= std::f32::consts::PI {
        -2.0
    } else {
        limit.cos() - 1e-6
    };
    // Without a branch per light (which is mispredicted whenever a light is near the limit):
    // every id is written, and the count moves on past those within it.
    let base = out.len();
    out.resize(base + from.len(), 0);
    let slots = &mut out[base..];
    let mut kept = 0;
    for (&k, &d) in from.iter().zip(dots.iter()) {
        slots[kept] = k;
        kept += (d >= cos_limit) as usize;
    }
    out.truncate(base + kept);
}

/// Texels of the domain square gathered into coarse cells, each with a bounding cap on the sphere,
/// and per frame the lights that can be nearest to some texel of each cell.
///
/// With c the cell's centre direction, ρ its cap radius and a_min the angle from c to the nearest
/// light, any light nearest to a texel of the cell is within a_min + 2ρ of c (triangle inequality),
/// so the texel loop only looks at those.
struct CandidateGrid {
    domain: Domain,
    side: usize,
    /// Texel indices, cell by cell, each cell padded with `u32::MAX` to a multiple of [`LANES`];
    /// `cell_starts[c]..cell_starts[c+1]` is cell c.
    texels: Vec<u32>,
    /// Texel directions in the same order as `texels` (structure of arrays; padding is +Y).
    dx: Vec<f32>,
    dy: Vec<f32>,
    dz: Vec<f32>,
    cell_starts: Vec<usize>,
    centres: Vec<Vec3>,
    /// Cap radius ρ of each cell, radians.
    radii: Vec<f32>,
    /// Blocks of 2 × 2 cells, each with its cap over the texels of its cells: their candidates
    /// are found among all the lights, and each cell's among its block's (a cell's lights nearest
    /// to its texels are among its block's), which takes the lists from N dot products a cell to
    /// about N / 4 and the block's candidates.
    block_of: Vec<usize>,
    block_centres: Vec<Vec3>,
    block_radii: Vec<f32>,
    block_candidates: Vec<u16>,
    block_starts: Vec<usize>,
    /// Every light's id, 0..N: the list the blocks' candidates are cut from.
    all: Vec<u16>,
    /// Candidate light ids, all cells concatenated; `starts[c]..starts[c+1]` is cell c's slice.
    candidates: Vec<u16>,
    starts: Vec<usize>,
    /// Seeds in SoA form and a dot-product buffer, reused every frame.
    seeds: DirectionsSoa,
    dots: Vec<f32>,
}

/// Texels per side of a coarse cell.
const CELL_TEXELS: usize = 8;
/// Texels searched together in the assignment loop.
const LANES: usize = 8;

impl CandidateGrid {
    fn new(domain: Domain, side: usize) -> Self {
        let g = side.div_ceil(CELL_TEXELS);
        let mut texels = Vec::with_capacity(side * side);
        let mut dirs: Vec<Vec3> = Vec::with_capacity(side * side);
        let mut cell_starts = vec![0];
        let mut centres = Vec::with_capacity(g * g);
        let mut radii = Vec::with_capacity(g * g);
        for cj in 0..g {
            for ci in 0..g {
                let start = texels.len();
                for j in cj * CELL_TEXELS..((cj + 1) * CELL_TEXELS).min(side) {
                    for i in ci * CELL_TEXELS..((ci + 1) * CELL_TEXELS).min(side) {
                        texels.push((j * side + i) as u32);
                        dirs.push(
                            domain
                                .square_to_dir(DomainImage::texel_centre(side, i, j))
                                .as_vec3(),
                        );
                    }
                }
                let (c, radius) = bounding_cap(&dirs[start..]);
                centres.push(c);
                radii.push(radius);
                while texels.len() % LANES != 0 {
                    texels.push(u32::MAX);
                    dirs.push(Vec3::Y);
                }
                cell_starts.push(texels.len());
            }
        }
        // The blocks of 2 × 2 cells (fewer at the square's last row and column).
        let gb = g.div_ceil(2);
        let mut block_of = vec![0; g * g];
        let (mut block_centres, mut block_radii) = (Vec::new(), Vec::new());
        for bj in 0..gb {
            for bi in 0..gb {
                let b = block_centres.len();
                let cells: Vec<usize> = (2 * bj..(2 * bj + 2).min(g))
                    .flat_map(|cj| (2 * bi..(2 * bi + 2).min(g)).map(move |ci| cj * g + ci))
                    .collect();
                let block_dirs: Vec<Vec3> = cells
                    .iter()
                    .flat_map(|&c| cell_starts[c]..cell_starts[c + 1])
                    .filter(|&t| texels[t] != u32::MAX)
                    .map(|t| dirs[t])
                    .collect();
                let (c, radius) = bounding_cap(&block_dirs);
                block_centres.push(c);
                block_radii.push(radius);
                for cell in cells {
                    block_of[cell] = b;
                }
            }
        }
        CandidateGrid {
            domain,
            side,
            texels,
            dx: dirs.iter().map(|d| d.x).collect(),
            dy: dirs.iter().map(|d| d.y).collect(),
            dz: dirs.iter().map(|d| d.z).collect(),
            cell_starts,
            centres,
            radii,
            block_of,
            block_centres,
            block_radii,
            block_candidates: Vec::new(),
            block_starts: Vec::new(),
            all: Vec::new(),
            candidates: Vec::new(),
            starts: Vec::new(),
            seeds: DirectionsSoa::default(),
            dots: Vec::new(),
        }
    }

    fn cell_count(&self) -> usize {
        self.centres.len()
    }

    fn fill_candidates(&mut self, seeds: &[Vec3]) {
        self.seeds.clear();
        self.seeds.extend(seeds.iter().copied());
        if self.all.len() != seeds.len() {
            self.all = (0..seeds.len() as u16).collect();
        }
        self.block_candidates.clear();
        self.block_starts.clear();
        self.block_starts.push(0);
        for (&centre, &radius) in self.block_centres.iter().zip(&self.block_radii) {
            gather_candidates(
                &self.seeds,
                &self.all,
                centre,
                radius,
                &mut self.dots,
                &mut self.block_candidates,
            );
            self.block_starts.push(self.block_candidates.len());
        }
        self.candidates.clear();
        self.starts.clear();
        self.starts.push(0);
        for (c, (&centre, &radius)) in self.centres.iter().zip(&self.radii).enumerate() {
            let b = self.block_of[c];
            let from = &self.block_candidates[self.block_starts[b]..self.block_starts[b + 1]];
            gather_candidates(
                &self.seeds,
                from,
                centre,
                radius,
                &mut self.dots,
                &mut self.candidates,
            );
            self.starts.push(self.candidates.len());
        }
    }

    fn candidates(&self, cell: usize) -> &[u16] {
        &self.candidates[self.starts[cell]..self.starts[cell + 1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 40) as f32) / (1u64 << 24) as f32
    }

    /// A skewed density: mostly dim, a few texels 10⁴–10⁶ × brighter (a sun, lamps).
    fn skewed(len: usize, seed: u64) -> Vec<f32> {
        let mut s = seed;
        (0..len)
            .map(|_| {
                let u = lcg(&mut s);
                if u < 0.003 {
                    1e4 + 1e6 * lcg(&mut s)
                } else {
                    0.1 + u
                }
            })
            .collect()
    }

    /// The candidate lists hold, for every texel, a light as near as the nearest of all: the
    /// cells' lists are cut from their blocks', and the square's sides include cells and blocks
    /// cut short by its edge.
    #[test]
    fn every_texel_finds_its_nearest_light_among_its_cells_candidates() {
        let mut state = 9u64;
        for (domain, side, n) in [
            (Domain::Sphere, 64, 1),
            (Domain::Sphere, 70, 7),
            (Domain::Upper, 44, 64),
            (Domain::Sphere, 102, 300),
        ] {
            let seeds: Vec<Vec3> = (0..n)
                .map(|_| {
                    let v = Vec3::new(lcg(&mut state), lcg(&mut state), lcg(&mut state));
                    (2.0 * v - Vec3::ONE).normalize_or(Vec3::Y)
                })
                .collect();
            let mut grid = CandidateGrid::new(domain, side);
            grid.fill_candidates(&seeds);
            let mut listed = 0usize;
            for cell in 0..grid.cell_count() {
                let cands = grid.candidates(cell);
                listed += cands.len();
                for t in grid.cell_starts[cell]..grid.cell_starts[cell + 1] {
                    if grid.texels[t] == u32::MAX {
                        continue;
                    }
                    let d = Vec3::new(grid.dx[t], grid.dy[t], grid.dz[t]);
                    let best = seeds.iter().map(|s| s.dot(d)).fold(-2.0f32, f32::max);
                    let found = cands
                        .iter()
                        .map(|&k| seeds[k as usize].dot(d))
                        .fold(-2.0f32, f32::max);
                    assert_eq!(found, best, "{domain:?} side {side} N={n}: texel {t}");
                }
            }
            // And the lists prune: far fewer than every light in every cell once N is large.
            if n >= 64 {
                assert!(
                    listed < grid.cell_count() * n / 4,
                    "{listed} candidates listed"
                );
            }
        }
    }

    /// The vectorised helpers agree with plain loops: the lane sum with a sequential f64 sum to
    /// rounding, the lane maximum exactly, at lengths with and without a tail; and the density
    /// reads NaN, infinite and negative luminances as 0.
    #[test]
    fn lane_sums_and_maxima_match_plain_loops() {
        for len in [0usize, 1, 7, 8, 9, 100, 4099] {
            let v = skewed(len, len as u64 + 7);
            let plain: f64 = v.iter().map(|&x| x as f64).sum();
            assert!(
                (sum_f64(&v) - plain).abs() <= 1e-12 * plain.max(1.0),
                "len {len}"
            );
            let max = v.iter().copied().fold(-1.0f32, f32::max);
            assert_eq!(max_f32(&v, -1.0), max, "len {len}");
        }
        let p = Placement {
            exponent: 0.5,
            max_seeds_per_texel: 0.0,
            uniform_share: 0.0,
        };
        let mut d = Vec::new();
        p.density(&[f32::NAN, f32::INFINITY, -1.0, 0.0, 4.0], 4, &mut d);
        assert_eq!(d, [0.0, 0.0, 0.0, 0.0, 2.0]);
    }

    /// The lane-wise nearest neighbour is the plain loop's (the first of equals), at lengths with
    /// and without a tail, with repeated directions, and a lone direction is its own.
    #[test]
    fn the_nearest_other_direction_matches_a_plain_loop() {
        let mut s = 11u64;
        for len in [1usize, 2, 7, 8, 9, 17, 256, 300] {
            let mut dirs: Vec<Vec3> = (0..len)
                .map(|_| {
                    let (u, v) = (lcg(&mut s), lcg(&mut s));
                    let (y, phi) = (1.0 - 2.0 * u, std::f32::consts::TAU * v);
                    let r = (1.0 - y * y).max(0.0).sqrt();
                    Vec3::new(r * phi.cos(), y, r * phi.sin())
                })
                .collect();
            // Exact ties: a direction repeated further on.
            if len > 9 {
                dirs[len - 1] = dirs[3];
                dirs[len - 2] = dirs[3];
            }
            let mut soa = DirectionsSoa::default();
            soa.extend(dirs.iter().copied());
            for k in 0..len {
                let mut plain = (f32::NEG_INFINITY, k);
                for (j, d) in dirs.iter().enumerate().filter(|&(j, _)| j != k) {
                    let v = dirs[k].x * d.x + dirs[k].y * d.y + dirs[k].z * d.z;
                    if v > plain.0 {
                        plain = (v, j);
                    }
                }
                assert_eq!(nearest_other(&soa, k), plain.1, "len {len}, k {k}");
            }
        }
    }

    /// The cap holds (no texel expects more than c of the N seeds, to rounding), texels under it
    /// are untouched, and the level is the root of C = c·Σ min(d, C)/N: checked against bisection.
    #[test]
    fn the_capped_density_meets_its_cap_and_solves_the_water_level() {
        for (seed, n) in [(1u64, 16usize), (2, 64), (3, 256), (4, 1024)] {
            let lum = skewed(128 * 128, seed);
            let p = Placement {
                exponent: 1.0,
                max_seeds_per_texel: 0.5,
                uniform_share: 0.0,
            };
            let mut d = Vec::new();
            p.density(&lum, n, &mut d);
            let total: f64 = d.iter().map(|&v| v as f64).sum();
            let cap = d.iter().copied().fold(0.0f32, f32::max) as f64;
            assert!(
                n as f64 * cap / total <= 0.5 * (1.0 + 1e-5),
                "N={n}: {} seeds in the brightest texel",
                n as f64 * cap / total
            );
            for (a, b) in lum.iter().zip(&d) {
                assert!(*b == a.min(cap as f32), "N={n}: {a} → {b} with cap {cap}");
            }
            // Bisection on g(C) = c·S(C)/N − C.
            let g =
                |c: f64| 0.5 * lum.iter().map(|&v| (v as f64).min(c)).sum::<f64>() / n as f64 - c;
            let (mut lo, mut hi) = (1e-9, 2e6);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if g(mid) > 0.0 { lo = mid } else { hi = mid }
            }
            assert!(
                (cap - lo).abs() <= 1e-4 * lo,
                "N={n}: level {cap} vs bisection {lo}"
            );
        }
    }

    /// A limited step turns along the great circle by exactly the step, and a target within it
    /// is reached exactly.
    #[test]
    fn a_limited_step_turns_by_the_step_along_the_great_circle() {
        let from = Vec3::new(1.0, 0.2, -0.3).normalize();
        let to = Vec3::new(-0.2, 0.9, 0.4).normalize();
        let step = 3f32.to_radians();
        let d = step_toward(from, to, step);
        assert!((angle(from, d) - step).abs() < 1e-5, "{}", angle(from, d));
        assert!((angle(from, d) + angle(d, to) - angle(from, to)).abs() < 1e-5);
        assert_eq!(step_toward(from, to, angle(from, to) + 1e-3), to);
        assert!((angle(from, Vec3::Y) - Vec3::Y.angle_between(from)).abs() < 1e-5);
    }

    /// Exponents in eighths by square roots equal powf; the uniform share adds β × the mean.
    #[test]
    fn exponents_and_the_uniform_share_shape_the_density_as_stated() {
        let lum = skewed(4096, 9);
        for k in 1..=8 {
            let e = k as f32 / 8.0;
            let p = Placement {
                exponent: e,
                max_seeds_per_texel: 0.0,
                uniform_share: 0.0,
            };
            let mut d = Vec::new();
            p.density(&lum, 64, &mut d);
            for (a, b) in lum.iter().zip(&d) {
                let want = a.powf(e);
                assert!(
                    (b - want).abs() <= 1e-5 * want,
                    "e = {e}: {a} → {b}, powf {want}"
                );
            }
        }
        let p = Placement {
            exponent: 0.5,
            max_seeds_per_texel: 0.0,
            uniform_share: 0.25,
        };
        let mut d = Vec::new();
        p.density(&lum, 64, &mut d);
        let mean = lum.iter().map(|v| v.sqrt() as f64).sum::<f64>() / lum.len() as f64;
        for (a, b) in lum.iter().zip(&d) {
            let want = a.sqrt() as f64 + 0.25 * mean;
            assert!((*b as f64 - want).abs() <= 1e-4 * want);
        }
    }
}
