//! Shadow groups: which lights share one shadow map (ALGORITHMS.md §6, "Clustering").
//!
//! Input: the frame's [`Light`]s. Output: a [`Grouping`], lights ordered so that each [`Group`]'s
//! members are contiguous, each group with a stable key (its shadow map follows the key through time)
//! and an axis (the direction its shadow map is drawn from). A leaf of the render tree (it uses only
//! [`crate::lights`]): the shadow maps are kept per group and the shading pass loops over groups.
//!
//! Lights closer than δ to a group's axis join it (the sun: most of a clear sky's energy sits within a
//! few degrees, and the importance-sampled set puts many lights there). A light dimmer than the
//! frame's mean light may join from farther: its radius is δ · Ē/E (E its luminance, Ē the mean),
//! at most [`MAX_RADIUS_SCALE`] δ. Moving a light's shadow by an angle α misplaces about E·α of
//! radiance, so every light's shadow error stays within what a mean light's is at δ, and the dim
//! lights of the sky and the ground, which carry little of the energy, stop costing a shadow map
//! each. Hysteresis keeps groups from popping: a light stays in last frame's group while it is
//! within 1.5 times its radius of that group's axis, and only joins a new group within its radius.
//! With clustering off every light is its own group.
//!
//! A shadow budget (docs/RENDER.md, "The shadow budget"): when the lights carry marks
//! (`Light::shadowed`, `budget::mark`), the lights marked `Some(false)` are grouped apart, by a
//! second clusterer, into groups with `shadowed: false`, which get no shadow map and are shaded as
//! unoccluded. They are still grouped (rather than put in one group) so that culling by normal
//! extent keeps working for them. Lights without a mark are shadowed, as before.

use crate::lights::Light;
use glam::Vec3;
use std::collections::HashMap;

/// Lights that share one shadow map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Group {
    /// Stable identity: the shadow-map cache is keyed on it.
    pub key: u32,
    /// Unit direction toward the group (irradiance-weighted mean of its members): the shadow map's view.
    pub axis: Vec3,
    /// Members are `Grouping::order[first..first + count]`.
    pub first: u32,
    pub count: u32,
    /// Whether the group gets a shadow map; `false` for the lights a shadow budget leaves
    /// unshadowed (their keys come from another clusterer and may repeat a shadowed group's).
    pub shadowed: bool,
}

/// The lights of a frame, grouped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Grouping {
    pub groups: Vec<Group>,
    /// Indices into the frame's light slice, group by group.
    pub order: Vec<u32>,
}

/// The largest join radius of a dim light, in multiples of δ.
pub const MAX_RADIUS_SCALE: f32 = 4.0;

/// Forms groups frame after frame, remembering last frame's to apply hysteresis.
#[derive(Debug)]
pub struct Clusterer {
    /// δ in radians (0: clustering off).
    delta: f32,
    /// Per light of the current frame: cos of its join radius, cos of 1.5 × that.
    cos_join: Vec<f32>,
    cos_keep: Vec<f32>,
    /// Light id → group key, from the last frame.
    previous: HashMap<u32, u32>,
    next_key: u32,
    // Scratch, kept between frames so that grouping does not allocate in steady state.
    slots: Vec<Slot>,
    assigned: Vec<Option<usize>>,
    by_power: Vec<usize>,
    /// Groups the lights a shadow budget leaves unshadowed, with its own hysteresis; made when
    /// the first such light arrives.
    unmarked: Option<Box<Clusterer>>,
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    key: u32,
    /// Σ luminance · direction of the members so far.
    sum: Vec3,
    members: u32,
}

impl Slot {
    fn axis(&self) -> Vec3 {
        self.sum.normalize_or(Vec3::Y)
    }
}

impl Clusterer {
    /// `delta_deg`: the join radius δ (2–5° per ALGORITHMS.md §6); 0 turns clustering off.
    pub fn new(delta_deg: f32) -> Clusterer {
        Clusterer {
            delta: delta_deg.max(0.0).to_radians(),
            cos_join: Vec::new(),
            cos_keep: Vec::new(),
            previous: HashMap::new(),
            next_key: 0,
            slots: Vec::new(),
            assigned: Vec::new(),
            by_power: Vec::new(),
            unmarked: None,
        }
    }

