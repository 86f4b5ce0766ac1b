//! The scene the lights fall on: triangle meshes (an OBJ via `tobj`, boxes, a ground plane), their
//! materials, their bounds, and the camera. The bottom of the render tree: it uses no other render
//! module.
//!
//! Input: an OBJ path (or none for the built-in layout). Output: a [`Scene`], one vertex and one index
//! list whose first [`Scene::caster_indices`] indices are the shadow casters (mesh and boxes) and the
//! rest receive shadows only (the ground plane), so the shadow pass draws a prefix of the index buffer.
//! For the passes, [`Scene::bucketed`] reorders the triangles by material class and normal bin
//! ([`BIN_SIDE`]² octahedral bins), each run with the cone that holds its normals (ALGORITHMS.md §6,
//! culling by normal extent), and [`SceneBuffers`] holds the result on the device.

use anyhow::{Context, bail};
use glam::{Mat4, Vec2, Vec3};
use std::ops::Range;
use std::path::Path;

/// One vertex as the shading and shadow passes read it (`shaders/shade.wgsl`, `VertexInput`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    /// Diffuse albedo ρ (linear RGB, 0..1).
    pub albedo: [f32; 3],
    /// Glossy lobe: [k_s, shininess s] of the normalized Blinn-Phong term (see [`Material`]).
    pub gloss: [f32; 2],
}

/// A surface's BRDF: Lambert plus normalized Blinn-Phong,
/// f(l, v) = ρ/π + k_s · (s + 8)/(8π) · (n·h)^s, with h = normalize(l + v).
/// The (s + 8)/(8π) factor (Akenine-Möller et al., *Real-Time Rendering*, 3rd ed., eq. 7.49) keeps the
/// lobe's reflected energy near k_s for any s, so ρ + k_s ≤ 1 is a plausible material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    pub albedo: [f32; 3],
    pub specular: f32,
    pub shininess: f32,
}

impl Material {
    /// Lambertian only: the shading is exactly DESIGN.md's diffuse formula.
    pub const fn diffuse(albedo: [f32; 3]) -> Self {
        Material {
            albedo,
            specular: 0.0,
            shininess: 1.0,
        }
    }
    /// The bunny: a glazed ceramic look.
    pub const GLAZED: Material = Material {
        albedo: [0.62, 0.6, 0.56],
        specular: 0.25,
        shininess: 64.0,
    };
    pub const GROUND: Material = Material::diffuse([0.5, 0.5, 0.5]);
    pub const BOX: Material = Material::diffuse([0.7, 0.45, 0.3]);
}

/// Axis-aligned bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    pub fn centre(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }
    /// Radius of the sphere around [`Aabb::centre`] that holds the box.
    pub fn radius(&self) -> f32 {
        0.5 * (self.max - self.min).length()
    }
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }
}

/// A triangle mesh as loaded from a file, before placement.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex unit normals (from the file, or area-weighted face normals when it has none).
    pub normals: Vec<Vec3>,
    pub indices: Vec<u32>,
}

impl Mesh {
    /// Loads every object of an OBJ file into one mesh (triangulated, one index per vertex).
    pub fn load_obj(path: &Path) -> anyhow::Result<Mesh> {
        // tobj's own open error carries no reason ("open file failed"): open the file here.
        let file = std::fs::File::open(path)
            .with_context(|| format!("reading the mesh {}", path.display()))?;
        let mut reader = std::io::BufReader::new(file);
        let (models, _materials) = tobj::load_obj_buf(&mut reader, &Self::OBJ_OPTIONS, |_| {
            // Materials are not used: an .mtl file is not read.
            Err(tobj::LoadError::OpenFileFailed)
        })
        .with_context(|| format!("reading the mesh {}", path.display()))?;
        Self::from_models(&models).with_context(|| format!("the mesh {}", path.display()))
    }

    /// The built-in mesh: the low-resolution Stanford bunny (tests/data/bunny-low.obj, see
    /// tests/data/LICENSE-bunny.txt), so the viewer runs with no files at hand.
    pub fn builtin_bunny() -> Mesh {
        const OBJ: &str = include_str!("../../tests/data/bunny-low.obj");
        let mut reader = std::io::BufReader::new(OBJ.as_bytes());
        let (models, _) = tobj::load_obj_buf(&mut reader, &Self::OBJ_OPTIONS, |_| {
            Err(tobj::LoadError::OpenFileFailed)
        })
        .expect("the built-in bunny parses");
        Self::from_models(&models).expect("the built-in bunny has triangles")
    }

