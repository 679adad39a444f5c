//! Exact nearest-volume lookup for points on surfaces.
//!
//! The renderer looks a volume up only where a ray hit a triangle, and it
//! shades one known side of that triangle, so the volumes a point may use
//! (those facing that side) are fixed per (triangle, side). Each triangle gets
//! a grid over its barycentric parallelogram, with cells about half the volume
//! spacing; each cell of each side stores the one volume that is nearest
//! everywhere in it, or else a short list of the volumes that can be nearest
//! somewhere in it. A triangle small enough for one cell with one volume per
//! side carries both answers itself. The shader finds the cell from the hit's
//! barycentric coordinates and scans at most that list: no normal tests, no
//! tree walk.

use super::volumes::Volume;
use super::volumes::{dmin2, faces_same_way, nearest_from, within_box_distance};
use crate::scene::Scene;
use crate::shaders::{Triangle, NO_VOLUME};
use glam::{Vec2, Vec3};

/// Most cells along one edge of a triangle.
const MAX_CELLS_PER_EDGE: f32 = 64.0;
/// Most cells in all, both sides counted: 64 MiB, half the storage-buffer
/// range every Vulkan device offers.
const MAX_CELLS: f64 = (8 << 20) as f64;

#[derive(Clone)]
pub struct VolumeLookup {
    /// Per triangle: its front side's first cell
    /// (the back side's follow) and `nu | nv << 16`, the cells along e1 and
    /// e2; or, with that word 0, no cells and the front and back sides'
    /// volumes in the last two words.
    pub triangles: Vec<[u32; 4]>,
    /// Per cell: `[volume, 0]` (possibly NO_VOLUME), or `[first item, count]`
    /// with count ≥ 2.
    pub cells: Vec<[u32; 2]>,
    /// Volume indices of the lists.
    pub items: Vec<u32>,
}

/// The cells of one triangle: `nu × nv` for the front, then as many for the back.
struct TriangleCells {
    dims: [u32; 2],
    cells: Vec<[u32; 2]>,
    items: Vec<u32>,
}

impl VolumeLookup {
    /// Tables for `volumes` (in k-d tree order) over the triangles of `scene`.
    pub fn build(scene: &Scene, volumes: &[Volume]) -> Self {
        let spacing = (super::volumes::placement_area(scene) / volumes.len().max(1) as f64).sqrt();
        let mut cell = ((0.5 * spacing) as f32).max(1e-6 * scene.extent);
        // Many large triangles would need too many cells: coarser ones only
        // make the lists longer.
        let offset = scene.ray_offset();
        // Triangles of one cell carry their answers themselves, mostly.
        let total = |cell: f32| -> f64 {
            let cells = |t: &Triangle| match grid_of(t, cell, offset) {
                [1, 1] => 0.0,
                [nu, nv] => 2.0 * nu as f64 * nv as f64,
            };
            scene.triangles.iter().map(cells).sum()
        };
        while total(cell) > MAX_CELLS && cell < scene.extent {
            cell *= 1.25;
        }
        let triangles = &scene.triangles;
        // Each core takes the next run of triangles as it gets free: a few
        // large triangles (a Cornell box's walls) hold most of the cells.
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let run = (triangles.len() / (64 * threads)).clamp(1, 256);
        let next = std::sync::atomic::AtomicUsize::new(0);
        let mut parts: Vec<(usize, Vec<TriangleCells>)> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|_| {
                    s.spawn(|| {
                        let mut mine = Vec::new();
                        loop {
                            let start = next.fetch_add(run, std::sync::atomic::Ordering::Relaxed);
                            if start >= triangles.len() {
                                break mine;
                            }
                            let part = &triangles[start..(start + run).min(triangles.len())];
                            mine.push((start, run_cells(part, volumes, cell, offset)));
                        }
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().expect("lookup build thread panicked"))
                .collect()
        });
        parts.sort_unstable_by_key(|&(start, _)| start);
        let mut lookup = Self {
            triangles: Vec::with_capacity(triangles.len()),
            cells: Vec::new(),
            items: Vec::new(),
        };
        for t in parts.into_iter().flat_map(|(_, cells)| cells) {
            if let [[front, 0], [back, 0]] = t.cells[..] {
                lookup.triangles.push([0, 0, front, back]);
                continue;
            }
            lookup.triangles.push([
                lookup.cells.len() as u32,
                t.dims[0] | (t.dims[1] << 16),
                0,
                0,
            ]);
            let base = lookup.items.len() as u32;
            lookup.cells.extend(t.cells.iter().map(|&[a, count]| {
                if count == 0 {
                    [a, 0]
                } else {
                    [a + base, count]
                }
            }));
            lookup.items.extend(t.items);
        }
        lookup
    }

