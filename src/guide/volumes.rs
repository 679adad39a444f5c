//! Radiance volumes: points spread over the scene's surfaces in proportion to
//! area, each with its surface normal, organised as a k-d tree for exact
//! nearest-neighbour lookup restricted to volumes facing the same way.

use crate::scene::Scene;
use glam::Vec3;

/// A radiance volume, stored as a node of an implicit k-d tree (see
/// [`build_kd_tree`]). Host-side only: kernels see volumes through the
/// lookup tables and their indices.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Volume {
    pub position: [f32; 3],
    /// Splitting coordinate, or [`KD_LEAF`].
    pub axis: u32,
    pub normal: [f32; 3],
}

/// `Volume::axis` of a k-d tree node without children.
pub const KD_LEAF: u32 = 3;

/// Deterministic generator for placement (SplitMix64).
pub(crate) struct SplitMix(pub u64);

impl SplitMix {
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub(crate) fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Area of the surfaces volumes are placed on: every non-emitting triangle.
pub fn placement_area(scene: &Scene) -> f64 {
    scene
        .triangles
        .iter()
        .filter(|t| t.light_pdf == 0.0)
        .map(|t| t.area as f64)
        .sum()
}

/// `count` volumes on the scene's non-emitting triangles, uniform by area.
pub fn place(scene: &Scene, count: usize, seed: u64) -> Vec<Volume> {
    let candidates: Vec<usize> = (0..scene.triangles.len())
        .filter(|&i| scene.triangles[i].light_pdf == 0.0)
        .collect();
    let mut cdf = Vec::with_capacity(candidates.len());
    let mut total = 0.0f64;
    for &i in &candidates {
        total += scene.triangles[i].area as f64;
        cdf.push(total);
    }
    let mut rng = SplitMix(seed ^ 0x5157_5241_4345);
    let mut volumes = Vec::with_capacity(count);
    if candidates.is_empty() || total <= 0.0 {
        return volumes;
    }
    for _ in 0..count {
        let r = rng.next_f32() as f64 * total;
        let k = cdf.partition_point(|&c| c <= r).min(candidates.len() - 1);
        let t = &scene.triangles[candidates[k]];
        let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let (e1, e2) = (Vec3::from(t.e1), Vec3::from(t.e2));
        let p = Vec3::from(t.v0) + u * e1 + v * e2;
        volumes.push(Volume {
            position: p.into(),
            axis: KD_LEAF,
            normal: e1.cross(e2).normalize().into(),
        });
    }
    volumes
}

/// Reorders `volumes` into an implicit k-d tree: the node of range [lo, hi) is
/// its median m = (lo + hi) / 2, with subtrees [lo, m) and [m + 1, hi); each
/// node's `axis` says which coordinate splits it.
pub fn build_kd_tree(volumes: &mut [Volume]) {
    fn build(v: &mut [Volume]) {
        if v.len() <= 1 {
            if let Some(only) = v.first_mut() {
                only.axis = KD_LEAF;
            }
            return;
        }
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in v.iter() {
            lo = lo.min(Vec3::from(p.position));
            hi = hi.max(Vec3::from(p.position));
        }
        let axis = (hi - lo).max_position();
        let m = v.len() / 2;
        v.select_nth_unstable_by(m, |a, b| a.position[axis].total_cmp(&b.position[axis]));
        v[m].axis = axis as u32;
        let (left, rest) = v.split_at_mut(m);
        build(left);
        build(&mut rest[1..]);
    }
    build(volumes);
}

/// Whether a volume may serve a point with normal `n`: it must face the same way.
pub fn faces_same_way(volume: &Volume, n: Vec3) -> bool {
    Vec3::from(volume.normal).dot(n) > 0.0
}

/// Nearest volume facing the same way as `n`, by brute force (test reference).
pub fn nearest_brute(volumes: &[Volume], p: Vec3, n: Vec3) -> Option<u32> {
    volumes
        .iter()
        .enumerate()
        .filter(|(_, v)| faces_same_way(v, n))
        .min_by(|a, b| {
            let da = Vec3::from(a.1.position).distance_squared(p);
            let db = Vec3::from(b.1.position).distance_squared(p);
            da.total_cmp(&db)
        })
        .map(|(i, _)| i as u32)
}

/// The same search through the k-d tree.
pub fn nearest_kd(volumes: &[Volume], p: Vec3, n: Vec3) -> Option<u32> {
    nearest_where(volumes, p, |v| faces_same_way(v, n))
}

/// Nearest volume to `p` among those `accept` lets through, via the k-d tree.
pub fn nearest_where(volumes: &[Volume], p: Vec3, accept: impl Fn(&Volume) -> bool) -> Option<u32> {
    nearest_from(volumes, p, accept, None)
}

/// [`nearest_where`], starting from `hint` (a volume likely near `p`, such
/// as a neighbour's answer) where `accept` lets it through: its distance
/// prunes the walk from the first step. A volume exactly as near as the
/// hint may be returned in its place.
pub fn nearest_from(
    volumes: &[Volume],
    p: Vec3,
    accept: impl Fn(&Volume) -> bool,
    hint: Option<u32>,
) -> Option<u32> {
    let mut best: Option<(f32, u32)> = hint.filter(|&h| accept(&volumes[h as usize])).map(|h| {
        (
            Vec3::from(volumes[h as usize].position).distance_squared(p),
            h,
        )
    });
    let mut stack = vec![(0usize, volumes.len(), 0.0f32)];
    while let Some((lo, hi, plane_d2)) = stack.pop() {
        if lo >= hi || best.is_some_and(|(d, _)| plane_d2 >= d) {
            continue;
        }
        let m = (lo + hi) / 2;
        let v = &volumes[m];
        let d2 = Vec3::from(v.position).distance_squared(p);
        if best.is_none_or(|(d, _)| d2 < d) && accept(v) {
            best = Some((d2, m as u32));
        }
        if v.axis == KD_LEAF {
            continue;
        }
        let a = v.axis as usize;
        let diff = p[a] - v.position[a];
        let (near, far) = if diff < 0.0 {
            ((lo, m), (m + 1, hi))
        } else {
            ((m + 1, hi), (lo, m))
        };
        stack.push((far.0, far.1, diff * diff));
        stack.push((near.0, near.1, 0.0));
    }
    best.map(|(_, i)| i)
}

pub fn dmin2(lo: Vec3, hi: Vec3, p: Vec3) -> f32 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length_squared()
}