    fn enabled(&self) -> bool {
        self.delta > 0.0
    }

    /// Each light's join radius: δ · Ē/E, between δ and [`MAX_RADIUS_SCALE`] δ.
    fn set_radii(&mut self, lights: &[Light]) {
        let mean = lights.iter().map(weight).sum::<f32>() / lights.len().max(1) as f32;
        self.cos_join.clear();
        self.cos_keep.clear();
        for l in lights {
            let radius = self.delta * (mean / weight(l)).clamp(1.0, MAX_RADIUS_SCALE);
            self.cos_join.push(radius.cos());
            self.cos_keep
                .push((1.5 * radius).min(std::f32::consts::PI).cos());
        }
    }

    /// Groups `lights` into `out` (cleared first): the shadowed groups first, then (when some
    /// lights are marked `shadowed: Some(false)`) the unshadowed ones.
    pub fn group(&mut self, lights: &[Light], out: &mut Grouping) {
        if !lights.iter().any(|l| l.shadowed == Some(false)) {
            self.group_all(lights, out);
            return;
        }
        let (lit, unlit): (Vec<usize>, Vec<usize>) =
            (0..lights.len()).partition(|&i| lights[i].shadowed != Some(false));
        let subset = |idx: &[usize]| idx.iter().map(|&i| lights[i]).collect::<Vec<Light>>();
        self.group_all(&subset(&lit), out);
        for o in &mut out.order {
            *o = lit[*o as usize] as u32;
        }
        let degrees = self.delta.to_degrees();
        let unmarked = self
            .unmarked
            .get_or_insert_with(|| Box::new(Clusterer::new(degrees)));
        let mut rest = Grouping::default();
        unmarked.group_all(&subset(&unlit), &mut rest);
        let base = out.order.len() as u32;
        out.groups.extend(rest.groups.into_iter().map(|g| Group {
            first: g.first + base,
            shadowed: false,
            ..g
        }));
        out.order
            .extend(rest.order.into_iter().map(|o| unlit[o as usize] as u32));
    }