    /// The shader's search on the CPU: the volume for point `p` shading the
    /// front (or back) side of triangle `index`.
    pub fn nearest(
        &self,
        scene: &Scene,
        volumes: &[Volume],
        index: u32,
        front: bool,
        p: Vec3,
    ) -> Option<u32> {
        let [first, dims, front_volume, back_volume] = self.triangles[index as usize];
        if dims == 0 {
            let v = if front { front_volume } else { back_volume };
            return Some(v).filter(|&v| v != NO_VOLUME);
        }
        let (nu, nv) = (dims & 0xffff, dims >> 16);
        let mut cell = first + if front { 0 } else { nu * nv };
        if nu * nv > 1 {
            let uv = barycentric(&scene.triangles[index as usize], p);
            let c = (uv * Vec2::new(nu as f32, nv as f32))
                .clamp(Vec2::ZERO, Vec2::new((nu - 1) as f32, (nv - 1) as f32))
                .as_uvec2();
            cell += c.x + nu * c.y;
        }
        let [a, count] = self.cells[cell as usize];
        if count == 0 {
            return Some(a).filter(|&v| v != NO_VOLUME);
        }
        self.items[a as usize..(a + count) as usize]
            .iter()
            .copied()
            .min_by(|&i, &j| {
                let di = Vec3::from(volumes[i as usize].position).distance_squared(p);
                let dj = Vec3::from(volumes[j as usize].position).distance_squared(p);
                di.total_cmp(&dj)
            })
    }

    /// Mean number of volumes a cell holds (1 for a cell with one answer).
    pub fn mean_candidates(&self) -> f64 {
        let total: u64 = self.cells.iter().map(|c| c[1].max(1) as u64).sum();
        total as f64 / self.cells.len().max(1) as f64
    }

    /// Triangles that carry their answers themselves.
    pub fn direct_triangles(&self) -> usize {
        self.triangles.iter().filter(|t| t[1] == 0).count()
    }

    /// Bytes of the per-triangle, cell and list tables on the device.
    pub fn bytes(&self) -> u64 {
        16 * self.triangles.len() as u64
            + 8 * self.cells.len() as u64
            + 16 * self.items.len() as u64
    }
}

/// Barycentric coordinates (along e1, e2) of the projection of `p` onto the
/// triangle's plane; the shader computes them the same way.
pub fn barycentric(t: &Triangle, p: Vec3) -> Vec2 {
    let (e1, e2) = (Vec3::from(t.e1), Vec3::from(t.e2));
    let q = p - Vec3::from(t.v0);
    let (d00, d01, d11) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d20, d21) = (q.dot(e1), q.dot(e2));
    let inv = 1.0 / (d00 * d11 - d01 * d01);
    Vec2::new(d11 * d20 - d01 * d21, d00 * d21 - d01 * d20) * inv
}

/// Cells along an edge for cells about `cell` wide.
fn cells_along(e: Vec3, cell: f32) -> u32 {
    (e.length() / cell).ceil().clamp(1.0, MAX_CELLS_PER_EDGE) as u32
}

/// The margin around a cell that covers rounding in the hit point and in
/// its barycentric coordinates.
fn margin(cell: f32, offset: f32) -> f32 {
    1e-3 * cell + offset
}

