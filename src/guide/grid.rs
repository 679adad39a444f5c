//! A lookup grid that makes the exact nearest-volume search cheap on the GPU.
//!
//! Query normals fall into six classes by their dominant axis. For a cell C and
//! class c, any volume facing the same way as *every* normal of the class (an
//! "always-facing" volume i) bounds the answer: the nearest facing volume to
//! any p in C is no farther than i, so no farther than dmax(C, i). The cell's
//! list holds every volume that can face some normal of the class and lies
//! within that bound of the cell. The shader scans the list; cells without
//! geometry, long lists and points outside the grid fall back to the k-d tree,
//! so the search stays exact everywhere.

use super::volumes::nearest_where;
use crate::scene::Scene;
use crate::shaders::{GridHeader, Volume, GRID_FALLBACK, GRID_MAX_LIST, KD_LEAF, NORMAL_CLASSES};
use glam::{UVec3, Vec3};

pub struct LookupGrid {
    pub origin: Vec3,
    pub cell: f32,
    pub dims: UVec3,
    /// Per (cell, class): start and length in `items`; length GRID_FALLBACK
    /// means "use the k-d tree".
    pub ranges: Vec<[u32; 2]>,
    pub items: Vec<u32>,
    /// (cell, class) pairs that surface points can query.
    pub touched_classes: u32,
}

/// The class of a query normal: 2 · dominant axis + (component < 0).
/// Ties go to the lower axis; the shader decides the same way.
pub fn normal_class(n: Vec3) -> u32 {
    let a = n.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    2 * axis + u32::from(n[axis as usize] < 0.0)
}

/// The four directions spanning the closed cone of normals of class `c`.
fn generators(c: u32) -> [Vec3; 4] {
    let axis = (c / 2) as usize;
    let sign = if c % 2 == 0 { 1.0 } else { -1.0 };
    let mut out = [Vec3::ZERO; 4];
    for (k, g) in out.iter_mut().enumerate() {
        let (s1, s2) = (
            if k & 1 == 0 { 1.0 } else { -1.0 },
            if k & 2 == 0 { 1.0 } else { -1.0 },
        );
        let mut v = Vec3::ZERO;
        v[axis] = sign;
        v[(axis + 1) % 3] = s1;
        v[(axis + 2) % 3] = s2;
        *g = v;
    }
    out
}

fn dmin2(lo: Vec3, hi: Vec3, p: Vec3) -> f32 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length_squared()
}

fn dmax2(lo: Vec3, hi: Vec3, p: Vec3) -> f32 {
    (p - lo).abs().max((hi - p).abs()).length_squared()
}

