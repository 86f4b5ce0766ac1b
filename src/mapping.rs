//! Equal-area maps between the unit square and the (hemi)sphere.
//!
//! Two domains, both equal-area so that every texel of a W×H square covers the same solid angle:
//! - [`Domain::Upper`]: HDS03 (Havran, Dmitriev, Seidel 2003) — Shirley–Chiu concentric square→disk,
//!   then the equal-area lift onto the upper hemisphere. Jacobian 2π. ALGORITHMS.md §1.
//! - [`Domain::Sphere`]: Clarberg's equal-area octahedral map (2008). Jacobian 4π; the upper
//!   hemisphere is the inner diamond. ALGORITHMS.md §1.
//!
//! Both use the same lift into the world frame of DESIGN.md: local z (the square's centre) is world
//! +Y, square +u is world +X and square +v is world −Z.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// The part of the sphere that lights are taken from, with its equal-area square parameterisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
#[value(rename_all = "lowercase")]
pub enum Domain {
    /// The upper hemisphere (+Y), HDS03 square; the square's boundary is the horizon.
    #[value(alias = "hemisphere")]
    Upper,
    /// The whole sphere, equal-area octahedral square.
    Sphere,
}

impl Domain {
    /// Solid angle covered by the domain, which is also the Jacobian |∂ω/∂u × ∂ω/∂v| of its map.
    pub fn solid_angle(self) -> f64 {
        match self {
            Domain::Upper => 2.0 * PI,
            Domain::Sphere => 4.0 * PI,
        }
    }

    /// The name used on the command line and in the LightSet document.
    pub fn name(self) -> &'static str {
        match self {
            Domain::Upper => "upper",
            Domain::Sphere => "sphere",
        }
    }

    /// Unit square → world direction.
    pub fn square_to_dir(self, uv: DVec2) -> DVec3 {
        let local = match self {
            Domain::Upper => hds03_square_to_hemisphere(uv),
            Domain::Sphere => equal_area_square_to_sphere(uv),
        };
        local_to_world(local)
    }

    /// World direction → unit square; `None` for a direction outside the domain (below the horizon
    /// for [`Domain::Upper`]) or a non-finite one.
    pub fn dir_to_square(self, dir: DVec3) -> Option<DVec2> {
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return None;
        }
        let local = world_to_local(dir.normalize());
        match self {
            Domain::Upper => invert_hds03_hemisphere(local),
            Domain::Sphere => Some(invert_equal_area_sphere(local)),
        }
    }

    /// Whether a world direction lies inside the domain.
    pub fn contains(self, dir: DVec3) -> bool {
        match self {
            Domain::Upper => dir.y >= 0.0,
            Domain::Sphere => true,
        }
    }
}

impl std::str::FromStr for Domain {
    type Err = String;
    /// The names `--domain` takes (and the query parameter `domain=`), aliases included.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        <Domain as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown domain '{s}' (expected 'upper' or 'sphere')"))
    }
}

/// Local frame (z = square centre) → world frame (+Y up, −Z forward): x→X, y→−Z, z→Y.
fn local_to_world(l: DVec3) -> DVec3 {
    DVec3::new(l.x, l.z, -l.y)
}

fn world_to_local(w: DVec3) -> DVec3 {
    DVec3::new(w.x, -w.z, w.y)
}

/// HDS03 forward map, (u,v) ∈ \[0,1\]² → hemisphere, local z up. ALGORITHMS.md §1 steps 1–3.
pub fn hds03_square_to_hemisphere(uv: DVec2) -> DVec3 {
    debug_assert!((-1e-9..=1.0 + 1e-9).contains(&uv.x) && (-1e-9..=1.0 + 1e-9).contains(&uv.y));
    let a = 2.0 * uv.x - 1.0;
    let b = 2.0 * uv.y - 1.0;
    // Degenerate case: the square's centre is the zenith (φ undefined there).
    if a == 0.0 && b == 0.0 {
        return DVec3::Z;
    }
    // Shirley–Chiu concentric map: radius from the larger coordinate, angle from the ratio.
    let (r, phi) = if a * a > b * b {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, FRAC_PI_2 - FRAC_PI_4 * (a / b))
    };
    let (s, c) = phi.sin_cos();
    let rho2 = r * r;
    // Equal-area lift: a disk of area π onto a hemisphere of area 2π.
    let lift = (2.0 - rho2).max(0.0).sqrt();
    DVec3::new(r * c * lift, r * s * lift, 1.0 - rho2)
}