/// Cells along e1 and e2 of a triangle. The shader's barycentric coordinates
/// lose precision like 1 / sin²θ as the angle θ at v0 closes; where their
/// error could pass the margin, the triangle keeps one cell, which needs none.
fn grid_of(t: &Triangle, cell: f32, offset: f32) -> [u32; 2] {
    let (e1, e2) = (Vec3::from(t.e1), Vec3::from(t.e2));
    let sin2 = e1.cross(e2).length_squared() / (e1.length_squared() * e2.length_squared());
    let error = 1e-6 * e1.length().max(e2.length()) / sin2;
    // NaN (a degenerate triangle) counts as too large.
    let precise = error < margin(cell, offset);
    if t.light_pdf > 0.0 || !precise {
        return [1, 1];
    }
    [cells_along(e1, cell), cells_along(e2, cell)]
}

/// Triangles of one cell that share one search of the k-d tree.
const GROUP: usize = 16;

/// The cells of consecutive triangles `part`. Neighbours in the BVH's
/// order lie close together, so the one-cell triangles among them search the
/// tree once per [`GROUP`], for every volume that any of them could need,
/// and each picks its own from that pool: the same lists as searching the
/// tree for each (the pool holds each one's search, in the tree's order).
fn run_cells(part: &[Triangle], volumes: &[Volume], cell: f32, offset: f32) -> Vec<TriangleCells> {
    // Each side's nearest volume starts from the last triangle's.
    let mut hints = [None; 2];
    let planned: Vec<_> = part
        .iter()
        .map(|t| {
            let p = plan_triangle(t, volumes, cell, offset, hints);
            if let Some(p) = &p {
                hints = p
                    .sides
                    .each_ref()
                    .map(|s| s.search.as_ref().map(|s| s.first));
            }
            p
        })
        .collect();
    let m = margin(cell, offset);
    let mut out = Vec::with_capacity(part.len());
    for group in planned.chunks(GROUP) {
        let small = |p: &&Option<Planned>| p.as_ref().is_some_and(|p| p.dims == [1, 1]);
        let searches = group
            .iter()
            .filter(small)
            .flatten()
            .flat_map(|p| p.sides.iter().filter_map(|s| s.search.as_ref()));
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        let mut r2 = 0.0f32;
        for s in searches {
            (lo, hi, r2) = (lo.min(s.lo), hi.max(s.hi), r2.max(s.r2));
        }
        let mut pool = Vec::new();
        if lo.x <= hi.x {
            within_box_distance(volumes, lo, hi, r2, &mut |j| pool.push(j));
        }
        for p in group {
            let pool = small(&p).then_some(&pool[..]);
            out.push(triangle_cells(p.as_ref(), volumes, m, pool));
        }
    }
    out
}

/// A triangle's grid and its two sides, searched as far as knowing where
/// their candidates lie; `None` for an emitter.
struct Planned {
    dims: [u32; 2],
    sides: [PlannedSide; 2],
}

struct PlannedSide {
    normal: Vec3,
    grid: CellGrid,
    /// The whole grid's region.
    region: Vec<Vec3>,
    /// `None` where no volume faces this side.
    search: Option<Search>,
}

fn plan_triangle(
    t: &Triangle,
    volumes: &[Volume],
    cell: f32,
    offset: f32,
    hints: [Option<u32>; 2],
) -> Option<Planned> {
    if t.light_pdf > 0.0 {
        // Paths end on emitters: nothing looks a volume up there.
        return None;
    }
    let (v0, e1, e2) = (Vec3::from(t.v0), Vec3::from(t.e1), Vec3::from(t.e2));
    let n = e1.cross(e2).normalize();
    let dims = grid_of(t, cell, offset);
    let m = margin(cell, offset);
    let side = |normal: Vec3, hint: Option<u32>| {
        // Query points sit one ray offset off the surface, on the shaded side.
        let grid = CellGrid {
            origin: v0 + normal * offset,
            e1,
            e2,
            dims,
        };
        let region = grid.block([0, 0], dims);
        let search = plan_search(volumes, &region, m, |v| faces_same_way(v, normal), hint);
        PlannedSide {
            normal,
            grid,
            region,
            search,
        }
    };
    Some(Planned {
        dims,
        sides: [side(n, hints[0]), side(-n, hints[1])],
    })
}