    const OBJ_OPTIONS: tobj::LoadOptions = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };

    fn from_models(models: &[tobj::Model]) -> anyhow::Result<Mesh> {
        let mut mesh = Mesh {
            positions: Vec::new(),
            normals: Vec::new(),
            indices: Vec::new(),
        };
        let mut all_have_normals = true;
        for model in models {
            let m = &model.mesh;
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(
                m.positions
                    .chunks_exact(3)
                    .map(|p| Vec3::new(p[0], p[1], p[2])),
            );
            if m.normals.len() == m.positions.len() {
                mesh.normals.extend(
                    m.normals
                        .chunks_exact(3)
                        .map(|n| Vec3::new(n[0], n[1], n[2])),
                );
            } else {
                all_have_normals = false;
            }
            mesh.indices.extend(m.indices.iter().map(|i| i + base));
        }
        if mesh.indices.is_empty() {
            bail!("holds no triangles");
        }
        if !all_have_normals || mesh.normals.iter().any(|n| !n.is_finite()) {
            mesh.normals = smooth_normals(&mesh.positions, &mesh.indices);
        } else {
            for n in &mut mesh.normals {
                *n = n.normalize_or(Vec3::Y);
            }
        }
        Ok(mesh)
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for &p in &self.positions {
            b.grow(p);
        }
        b
    }

    /// The transform that scales the mesh to `height` and stands it on y = 0, centred on x = z = 0.
    pub fn placement(&self, height: f32) -> Mat4 {
        let b = self.bounds();
        let extent = (b.max - b.min).max_element().max(f32::MIN_POSITIVE);
        let s = height / (b.max.y - b.min.y).max(extent * 1e-3);
        let foot = Vec3::new(b.centre().x, b.min.y, b.centre().z);
        Mat4::from_scale(Vec3::splat(s)) * Mat4::from_translation(-foot)
    }
}

/// Area-weighted vertex normals: each face adds its unnormalized cross product to its corners.
pub fn smooth_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; positions.len()];
    for t in indices.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            normals[i as usize] += n;
        }
    }
    // A vertex on no face (or only on degenerate ones) gets +Y rather than NaN.
    normals
        .into_iter()
        .map(|n| n.normalize_or(Vec3::Y))
        .collect()
}

/// Everything drawn: casters first, then receivers.
#[derive(Clone, Debug)]
pub struct Scene {
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
    /// Indices `0..caster_indices` cast shadows (the shadow pass draws only these).
    pub caster_indices: u32,
    /// Bounds of the shadow casters (the shadow maps are fitted to their bounding sphere).
    pub caster_bounds: Aabb,
    /// Bounds of everything.
    pub bounds: Aabb,
    /// Whether a receiver has been added (casters must all come first).
    receivers_started: bool,
}

impl Default for Scene {
    fn default() -> Self {
        Scene {
            vertices: Vec::new(),
            indices: Vec::new(),
            caster_indices: 0,
            caster_bounds: Aabb::EMPTY,
            bounds: Aabb::EMPTY,
            receivers_started: false,
        }
    }
}