/// HDS03 inverse, hemisphere (local z ≥ 0) → unit square; `None` below the horizon.
/// ALGORITHMS.md §1, the four-sector table.
pub fn invert_hds03_hemisphere(w: DVec3) -> Option<DVec2> {
    if w.z < 0.0 {
        return None;
    }
    let rho = (1.0 - w.z).max(0.0).sqrt();
    // φ wrapped into [−π/4, 7π/4).
    let mut phi = w.y.atan2(w.x);
    if phi < -FRAC_PI_4 {
        phi += 2.0 * PI;
    }
    let k = 4.0 / PI;
    let (a, b) = if phi < FRAC_PI_4 {
        (rho, rho * k * phi)
    } else if phi < 3.0 * FRAC_PI_4 {
        (-rho * k * (phi - FRAC_PI_2), rho)
    } else if phi < 5.0 * FRAC_PI_4 {
        (-rho, -rho * k * (phi - PI))
    } else {
        (rho * k * (phi - 1.5 * PI), -rho)
    };
    Some(DVec2::new((a + 1.0) * 0.5, (b + 1.0) * 0.5).clamp(DVec2::ZERO, DVec2::ONE))
}

/// Clarberg's equal-area octahedral map, (u,v) ∈ \[0,1\]² → sphere, local z up. ALGORITHMS.md §1.
pub fn equal_area_square_to_sphere(uv: DVec2) -> DVec3 {
    let up = 2.0 * uv.x - 1.0;
    let vp = 2.0 * uv.y - 1.0;
    let (au, av) = (up.abs(), vp.abs());
    // Signed distance from the diamond's edge: d < 1 inside (upper hemisphere), d > 1 outside.
    let d = au + av;
    let r = 1.0 - (1.0 - d).abs();
    // Degenerate case: r = 0 at the centre (zenith) and the corners (nadir); φ is undefined there.
    let phi = if r == 0.0 {
        FRAC_PI_4
    } else {
        ((av - au) / r + 1.0) * FRAC_PI_4
    };
    let z = (1.0 - r * r).copysign(1.0 - d);
    let s = r * (2.0 - r * r).max(0.0).sqrt();
    DVec3::new(s * phi.cos().copysign(up), s * phi.sin().copysign(vp), z)
}