/// The cells of a planned triangle; its candidates are searched in the
/// whole tree, or among `pool` where that holds them.
fn triangle_cells(
    planned: Option<&Planned>,
    volumes: &[Volume],
    m: f32,
    pool: Option<&[u32]>,
) -> TriangleCells {
    let Some(planned) = planned else {
        return TriangleCells {
            dims: [1, 1],
            cells: vec![[NO_VOLUME, 0]; 2],
            items: Vec::new(),
        };
    };
    let [nu, nv] = planned.dims;
    let mut out = TriangleCells {
        dims: planned.dims,
        cells: Vec::new(),
        items: Vec::new(),
    };
    for side in &planned.sides {
        // The tree is searched once, for the whole grid; each half of a
        // block of cells then searches its block's candidates only (see
        // `candidates`), down to single cells.
        let accept = |v: &Volume| faces_same_way(v, side.normal);
        let found = side.search.as_ref().map_or_else(Vec::new, |s| {
            s.candidates(volumes, pool, &side.region, m, accept)
        });
        let mut cells = vec![Vec::new(); (nu * nv) as usize];
        side.grid
            .split(volumes, &found, [0, 0], [nu, nv], m, &mut cells);
        for found in &cells {
            match found.as_slice() {
                [] => out.cells.push([NO_VOLUME, 0]),
                [only] => out.cells.push([*only, 0]),
                list => {
                    out.cells.push([out.items.len() as u32, list.len() as u32]);
                    out.items.extend_from_slice(list);
                }
            }
        }
    }
    out
}

/// A triangle side's grid of cells, `dims` along e1 and e2 from `origin`.
struct CellGrid {
    origin: Vec3,
    e1: Vec3,
    e2: Vec3,
    dims: [u32; 2],
}

impl CellGrid {
    fn point(&self, uv: Vec2) -> Vec3 {
        self.origin + uv.x * self.e1 + uv.y * self.e2
    }

    fn quad(&self, lo: [u32; 2], hi: [u32; 2]) -> [Vec2; 4] {
        let [nu, nv] = [self.dims[0] as f32, self.dims[1] as f32];
        let (u0, u1) = (lo[0] as f32 / nu, hi[0] as f32 / nu);
        let (w0, w1) = (lo[1] as f32 / nv, hi[1] as f32 / nv);
        [
            Vec2::new(u0, w0),
            Vec2::new(u1, w0),
            Vec2::new(u1, w1),
            Vec2::new(u0, w1),
        ]
    }

    /// The region of cells lo..hi: their whole parallelogram, which holds
    /// every one of their own regions (clipped or not).
    fn block(&self, lo: [u32; 2], hi: [u32; 2]) -> Vec<Vec3> {
        self.quad(lo, hi).iter().map(|&uv| self.point(uv)).collect()
    }

    /// One cell's region: its part on the triangle (see clip_to_triangle).
    fn cell(&self, iu: u32, iv: u32) -> Vec<Vec3> {
        clip_to_triangle(self.quad([iu, iv], [iu + 1, iv + 1]))
            .iter()
            .map(|&uv| self.point(uv))
            .collect()
    }

    /// Fills `cells` (row-major) for the block lo..hi from `found`, its
    /// candidates, halving the longer side of the block at each step.
    fn split(
        &self,
        volumes: &[Volume],
        found: &[u32],
        lo: [u32; 2],
        hi: [u32; 2],
        margin: f32,
        cells: &mut [Vec<u32>],
    ) {
        if found.is_empty() {
            return;
        }
        let [du, dv] = [hi[0] - lo[0], hi[1] - lo[1]];
        if du == 1 && dv == 1 {
            let region = self.cell(lo[0], lo[1]);
            cells[(lo[0] + self.dims[0] * lo[1]) as usize] =
                candidates_among(volumes, found, &region, margin);
            return;
        }
        let halves = if du >= dv {
            let mid = lo[0] + du / 2;
            [(lo, [mid, hi[1]]), ([mid, lo[1]], hi)]
        } else {
            let mid = lo[1] + dv / 2;
            [(lo, [hi[0], mid]), ([lo[0], mid], hi)]
        };
        for (a, b) in halves {
            // A single cell searches `found` itself, for its own region.
            if (b[0] - a[0]) * (b[1] - a[1]) == 1 {
                self.split(volumes, found, a, b, margin, cells);
            } else {
                let mine = candidates_among(volumes, found, &self.block(a, b), margin);
                self.split(volumes, &mine, a, b, margin, cells);
            }
        }
    }
}

