//! Ground shadows of a light set (ALGORITHMS.md §9): occluders on a ground plane y = 0, probes on
//! the ground around them (normal +Y), the reference irradiance from emitters with exact
//! ray–occluder visibility, and E_N from lights with each light's visibility averaged over its
//! disc (§12). The evaluation's scenes and sky emitters are in `eval::shadowed`; the geometry is
//! here, below the evaluation, so that an extraction can check a choice by its shadows too.

use super::Light;
use super::error::relative_error;
use glam::DVec3;

/// Rays per light for the visibility averaged over its disc.
pub const CONE_SAMPLES: usize = 32;

/// An occluder above the ground plane.
#[derive(Clone, Copy, Debug)]
pub enum Occluder {
    Sphere {
        centre: DVec3,
        radius: f64,
    },
    /// An axis-aligned box.
    Box {
        min: DVec3,
        max: DVec3,
    },
}

impl Occluder {
    /// A bounding sphere, for the cheap rejection test.
    fn bound(&self) -> (DVec3, f64) {
        match *self {
            Occluder::Sphere { centre, radius } => (centre, radius),
            Occluder::Box { min, max } => ((min + max) * 0.5, (max - min).length() * 0.5),
        }
    }

    /// Whether the ray p + t·d, t > 0, hits the occluder.
    pub fn hit(&self, p: DVec3, d: DVec3) -> bool {
        match *self {
            Occluder::Sphere { centre, radius } => ray_hits_sphere(p, d, centre, radius),
            Occluder::Box { min, max } => {
                let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
                for a in 0..3 {
                    let (o, v) = (p[a], d[a]);
                    if v.abs() < 1e-15 {
                        if o < min[a] || o > max[a] {
                            return false;
                        }
                        continue;
                    }
                    let (mut ta, mut tb) = ((min[a] - o) / v, (max[a] - o) / v);
                    if ta > tb {
                        std::mem::swap(&mut ta, &mut tb);
                    }
                    t0 = t0.max(ta);
                    t1 = t1.min(tb);
                    if t0 > t1 {
                        return false;
                    }
                }
                t1 > 0.0
            }
        }
    }

    /// Whether the ground point `p` lies under (inside the footprint of) the occluder.
    fn covers(&self, p: DVec3) -> bool {
        match *self {
            Occluder::Sphere { centre, radius } => {
                centre.y <= radius && (p - centre).length() < radius
            }
            Occluder::Box { min, max } => {
                min.y <= 1e-9 && p.x > min.x && p.x < max.x && p.z > min.z && p.z < max.z
            }
        }
    }
}

fn ray_hits_sphere(p: DVec3, d: DVec3, c: DVec3, r: f64) -> bool {
    let oc = c - p;
    let b = oc.dot(d);
    if b <= 0.0 {
        return false;
    }
    oc.length_squared() - b * b < r * r
}

/// A ground plane with occluders and its probe points.
#[derive(Clone, Debug)]
pub struct ShadowScene {
    pub name: &'static str,
    pub occluders: Vec<Occluder>,
    pub probes: Vec<DVec3>,
}

impl ShadowScene {
    /// `occluders` with probes on a grid of `step` over the square of half-side `half` about the
    /// origin, except under an occluder.
    pub fn new(name: &'static str, occluders: Vec<Occluder>, half: f64, step: f64) -> Self {
        let n = (2.0 * half / step).round() as i64;
        let mut probes = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let p = DVec3::new(-half + i as f64 * step, 0.0, -half + j as f64 * step);
                if !occluders.iter().any(|o| o.covers(p)) {
                    probes.push(p);
                }
            }
        }
        ShadowScene {
            name,
            occluders,
            probes,
        }
    }

    /// Whether the ray from ground point `p` toward `d` is blocked.
    fn blocked(&self, p: DVec3, d: DVec3) -> bool {
        self.occluders.iter().any(|o| o.hit(p, d))
    }
}

/// The reference irradiance of one scene at its probes, brute force over `emitters` (unit
/// direction, luminance × sr × ω_y: the evaluation's `sky_emitters`, or a domain square's bins).
pub struct ShadowReference {
    truth: Vec<f64>,
}