impl Scene {
    /// The default layout: the mesh, 1 unit tall, on a 6 × 6 ground plane with three boxes.
    pub fn showcase(mesh: &Mesh) -> Scene {
        let mut scene = Scene::default();
        scene.add_mesh(mesh, mesh.placement(1.0), Material::GLAZED);
        scene.add_box(
            Vec3::new(-1.5, 0.0, -0.9),
            Vec3::new(-0.9, 0.6, -0.3),
            Material::BOX,
        );
        scene.add_box(
            Vec3::new(0.9, 0.0, -1.2),
            Vec3::new(1.3, 1.1, -0.8),
            Material::diffuse([0.35, 0.5, 0.7]),
        );
        scene.add_box(
            Vec3::new(0.8, 0.0, 0.6),
            Vec3::new(1.4, 0.25, 1.2),
            Material::diffuse([0.55, 0.65, 0.4]),
        );
        scene.add_ground(0.0, 3.0, Material::GROUND);
        scene
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    fn push(&mut self, position: Vec3, normal: Vec3, m: Material) -> u32 {
        self.vertices.push(Vertex {
            position: position.to_array(),
            normal: normal.to_array(),
            albedo: m.albedo,
            gloss: [m.specular, m.shininess],
        });
        self.bounds.grow(position);
        (self.vertices.len() - 1) as u32
    }

    fn end_caster(&mut self, first_vertex: usize) {
        assert!(
            !self.receivers_started,
            "add every shadow caster before the first receiver"
        );
        self.caster_indices = self.indices.len() as u32;
        for v in &self.vertices[first_vertex..] {
            self.caster_bounds.grow(Vec3::from_array(v.position));
        }
    }

    /// Adds a mesh under `transform` (normals by its inverse transpose).
    pub fn add_mesh(&mut self, mesh: &Mesh, transform: Mat4, m: Material) {
        let first = self.vertices.len();
        let normal_matrix = transform.inverse().transpose();
        let base = first as u32;
        for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
            let n = normal_matrix.transform_vector3(*n).normalize_or(Vec3::Y);
            self.push(transform.transform_point3(*p), n, m);
        }
        self.indices.extend(mesh.indices.iter().map(|i| i + base));
        self.end_caster(first);
    }

    /// Adds an axis-aligned box, counter-clockwise faces seen from outside, flat normals.
    pub fn add_box(&mut self, min: Vec3, max: Vec3, m: Material) {
        let first = self.vertices.len();
        let c = 0.5 * (min + max);
        let h = 0.5 * (max - min);
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut n = Vec3::ZERO;
                n[axis] = sign;
                // Two tangents such that t × b = n (counter-clockwise seen from outside).
                let t = Vec3::from_array(std::array::from_fn(|i| {
                    if i == (axis + 1) % 3 { 1.0 } else { 0.0 }
                }));
                let b = n.cross(t);
                let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                    .map(|(u, v)| c + h * (n + t * u + b * v));
                let base = self.vertices.len() as u32;
                for p in corners {
                    self.push(p, n, m);
                }
                self.indices
                    .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
            }
        }
        self.end_caster(first);
    }

    /// Adds the ground: a square at height `y`, half side `half`, facing +Y; it receives shadows only.
    pub fn add_ground(&mut self, y: f32, half: f32, m: Material) {
        self.receivers_started = true;
        let base = self.vertices.len() as u32;
        for (x, z) in [(-half, half), (half, half), (half, -half), (-half, -half)] {
            self.push(Vec3::new(x, y, z), Vec3::Y, m);
        }
        self.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }

    /// Index ranges: (casters, everything).
    pub fn index_ranges(&self) -> (Range<u32>, Range<u32>) {
        (0..self.caster_indices, 0..self.indices.len() as u32)
    }
}

/// Side B of the B × B grid of normal bins (64 bins of about 25°) that [`Scene::bucketed`] sorts
/// triangles into; the draws, not the shaders, carry the bins (ALGORITHMS.md §6, culling by normal
/// extent).
pub const BIN_SIDE: u32 = 8;

/// Octahedral map of a unit vector to the unit square \[0,1\]², +Y at the centre.
pub fn octahedral_encode(n: Vec3) -> Vec2 {
    let mut p = Vec2::new(n.x, n.z) / (n.x.abs() + n.y.abs() + n.z.abs());
    if n.y < 0.0 {
        let s = Vec2::new(
            if p.x >= 0.0 { 1.0 } else { -1.0 },
            if p.y >= 0.0 { 1.0 } else { -1.0 },
        );
        p = (Vec2::ONE - Vec2::new(p.y.abs(), p.x.abs())) * s;
    }
    p * 0.5 + Vec2::splat(0.5)
}

/// Inverse of [`octahedral_encode`].
pub fn octahedral_decode(uv: Vec2) -> Vec3 {
    let p = uv * 2.0 - Vec2::ONE;
    let y = 1.0 - p.x.abs() - p.y.abs();
    let (x, z) = if y < 0.0 {
        // The lower hemisphere is folded over the square's corners; unfold it.
        (
            (1.0 - p.y.abs()) * p.x.signum(),
            (1.0 - p.x.abs()) * p.y.signum(),
        )
    } else {
        (p.x, p.y)
    };
    Vec3::new(x, y, z).normalize()
}