/// The part of the cell `quad` (barycentric corners, counter-clockwise) on
/// the triangle, u + v ≤ 1; a cell beyond the triangle keeps its corner
/// nearest to it, where rounding can still send a query.
fn clip_to_triangle(quad: [Vec2; 4]) -> Vec<Vec2> {
    let inside = |p: Vec2| p.x + p.y <= 1.0;
    let mut out = Vec::with_capacity(5);
    for k in 0..4 {
        let (a, b) = (quad[k], quad[(k + 1) % 4]);
        if inside(a) {
            out.push(a);
        }
        if inside(a) != inside(b) {
            let s = (1.0 - a.x - a.y) / ((b.x - a.x) + (b.y - a.y));
            out.push(a + s * (b - a));
        }
    }
    // Corners on the cut line come out twice.
    out.dedup();
    if out.len() > 1 && out.first() == out.last() {
        out.pop();
    }
    if out.is_empty() {
        out.push(quad[0]);
    }
    out
}

/// Where the candidates of a region lie: its centre, the nearest volume
/// to it, and the box and squared distance of [`search_box`].
struct Search {
    centre: Vec3,
    first: u32,
    lo: Vec3,
    hi: Vec3,
    r2: f32,
}

/// The search for the volumes `accept` lets through that can be nearest to
/// some point within `margin` of the convex polygon `region`; `None` where
/// `accept` lets none through. `hint` starts the search for the nearest.
fn plan_search(
    volumes: &[Volume],
    region: &[Vec3],
    margin: f32,
    accept: impl Fn(&Volume) -> bool,
    hint: Option<u32>,
) -> Option<Search> {
    let centre = region.iter().copied().sum::<Vec3>() / region.len() as f32;
    let first = nearest_from(volumes, centre, accept, hint)?;
    let (lo, hi, r2) = search_box(volumes, region, margin, first);
    Some(Search {
        centre,
        first,
        lo,
        hi,
        r2,
    })
}

impl Search {
    /// The candidates, nearest to the region's centre first: found in the
    /// whole k-d tree, or in `pool`, a part of it (in the tree's order)
    /// that holds every volume within the search's distance of its box.
    fn candidates(
        &self,
        volumes: &[Volume],
        pool: Option<&[u32]>,
        region: &[Vec3],
        margin: f32,
        accept: impl Fn(&Volume) -> bool,
    ) -> Vec<u32> {
        let mut found = Vec::new();
        let mut take = |j: u32| {
            if accept(&volumes[j as usize]) {
                found.push(j);
            }
        };
        match pool {
            Some(pool) => pool
                .iter()
                .filter(|&&j| {
                    dmin2(self.lo, self.hi, volumes[j as usize].position.into()) <= self.r2
                })
                .for_each(|&j| take(j)),
            None => within_box_distance(volumes, self.lo, self.hi, self.r2, &mut take),
        }
        undominated(volumes, found, region, margin, self.centre)
    }
}

/// As `candidates`, searched among `known`: the candidates of a region that
/// holds this one. They hold all of this region's, since a volume nearest
/// to some point here is nearest to that point of the larger region; the
/// result may keep one that the whole tree would have shown dominated.
fn candidates_among(volumes: &[Volume], known: &[u32], region: &[Vec3], margin: f32) -> Vec<u32> {
    let position = |i: u32| Vec3::from(volumes[i as usize].position);
    let centre = region.iter().copied().sum::<Vec3>() / region.len() as f32;
    let Some(first) = known.iter().copied().min_by(|&a, &b| {
        centre
            .distance_squared(position(a))
            .total_cmp(&centre.distance_squared(position(b)))
    }) else {
        return Vec::new();
    };
    let (lo, hi, r2) = search_box(volumes, region, margin, first);
    let found = known
        .iter()
        .copied()
        .filter(|&j| dmin2(lo, hi, position(j)) <= r2)
        .collect();
    undominated(volumes, found, region, margin, centre)
}