    /// Groups every light of `lights`, all shadowed.
    fn group_all(&mut self, lights: &[Light], out: &mut Grouping) {
        out.groups.clear();
        out.order.clear();
        if !self.enabled() {
            // One group per light, keyed by the light's id so its shadow map follows the id.
            for (i, l) in lights.iter().enumerate() {
                out.groups.push(Group {
                    key: l.id,
                    axis: dir(l),
                    first: i as u32,
                    count: 1,
                    shadowed: true,
                });
                out.order.push(i as u32);
            }
            return;
        }
        self.slots.clear();
        self.assigned.clear();
        self.assigned.resize(lights.len(), None);
        self.set_radii(lights);

        // 1. Hysteresis: last frame's groups, rebuilt from the members that are still close.
        let mut slot_of_key: HashMap<u32, usize> = HashMap::new();
        for (i, l) in lights.iter().enumerate() {
            if let Some(&key) = self.previous.get(&l.id) {
                let s = *slot_of_key.entry(key).or_insert_with(|| {
                    self.slots.push(Slot {
                        key,
                        sum: Vec3::ZERO,
                        members: 0,
                    });
                    self.slots.len() - 1
                });
                self.assigned[i] = Some(s);
                self.slots[s].sum += weight(l) * dir(l);
                self.slots[s].members += 1;
            }
        }
        // Members now beyond δ_keep of their group's axis leave it (the axis is recomputed without them).
        for (i, l) in lights.iter().enumerate() {
            if let Some(s) = self.assigned[i]
                && self.slots[s].axis().dot(dir(l)) < self.cos_keep[i]
            {
                self.assigned[i] = None;
                self.slots[s].sum -= weight(l) * dir(l);
                self.slots[s].members -= 1;
            }
        }

        // 2. The rest, brightest first: join the nearest group within δ, or found one.
        self.by_power.clear();
        self.by_power
            .extend((0..lights.len()).filter(|&i| self.assigned[i].is_none()));
        self.by_power.sort_by(|&a, &b| {
            weight(&lights[b])
                .total_cmp(&weight(&lights[a]))
                .then(lights[a].id.cmp(&lights[b].id))
        });
        for k in 0..self.by_power.len() {
            let i = self.by_power[k];
            let d = dir(&lights[i]);
            let nearest = self
                .slots
                .iter()
                .enumerate()
                .filter(|(_, s)| s.members > 0)
                .map(|(j, s)| (j, s.axis().dot(d)))
                .filter(|&(_, c)| c >= self.cos_join[i])
                .max_by(|a, b| a.1.total_cmp(&b.1));
            let s = match nearest {
                Some((j, _)) => j,
                None => {
                    self.slots.push(Slot {
                        key: self.next_key,
                        sum: Vec3::ZERO,
                        members: 0,
                    });
                    self.next_key = self.next_key.wrapping_add(1);
                    self.slots.len() - 1
                }
            };
            self.assigned[i] = Some(s);
            self.slots[s].sum += weight(&lights[i]) * d;
            self.slots[s].members += 1;
        }

        // 3. Emit non-empty groups in order of their first member (lights come in id order, so the
        //    output is deterministic), and remember the assignment for the next frame.
        self.previous.clear();
        let mut group_of_slot: Vec<Option<usize>> = vec![None; self.slots.len()];
        for (i, l) in lights.iter().enumerate() {
            let s = self.assigned[i].expect("every light is assigned");
            if group_of_slot[s].is_none() {
                group_of_slot[s] = Some(out.groups.len());
                out.groups.push(Group {
                    key: self.slots[s].key,
                    axis: self.slots[s].axis(),
                    first: 0,
                    count: 0,
                    shadowed: true,
                });
            }
            out.groups[group_of_slot[s].unwrap()].count += 1;
            self.previous.insert(l.id, self.slots[s].key);
        }
        let mut first = 0;
        for g in &mut out.groups {
            g.first = first;
            first += g.count;
        }
        let mut fill: Vec<u32> = out.groups.iter().map(|g| g.first).collect();
        out.order.resize(lights.len(), 0);
        for i in 0..lights.len() {
            let gi = group_of_slot[self.assigned[i].unwrap()].unwrap();
            out.order[fill[gi] as usize] = i as u32;
            fill[gi] += 1;
        }
    }
}

/// The direction a light's shadow map is drawn from ([`Light::one_map_shadow_dir`]: its core's,
/// where that lies near the light). Shading uses `to_light`.
fn dir(l: &Light) -> Vec3 {
    l.one_map_shadow_dir().as_vec3().normalize_or(Vec3::Y)
}