/// Bin of a unit normal in the B × B octahedral grid (`side` = B).
pub fn bin_of(n: Vec3, side: u32) -> u32 {
    let uv = octahedral_encode(n) * side as f32;
    let i = (uv.x as u32).min(side - 1);
    let j = (uv.y as u32).min(side - 1);
    j * side + i
}

/// A run of triangles drawn in one call, with the cone that holds all their vertex normals.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawRange {
    /// Index range in [`Scene::bucketed`]'s index list.
    pub range: Range<u32>,
    /// Cone axis (unit) and sin of its half-angle α; `sin_alpha = 1` when α ≥ 90°.
    pub axis: Vec3,
    pub sin_alpha: f32,
    /// The triangles have a glossy lobe (k_s > 0); the others are Lambertian.
    pub glossy: bool,
}

impl Scene {
    /// The index list reordered by material class (glossy or Lambertian) and normal bin (B × B
    /// octahedral bins of each triangle's mean vertex normal), casters still first, and one
    /// [`DrawRange`] per non-empty (casters/receivers, class, bin).
    /// A light can reach a triangle of a range only if to_light·axis > −sin α (ALGORITHMS.md §6),
    /// so the shading pass gives each range the short list of lights that pass.
    pub fn bucketed(&self, side: u32) -> (Vec<u32>, Vec<DrawRange>) {
        let normal = |i: u32| Vec3::from_array(self.vertices[i as usize].normal);
        let mut indices = Vec::with_capacity(self.indices.len());
        let mut draws = Vec::new();
        let (casters, all) = self.index_ranges();
        for part in [casters, self.caster_indices..all.end] {
            let tris = &self.indices[part.start as usize..part.end as usize];
            let glossy = |i: u32| self.vertices[i as usize].gloss[0] > 0.0;
            let mut keyed: Vec<(u32, [u32; 3])> = tris
                .chunks_exact(3)
                .map(|t| {
                    let mean = normal(t[0]) + normal(t[1]) + normal(t[2]);
                    let bin = bin_of(mean.normalize_or(Vec3::Y), side);
                    // The class goes above the bin bits: sorting groups each class's bins.
                    let class = t.iter().any(|&i| glossy(i)) as u32;
                    (class << 16 | bin, [t[0], t[1], t[2]])
                })
                .collect();
            // Stable: triangles keep their order within a bin.
            keyed.sort_by_key(|(bin, _)| *bin);
            let mut start = 0;
            while start < keyed.len() {
                let bin = keyed[start].0;
                let end = start + keyed[start..].iter().take_while(|(b, _)| *b == bin).count();
                let first = indices.len() as u32;
                let run = &keyed[start..end];
                let axis = run
                    .iter()
                    .flat_map(|(_, t)| t.map(normal))
                    .sum::<Vec3>()
                    .normalize_or(Vec3::Y);
                let alpha = run
                    .iter()
                    .flat_map(|(_, t)| t.map(normal))
                    .map(|n| axis.dot(n).clamp(-1.0, 1.0).acos())
                    .fold(0.0f32, f32::max)
                    + 1e-3; // rounding margin
                for (_, t) in run {
                    indices.extend_from_slice(t);
                }
                draws.push(DrawRange {
                    range: first..indices.len() as u32,
                    axis,
                    sin_alpha: if alpha >= std::f32::consts::FRAC_PI_2 {
                        1.0
                    } else {
                        alpha.sin()
                    },
                    glossy: bin >> 16 != 0,
                });
                start = end;
            }
        }
        (indices, draws)
    }
}

/// The scene's vertex and index buffers on the device.
pub struct SceneBuffers {
    pub vertices: wgpu::Buffer,
    /// Indices bucketed by normal bin ([`Scene::bucketed`]), casters first.
    pub indices: wgpu::Buffer,
    /// Index range of the shadow casters, and of everything.
    pub casters: Range<u32>,
    pub all: Range<u32>,
    /// The draws of the shading pass, each with its normal cone.
    pub draws: Vec<DrawRange>,
}