/// The box around `region` (grown by `margin`) and the squared distance
/// from it within which a volume may be nearest somewhere in the region:
/// every point of the region has a volume no farther than `first` is.
fn search_box(volumes: &[Volume], region: &[Vec3], margin: f32, first: u32) -> (Vec3, Vec3, f32) {
    let p0 = Vec3::from(volumes[first as usize].position);
    let bound = region.iter().map(|q| q.distance(p0)).fold(0.0f32, f32::max) + margin;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for &q in region {
        lo = lo.min(q);
        hi = hi.max(q);
    }
    (
        lo - Vec3::splat(margin),
        hi + Vec3::splat(margin),
        bound * bound,
    )
}

/// `found`, nearest to `centre` first, less each volume that another of
/// them is nearer than at every point within `margin` of `region`.
fn undominated(
    volumes: &[Volume],
    mut found: Vec<u32>,
    region: &[Vec3],
    margin: f32,
    centre: Vec3,
) -> Vec<u32> {
    let position = |i: u32| Vec3::from(volumes[i as usize].position);
    found.sort_by(|&a, &b| {
        centre
            .distance_squared(position(a))
            .total_cmp(&centre.distance_squared(position(b)))
    });
    // Drop j when some i is nearer at every point within `margin` of the
    // region: the region's vertices lie more than `margin` inside i's side of
    // the bisector plane, so all of it does.
    let dominated = |j: u32| {
        let pj = position(j);
        found.iter().any(|&i| {
            let pi = position(i);
            let d = pj - pi;
            let mid = 0.5 * (pi + pj);
            let limit = -margin * d.length() * (1.0 + 1e-4);
            i != j && d != Vec3::ZERO && region.iter().all(|&q| (q - mid).dot(d) < limit)
        })
    };
    found.iter().copied().filter(|&j| !dominated(j)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangle(e1: Vec3, e2: Vec3) -> Triangle {
        Triangle {
            e1: e1.into(),
            e2: e2.into(),
            ..Default::default()
        }
    }

    #[test]
    fn thin_triangles_keep_one_cell() {
        // A right triangle 10 cells a side gets its grid ...
        let square = triangle(Vec3::X * 10.0, Vec3::Y * 10.0);
        assert_eq!(grid_of(&square, 1.0, 1e-5), [10, 10]);
        // ... one with a 0.01° angle at v0 would round its barycentric
        // coordinates past the margin, so it keeps one cell.
        let sliver = triangle(Vec3::X * 10.0, Vec3::new(10.0, 0.0017, 0.0));
        assert_eq!(grid_of(&sliver, 1.0, 1e-5), [1, 1]);
    }

    #[test]
    fn cells_clip_to_the_triangle() {
        let inside = clip_to_triangle([
            Vec2::new(0.0, 0.0),
            Vec2::new(0.5, 0.0),
            Vec2::new(0.5, 0.5),
            Vec2::new(0.0, 0.5),
        ]);
        assert_eq!(inside.len(), 4);
        let cut = clip_to_triangle([
            Vec2::new(0.5, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 0.5),
            Vec2::new(0.5, 0.5),
        ]);
        assert_eq!(
            cut,
            vec![
                Vec2::new(0.5, 0.0),
                Vec2::new(1.0, 0.0),
                Vec2::new(0.5, 0.5)
            ]
        );
        // A cell wholly past the hypotenuse keeps its corner nearest to it.
        let past = clip_to_triangle([
            Vec2::new(0.75, 0.5),
            Vec2::new(1.0, 0.5),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.75, 1.0),
        ]);
        assert_eq!(past, vec![Vec2::new(0.75, 0.5)]);
    }
}