/// Inverse of [`equal_area_square_to_sphere`] for a unit vector in the local frame.
pub fn invert_equal_area_sphere(w: DVec3) -> DVec2 {
    let (x, y, z) = (w.x.abs(), w.y.abs(), w.z.abs());
    // r from z = 1 − r² (upper) or −(1 − r²) (lower).
    let r = (1.0 - z).max(0.0).sqrt();
    // φ ∈ [0, π/2] of the first-quadrant point, normalised to [0, 1].
    let phi_n = if x == 0.0 && y == 0.0 {
        0.5
    } else {
        y.atan2(x) / FRAC_PI_2
    };
    // In the first quadrant of the inner diamond: v' − u' = r(2φ_n − 1), u' + v' = r.
    let mut v = phi_n * r;
    let mut u = r - v;
    if w.z < 0.0 {
        // Lower hemisphere: reflect across the diamond's edge u' + v' = 1.
        std::mem::swap(&mut u, &mut v);
        u = 1.0 - u;
        v = 1.0 - v;
    }
    let u = u.copysign(w.x);
    let v = v.copysign(w.y);
    DVec2::new((u + 1.0) * 0.5, (v + 1.0) * 0.5).clamp(DVec2::ZERO, DVec2::ONE)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::lcg;

    #[test]
    fn round_trip_both_domains() {
        let mut s = 7u64;
        for domain in [Domain::Upper, Domain::Sphere] {
            for _ in 0..100_000 {
                let uv = DVec2::new(lcg(&mut s), lcg(&mut s));
                let d = domain.square_to_dir(uv);
                assert!(
                    (d.length() - 1.0).abs() < 1e-12,
                    "{domain:?} {uv} -> {d} not unit"
                );
                let back = domain.dir_to_square(d).expect("inside the domain");
                assert!(
                    (back - uv).abs().max_element() < 1e-12,
                    "{domain:?} uv {uv} -> {d} -> {back}"
                );
            }
        }
    }

    #[test]
    fn jacobian_is_constant() {
        let mut s = 11u64;
        let h = 1e-6;
        for domain in [Domain::Upper, Domain::Sphere] {
            for _ in 0..20_000 {
                let uv = DVec2::new(lcg(&mut s), lcg(&mut s)) * (1.0 - 4.0 * h) + 2.0 * h;
                let du = (domain.square_to_dir(uv + DVec2::X * h)
                    - domain.square_to_dir(uv - DVec2::X * h))
                    / (2.0 * h);
                let dv = (domain.square_to_dir(uv + DVec2::Y * h)
                    - domain.square_to_dir(uv - DVec2::Y * h))
                    / (2.0 * h);
                let jac = du.cross(dv).length();
                // Points within h of a diagonal or the diamond edge straddle a kink of the map;
                // the derivative there is one-sided, skip them.
                let a = (2.0 * uv - 1.0).abs();
                let near_kink = (a.x - a.y).abs() < 4.0 * h || (a.x + a.y - 1.0).abs() < 4.0 * h;
                if !near_kink {
                    assert!(
                        (jac - domain.solid_angle()).abs() < 1e-4,
                        "{domain:?} at {uv}: jacobian {jac}"
                    );
                }
            }
        }
    }

    #[test]
    fn uniform_square_gives_uniform_hemisphere_moments() {
        // E[cos θ] = 1/2, E[cos² θ] = 1/3 for uniform directions on the hemisphere.
        let n = 1000;
        let (mut m1, mut m2) = (0.0, 0.0);
        for i in 0..n {
            for j in 0..n {
                let uv = DVec2::new((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                let y = Domain::Upper.square_to_dir(uv).y;
                m1 += y;
                m2 += y * y;
            }
        }
        let nn = (n * n) as f64;
        assert!((m1 / nn - 0.5).abs() < 1e-5, "E[z] = {}", m1 / nn);
        assert!((m2 / nn - 1.0 / 3.0).abs() < 1e-5, "E[z²] = {}", m2 / nn);
    }

    #[test]
    fn conventions_centre_boundary_and_axes() {
        let c = DVec2::splat(0.5);
        assert!((Domain::Upper.square_to_dir(c) - DVec3::Y).length() < 1e-15);
        assert!((Domain::Sphere.square_to_dir(c) - DVec3::Y).length() < 1e-15);
        // Square +u → +X and +v → −Z, on the horizon at the boundary.
        assert!((Domain::Upper.square_to_dir(DVec2::new(1.0, 0.5)) - DVec3::X).length() < 1e-12);
        assert!((Domain::Upper.square_to_dir(DVec2::new(0.5, 1.0)) + DVec3::Z).length() < 1e-12);
        // The sphere's inner diamond edge is the horizon, its corners the nadir.
        assert!((Domain::Sphere.square_to_dir(DVec2::new(1.0, 0.5)) - DVec3::X).length() < 1e-12);
        assert!((Domain::Sphere.square_to_dir(DVec2::ZERO) + DVec3::Y).length() < 1e-12);
        for t in 0..=100 {
            let t = t as f64 / 100.0;
            for uv in [DVec2::new(t, 0.0), DVec2::new(0.0, t), DVec2::new(t, 1.0)] {
                assert!(Domain::Upper.square_to_dir(uv).y.abs() < 1e-12);
            }
        }
    }

    #[test]
    fn continuous_across_diagonals() {
        let e = 1e-9;
        for domain in [Domain::Upper, Domain::Sphere] {
            for i in 1..200 {
                let t = i as f64 / 200.0;
                let p = DVec2::new(t, t);
                let q = DVec2::new(1.0 - t, t);
                for base in [p, q] {
                    let a = domain.square_to_dir(base + DVec2::new(e, -e));
                    let b = domain.square_to_dir(base - DVec2::new(e, -e));
                    assert!((a - b).length() < 1e-7, "{domain:?} jump at {base}");
                }
            }
        }
    }

    #[test]
    fn below_horizon_is_outside_upper() {
        assert!(
            Domain::Upper
                .dir_to_square(DVec3::new(0.0, -0.1, 1.0))
                .is_none()
        );
        assert!(
            Domain::Sphere
                .dir_to_square(DVec3::new(0.0, -0.1, 1.0))
                .is_some()
        );
        assert!(
            Domain::Sphere
                .dir_to_square(DVec3::new(f64::NAN, 0.0, 1.0))
                .is_none()
        );
    }
}