/// Calls `f` with every volume (k-d tree order) whose squared distance to the
/// box [lo, hi] is at most `r2`.
pub fn within_box_distance(
    volumes: &[Volume],
    lo: Vec3,
    hi: Vec3,
    r2: f32,
    f: &mut dyn FnMut(u32),
) {
    let mut stack = vec![(0usize, volumes.len())];
    while let Some((a, b)) = stack.pop() {
        if a >= b {
            continue;
        }
        let m = (a + b) / 2;
        let v = &volumes[m];
        let p = Vec3::from(v.position);
        if dmin2(lo, hi, p) <= r2 {
            f(m as u32);
        }
        if v.axis == KD_LEAF {
            continue;
        }
        let axis = v.axis as usize;
        let r = r2.sqrt();
        // Left subtree holds coordinates <= the split, right >= it.
        if lo[axis] - r <= p[axis] {
            stack.push((a, m));
        }
        if hi[axis] + r >= p[axis] {
            stack.push((m + 1, b));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(count: usize, seed: u64) -> Vec<Volume> {
        let mut rng = SplitMix(seed);
        (0..count)
            .map(|_| {
                let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 10.0;
                let n =
                    (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5).normalize();
                Volume {
                    position: p.into(),
                    axis: KD_LEAF,
                    normal: n.into(),
                }
            })
            .collect()
    }

    #[test]
    fn kd_tree_search_equals_brute_force() {
        let mut vols = cloud(3000, 1);
        build_kd_tree(&mut vols);
        let queries = cloud(2000, 2);
        for q in &queries {
            let (p, n) = (Vec3::from(q.position), Vec3::from(q.normal));
            let a = nearest_kd(&vols, p, n).unwrap();
            let b = nearest_brute(&vols, p, n).unwrap();
            let da = Vec3::from(vols[a as usize].position).distance(p);
            let db = Vec3::from(vols[b as usize].position).distance(p);
            assert_eq!(da, db, "query {p} {n}");
            assert!(faces_same_way(&vols[a as usize], n));
        }
    }

    #[test]
    fn never_uses_a_volume_behind_a_thin_wall() {
        // Two sides of a wall 0.01 thick: the nearer volume faces the other way.
        let mut vols = vec![
            Volume {
                position: [0.0, 0.005, 0.0],
                axis: KD_LEAF,
                normal: [0.0, 1.0, 0.0],
            },
            Volume {
                position: [3.0, -0.005, 0.0],
                axis: KD_LEAF,
                normal: [0.0, -1.0, 0.0],
            },
        ];
        build_kd_tree(&mut vols);
        let i = nearest_kd(&vols, Vec3::new(0.0, -0.005, 0.0), Vec3::NEG_Y).unwrap();
        assert_eq!(vols[i as usize].normal, [0.0, -1.0, 0.0]);
    }
}