/// Calls `f` with every volume (k-d tree order) whose squared distance to the
/// box [lo, hi] is at most `r2`, until `f` returns false.
fn within_box_distance(
    volumes: &[Volume],
    lo: Vec3,
    hi: Vec3,
    r2: f32,
    f: &mut dyn FnMut(u32) -> bool,
) {
    let mut stack = vec![(0usize, volumes.len())];
    while let Some((a, b)) = stack.pop() {
        if a >= b {
            continue;
        }
        let m = (a + b) / 2;
        let v = &volumes[m];
        let p = Vec3::from(v.position);
        if dmin2(lo, hi, p) <= r2 && !f(m as u32) {
            return;
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

impl LookupGrid {
    /// Builds the grid for `volumes` (in k-d tree order) over `scene`.
    pub fn build(scene: &Scene, volumes: &[Volume]) -> Self {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut area = 0.0f64;
        for t in &scene.triangles {
            let v0 = Vec3::from(t.v0);
            for p in [v0, v0 + Vec3::from(t.e1), v0 + Vec3::from(t.e2)] {
                lo = lo.min(p);
                hi = hi.max(p);
            }
            area += t.area as f64;
        }
        let margin = 1e-3 * scene.extent;
        lo -= Vec3::splat(margin);
        hi += Vec3::splat(margin);
        // Cells half as wide as the spacing of the volumes, at most 64 a side
        // (the ranges table holds every cell: 64³ · 6 · 8 bytes at most).
        let spacing = (area / volumes.len().max(1) as f64).sqrt() as f32;
        let size = hi - lo;
        let cell = (0.5 * spacing).max(size.max_element() / 64.0).max(1e-6);
        if cell > 2.0 * spacing {
            // Cells wider than a few volumes would mostly overflow their lists:
            // with this many volumes the k-d tree serves every lookup.
            return Self {
                origin: lo,
                cell,
                dims: UVec3::ZERO,
                ranges: Vec::new(),
                items: Vec::new(),
                touched_classes: 0,
            };
        }
        let dims = (size / cell).ceil().as_uvec3().max(UVec3::ONE);
        let cells = (dims.x * dims.y * dims.z) as usize;

        // Cells touched by geometry (triangle boxes grown by the ray offset), with
        // the classes of the normals queries there can have: either side's.
        let mut touched = vec![0u8; cells];
        let cell_of = |p: Vec3| {
            ((p - lo) / cell)
                .floor()
                .as_ivec3()
                .clamp(glam::IVec3::ZERO, dims.as_ivec3() - 1)
        };
        for t in &scene.triangles {
            let v0 = Vec3::from(t.v0);
            let ps = [v0, v0 + Vec3::from(t.e1), v0 + Vec3::from(t.e2)];
            let tl = ps[0].min(ps[1]).min(ps[2]) - Vec3::splat(margin);
            let th = ps[0].max(ps[1]).max(ps[2]) + Vec3::splat(margin);
            let (a, b) = (cell_of(tl), cell_of(th));
            let n = Vec3::from(t.e1).cross(Vec3::from(t.e2));
            let classes = (1u8 << normal_class(n)) | (1u8 << normal_class(-n));
            for z in a.z..=b.z {
                for y in a.y..=b.y {
                    for x in a.x..=b.x {
                        touched[(x as u32 + dims.x * (y as u32 + dims.y * z as u32)) as usize] |=
                            classes;
                    }
                }
            }
        }

        let mut ranges = vec![[0, GRID_FALLBACK]; cells * NORMAL_CLASSES as usize];
        let mut items = Vec::new();
        for c in 0..NORMAL_CLASSES {
            let g = generators(c);
            let always = |v: &Volume| g.iter().all(|d| Vec3::from(v.normal).dot(*d) > 0.0);
            let maybe = |v: &Volume| g.iter().any(|d| Vec3::from(v.normal).dot(*d) > 0.0);
            // The always-facing volumes in a k-d tree of their own, so the
            // bound below is a plain nearest-neighbour query.
            let mut bounders: Vec<Volume> = volumes.iter().filter(|v| always(v)).copied().collect();
            if bounders.is_empty() {
                continue; // no bound: this class always uses the k-d tree
            }
            super::volumes::build_kd_tree(&mut bounders);
            for z in 0..dims.z {
                for y in 0..dims.y {
                    for x in 0..dims.x {
                        let index = (x + dims.x * (y + dims.y * z)) as usize;
                        if touched[index] & (1 << c) == 0 {
                            continue;
                        }
                        // The box grows a little so rounding at its faces cannot matter.
                        let slack = Vec3::splat(1e-3 * cell);
                        let clo = lo + Vec3::new(x as f32, y as f32, z as f32) * cell - slack;
                        let chi = clo + Vec3::splat(cell) + 2.0 * slack;
                        let centre = 0.5 * (clo + chi);
                        let Some(i) = nearest_where(&bounders, centre, |_| true) else {
                            continue;
                        };
                        let bound2 = dmax2(clo, chi, Vec3::from(bounders[i as usize].position));
                        let start = items.len();
                        let mut overflow = false;
                        within_box_distance(volumes, clo, chi, bound2, &mut |j| {
                            if maybe(&volumes[j as usize]) {
                                items.push(j);
                                overflow = items.len() - start > GRID_MAX_LIST as usize;
                            }
                            !overflow
                        });
                        if overflow {
                            items.truncate(start);
                            continue;
                        }
                        // Drop j when an always-facing i is nearer than j at every
                        // corner of the cell: the bisector plane keeps all of the cell
                        // on i's side, and i serves every query j could serve.
                        let corners: Vec<Vec3> = (0..8)
                            .map(|k| {
                                Vec3::new(
                                    if k & 1 == 0 { clo.x } else { chi.x },
                                    if k & 2 == 0 { clo.y } else { chi.y },
                                    if k & 4 == 0 { clo.z } else { chi.z },
                                )
                            })
                            .collect();
                        let found = items[start..].to_vec();
                        let pruners: Vec<Vec3> = found
                            .iter()
                            .filter(|&&i| always(&volumes[i as usize]))
                            .map(|&i| Vec3::from(volumes[i as usize].position))
                            .collect();
                        items.truncate(start);
                        for &j in &found {
                            let pj = Vec3::from(volumes[j as usize].position);
                            let dominated = pruners.iter().any(|&pi| {
                                pi != pj
                                    && corners.iter().all(|&q| {
                                        let (di, dj) =
                                            (q.distance_squared(pi), q.distance_squared(pj));
                                        di < dj * (1.0 - 1e-4)
                                    })
                            });
                            if !dominated {
                                items.push(j);
                            }
                        }
                        ranges[index * NORMAL_CLASSES as usize + c as usize] =
                            [start as u32, (items.len() - start) as u32];
                    }
                }
            }
        }
        Self {
            origin: lo,
            cell,
            dims,
            ranges,
            items,
            touched_classes: touched.iter().map(|t| t.count_ones()).sum(),
        }
    }

    /// Nearest facing volume through the grid, falling back to the k-d tree
    /// (the shader's search, on the CPU).
    pub fn nearest(&self, volumes: &[Volume], p: Vec3, n: Vec3) -> Option<u32> {
        let g = (p - self.origin) / self.cell;
        if self.dims != UVec3::ZERO
            && g.cmpge(Vec3::ZERO).all()
            && g.cmplt(self.dims.as_vec3()).all()
        {
            let c = g.as_uvec3();
            let index =
                (c.x + self.dims.x * (c.y + self.dims.y * c.z)) * NORMAL_CLASSES + normal_class(n);
            let [start, count] = self.ranges[index as usize];
            if count != GRID_FALLBACK {
                let list = &self.items[start as usize..(start + count) as usize];
                return list
                    .iter()
                    .filter(|&&j| Vec3::from(volumes[j as usize].normal).dot(n) > 0.0)
                    .min_by(|&&a, &&b| {
                        let da = Vec3::from(volumes[a as usize].position).distance_squared(p);
                        let db = Vec3::from(volumes[b as usize].position).distance_squared(p);
                        da.total_cmp(&db)
                    })
                    .copied();
            }
        }
        super::volumes::nearest_kd(volumes, p, n)
    }

    /// Share of the (cell, class) pairs surfaces query that lists serve.
    pub fn coverage(&self) -> f64 {
        let listed = self.ranges.iter().filter(|r| r[1] != GRID_FALLBACK).count();
        listed as f64 / self.touched_classes.max(1) as f64
    }

    /// Mean length of the lists the grid keeps.
    pub fn mean_list_length(&self) -> f64 {
        let lists: Vec<u32> = self
            .ranges
            .iter()
            .filter(|r| r[1] != GRID_FALLBACK)
            .map(|r| r[1])
            .collect();
        lists.iter().map(|&l| l as f64).sum::<f64>() / lists.len().max(1) as f64
    }

    pub fn bytes(&self) -> u64 {
        size_of::<GridHeader>() as u64 + 8 * self.ranges.len() as u64 + 16 * self.items.len() as u64
    }

    /// The header the shader reads before the ranges.
    pub fn header(&self) -> GridHeader {
        GridHeader {
            origin: self.origin.into(),
            inv_cell: 1.0 / self.cell,
            dims: self.dims.into(),
            pad: 0,
        }
    }
}