impl SceneBuffers {
    pub fn new(device: &wgpu::Device, scene: &Scene) -> SceneBuffers {
        use wgpu::util::DeviceExt;
        let (casters, all) = scene.index_ranges();
        let (indices, draws) = scene.bucketed(BIN_SIDE);
        debug_assert_eq!(indices.len(), scene.indices.len());
        SceneBuffers {
            vertices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("scene vertices"),
                contents: bytemuck::cast_slice(&scene.vertices),
                usage: wgpu::BufferUsages::VERTEX,
            }),
            indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("scene indices"),
                contents: bytemuck::cast_slice(&indices),
                usage: wgpu::BufferUsages::INDEX,
            }),
            casters,
            all,
            draws,
        }
    }
}

/// A perspective camera looking at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
    pub near: f32,
    pub far: f32,
}

impl Camera {
    /// A view of the scene from the front (+Z side), above, framing `bounds`.
    pub fn framing(bounds: &Aabb, azimuth_deg: f32) -> Camera {
        let target = Vec3::new(0.0, 0.35, 0.0);
        let r = bounds.radius().max(1e-3);
        let (s, c) = azimuth_deg.to_radians().sin_cos();
        // 28° above the horizon, at 0.95 of the bounding radius: the ground fills the lower frame.
        let elevation = 28f32.to_radians();
        let dist = 0.95 * r;
        let eye =
            target + dist * Vec3::new(s * elevation.cos(), elevation.sin(), c * elevation.cos());
        Camera {
            eye,
            target,
            fov_y: 45f32.to_radians(),
            near: 0.05 * r,
            far: 4.0 * r,
        }
    }

    /// World → clip (wgpu NDC: y up, z in [0, 1]).
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        use glam::camera::rh::{proj::directx::perspective, view::look_at_mat4};
        perspective(self.fov_y, aspect, self.near, self.far)
            * look_at_mat4(self.eye, self.target, Vec3::Y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_faces_wind_counter_clockwise_outward() {
        let mut s = Scene::default();
        s.add_box(Vec3::splat(-1.0), Vec3::splat(1.0), Material::BOX);
        for t in s.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| Vec3::from(s.vertices[i as usize].position));
            let n = Vec3::from(s.vertices[t[0] as usize].normal);
            let face = (b - a).cross(c - a).normalize();
            assert!(face.dot(n) > 0.99, "face {face} vs normal {n}");
            assert!((a + b + c).dot(n) > 0.0, "normal points outward");
        }
        assert_eq!(s.caster_indices, 36);
    }

    #[test]
    fn placement_stands_the_mesh_on_the_ground() {
        let mesh = Mesh {
            positions: vec![
                Vec3::new(2.0, 5.0, 1.0),
                Vec3::new(4.0, 9.0, 3.0),
                Vec3::new(3.0, 7.0, 5.0),
            ],
            normals: vec![Vec3::Y; 3],
            indices: vec![0, 1, 2],
        };
        let m = mesh.placement(1.0);
        let lo = m.transform_point3(Vec3::new(3.0, 5.0, 3.0));
        let hi = m.transform_point3(Vec3::new(3.0, 9.0, 3.0));
        assert!(lo.abs_diff_eq(Vec3::ZERO, 1e-6), "{lo}");
        assert!((hi.y - 1.0).abs() < 1e-6, "{hi}");
    }

    #[test]
    fn octahedral_round_trip() {
        for k in 0..500 {
            // Fibonacci sphere directions.
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / 500.0;
            let phi = k as f32 * 2.399_963;
            let r = (1.0 - y * y).sqrt();
            let d = Vec3::new(r * phi.cos(), y, r * phi.sin());
            let uv = octahedral_encode(d);
            let back = octahedral_decode(uv);
            assert!(d.dot(back) > 0.99999, "{d} -> {uv} -> {back}");
        }
    }

    #[test]
    fn bins_cover_the_grid() {
        let mut seen = vec![false; (BIN_SIDE * BIN_SIDE) as usize];
        for k in 0..20000 {
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / 20000.0;
            let phi = k as f32 * 2.399_963;
            let r = (1.0 - y * y).sqrt();
            seen[bin_of(Vec3::new(r * phi.cos(), y, r * phi.sin()), BIN_SIDE) as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
    }
}