/// A light's weight in its group's axis: its luminance, with a floor so that black lights still
/// have a direction.
fn weight(l: &Light) -> f32 {
    let [r, g, b] = l.irradiance;
    (0.2126 * r + 0.7152 * g + 0.0722 * b).max(1e-12)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, az_deg: f32, el_deg: f32, power: f32) -> Light {
        let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
        Light {
            id,
            to_light: [el.cos() * az.sin(), el.sin(), -el.cos() * az.cos()],
            irradiance: [power; 3],
            solid_angle: 0.01,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        }
    }

    #[test]
    fn lights_near_the_sun_share_a_group_and_far_ones_do_not() {
        let lights = [
            light(0, 10.0, 20.0, 100.0),
            light(1, 11.0, 20.5, 50.0),
            light(2, 9.0, 19.0, 40.0),
            light(3, 120.0, 40.0, 1.0),
            light(4, 240.0, 60.0, 1.0),
        ];
        let mut c = Clusterer::new(3.0);
        let mut g = Grouping::default();
        c.group(&lights, &mut g);
        assert_eq!(g.groups.len(), 3, "{g:?}");
        assert_eq!(g.groups[0].count, 3);
        assert_eq!(&g.order[..3], &[0, 1, 2]);
        assert_eq!(g.order.len(), 5);
    }

    #[test]
    fn hysteresis_keeps_a_light_that_drifts_between_delta_and_delta_keep() {
        let mut c = Clusterer::new(3.0);
        let mut g = Grouping::default();
        c.group(
            &[light(0, 0.0, 30.0, 10.0), light(1, 2.0, 30.0, 8.0)],
            &mut g,
        );
        assert_eq!(g.groups.len(), 1);
        let key = g.groups[0].key;
        // Light 1 (radius 3° × 9/8 = 3.4°) now 4° from light 0: beyond its radius, within 1.5 times
        // it of the (power-weighted) axis.
        c.group(
            &[
                light(0, 0.0, 30.0, 10.0),
                light(1, 4.0 / 30f32.to_radians().cos(), 30.0, 8.0),
            ],
            &mut g,
        );
        assert_eq!(g.groups.len(), 1, "{g:?}");
        assert_eq!(
            g.groups[0].key, key,
            "the group keeps its key (and its shadow map)"
        );
        // A fresh clusterer puts them apart.
        let mut fresh = Clusterer::new(3.0);
        fresh.group(
            &[
                light(0, 0.0, 30.0, 10.0),
                light(1, 4.0 / 30f32.to_radians().cos(), 30.0, 8.0),
            ],
            &mut g,
        );
        assert_eq!(g.groups.len(), 2);
    }

    #[test]
    fn a_dim_light_joins_from_farther_than_a_bright_one() {
        // Mean luminance 27.5: light 1 (10 %) gets 4 δ = 12°, light 3 (at the mean) δ = 3°.
        let lights = [
            light(0, 0.0, 30.0, 100.0),
            light(1, 8.0, 30.0, 2.5),
            light(2, 180.0, 30.0, 5.0),
            light(3, 188.0, 30.0, 2.5),
        ];
        let mut g = Grouping::default();
        Clusterer::new(3.0).group(&lights, &mut g);
        // 1 joins 0 (7° away, within its 12°); 3 and 2 are both dim: one group.
        assert_eq!(g.groups.len(), 2, "{g:?}");
        // Two lights at the mean power 7° apart stay apart.
        let even = [light(0, 0.0, 30.0, 1.0), light(1, 8.0, 30.0, 1.0)];
        Clusterer::new(3.0).group(&even, &mut g);
        assert_eq!(g.groups.len(), 2, "{g:?}");
    }

    #[test]
    fn lights_a_budget_leaves_unshadowed_are_grouped_apart_without_a_map() {
        // Two lights side by side (they would share a group), one marked, one not; a third unmarked.
        let mut lights = [
            light(0, 0.0, 30.0, 10.0),
            light(1, 1.0, 30.0, 8.0),
            light(2, 120.0, 40.0, 1.0),
        ];
        lights[0].shadowed = Some(true);
        lights[1].shadowed = Some(false);
        lights[2].shadowed = Some(false);
        let mut c = Clusterer::new(3.0);
        let mut g = Grouping::default();
        c.group(&lights, &mut g);
        assert_eq!(g.groups.len(), 3, "{g:?}");
        assert!(g.groups[0].shadowed && g.groups[0].count == 1);
        assert_eq!(g.order[0], 0);
        assert!(g.groups[1..].iter().all(|g| !g.shadowed));
        let mut order = g.order.clone();
        order.sort_unstable();
        assert_eq!(order, [0, 1, 2], "every light once");
        for grp in &g.groups {
            for &i in &g.order[grp.first as usize..(grp.first + grp.count) as usize] {
                assert_eq!(grp.shadowed, lights[i as usize].shadowed == Some(true));
            }
        }
        // Without marks, the same lights are all shadowed and the first two share a map.
        let plain = lights.map(|l| Light {
            shadowed: None,
            ..l
        });
        Clusterer::new(3.0).group(&plain, &mut g);
        assert_eq!(g.groups.len(), 2, "{g:?}");
        assert!(g.groups.iter().all(|g| g.shadowed));
    }

    #[test]
    fn clustering_off_gives_one_group_per_light_keyed_by_id() {
        let mut c = Clusterer::new(0.0);
        let mut g = Grouping::default();
        c.group(
            &[light(7, 0.0, 30.0, 10.0), light(9, 0.5, 30.0, 1.0)],
            &mut g,
        );
        assert_eq!(g.groups.iter().map(|g| g.key).collect::<Vec<_>>(), [7, 9]);
    }
}