impl ShadowReference {
    /// On up to 8 threads (the evaluation's references are large).
    pub fn new(scene: &ShadowScene, emitters: &[(DVec3, f64)]) -> Self {
        let open: f64 = emitters.iter().map(|e| e.1).sum();
        let per_probe = |p: &DVec3| {
            // Only directions inside an occluder's bounding cap can be blocked.
            let caps = bounding_caps(scene, *p);
            let mut blocked = 0.0;
            for &(d, w) in emitters {
                if caps.iter().any(|(a, cos)| d.dot(*a) >= *cos) && scene.blocked(*p, d) {
                    blocked += w;
                }
            }
            open - blocked
        };
        let threads = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
            .min(8);
        let chunk = scene.probes.len().div_ceil(threads).max(1);
        let truth = std::thread::scope(|s| {
            let handles: Vec<_> = scene
                .probes
                .chunks(chunk)
                .map(|ps| s.spawn(move || ps.iter().map(per_probe).collect::<Vec<f64>>()))
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().expect("probe thread"))
                .collect()
        });
        ShadowReference { truth }
    }

    /// Relative RMS of a light set's shadowed irradiance against the reference.
    pub fn error(&self, scene: &ShadowScene, lights: &[Light]) -> f64 {
        relative_error(&lights_irradiance(scene, lights), &self.truth).rel_rms
    }

    pub fn truth(&self) -> &[f64] {
        &self.truth
    }
}

/// E_N at every probe of `scene`: each light's luminance × max(0, l_y) × its disc-averaged
/// visibility; a light with a two-part extent, each part's share of that over its own disc (the
/// core's about its own direction).
pub fn lights_irradiance(scene: &ShadowScene, lights: &[Light]) -> Vec<f64> {
    struct Rays {
        dirs: Vec<DVec3>,
        weight: f64,
        axis: DVec3,
        /// The widest angle of a ray from the axis.
        spread: f64,
        /// Rays above the horizon: the open count where no occluder can block one.
        up: usize,
    }
    let parts = lights
        .iter()
        .filter(|l| l.to_light[1] > 0.0 && l.luminance() > 0.0)
        .flat_map(|l| {
            let [core, rest] = match l.extent {
                Some(e) => e.parts(l.dir()).map(Some),
                None => [Some((1.0, l.angular_radius, l.dir())), None],
            };
            [core, rest].into_iter().flatten().map(move |p| (l, p))
        });
    let rays: Vec<Rays> = parts
        .map(|(l, (share, radius, axis))| {
            let dirs = disc_rays(axis, radius as f64);
            let spread = dirs
                .iter()
                .map(|r| r.dot(axis).clamp(-1.0, 1.0).acos())
                .fold(0.0, f64::max);
            let up = dirs.iter().filter(|r| r.y > 0.0).count();
            Rays {
                dirs,
                // The light's cosine for either part: shading is by `to_light` (§9's E_N).
                weight: share * l.luminance() * l.dir().y,
                axis,
                spread,
                up,
            }
        })
        .collect();
    scene
        .probes
        .iter()
        .map(|&p| {
            // A light whose disc clears every occluder's bounding cap is open on all its rays.
            let caps: Vec<(DVec3, f64)> = bounding_caps(scene, p)
                .into_iter()
                .map(|(a, cos)| (a, cos.clamp(-1.0, 1.0).acos()))
                .collect();
            rays.iter()
                .map(|r| {
                    let clear = caps.iter().all(|(a, angle)| {
                        r.axis.dot(*a).clamp(-1.0, 1.0).acos() > angle + r.spread + 1e-9
                    });
                    let open = if clear {
                        r.up
                    } else {
                        r.dirs
                            .iter()
                            .filter(|d| d.y > 0.0 && !scene.blocked(p, **d))
                            .count()
                    };
                    r.weight * open as f64 / r.dirs.len() as f64
                })
                .sum()
        })
        .collect()
}

/// Each occluder's bounding cap seen from ground point `p`: its axis and the cosine of its
/// half-angle (−1 where `p` is inside the bound: every direction may be blocked).
fn bounding_caps(scene: &ShadowScene, p: DVec3) -> Vec<(DVec3, f64)> {
    scene
        .occluders
        .iter()
        .map(|o| {
            let (c, r) = o.bound();
            let to = c - p;
            let dist = to.length();
            let cos = if dist <= r {
                -1.0
            } else {
                (1.0 - (r / dist).powi(2)).max(0.0).sqrt()
            };
            (to / dist.max(1e-12), cos)
        })
        .collect()
}

/// Rays spread evenly (Vogel spiral, equal area) over the disc of angular radius `radius` about `d`;
/// the single ray `d` when the radius is below 0.01°.
pub fn disc_rays(d: DVec3, radius: f64) -> Vec<DVec3> {
    if radius < 0.01f64.to_radians() {
        return vec![d];
    }
    let radius = radius.min(std::f64::consts::FRAC_PI_2);
    let (u, v) = d.any_orthonormal_pair();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    // Equal-area rings on the spherical cap: 1 − cos γ uniform in [0, 1 − cos R].
    let top = 1.0 - radius.cos();
    (0..CONE_SAMPLES)
        .map(|i| {
            let c = 1.0 - top * (i as f64 + 0.5) / CONE_SAMPLES as f64;
            let s = (1.0 - c * c).max(0.0).sqrt();
            let phi = golden * i as f64;
            (d * c + (u * phi.cos() + v * phi.sin()) * s).normalize()
        })
        .collect()
}
