//! Binned-SAH BVH built on the host and flattened for the GPU: children of an
//! interior node sit next to each other, so a node needs one index.

use crate::shaders::{BvhNode, BVH_STACK_SIZE};
use glam::Vec3;

const BINS: usize = 16;
const MAX_LEAF: usize = 4;
/// Past this depth nodes split at the median, which halves them: 32 more levels
/// hold 2^32 triangles, so the depth (and the GPU traversal stack) stays below
/// BVH_STACK_SIZE whatever the geometry.
const MEDIAN_DEPTH: u32 = BVH_STACK_SIZE - 33;

#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };
    fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    fn merge(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

/// The flattened tree and the triangle order its leaves refer to.
pub struct Bvh {
    pub nodes: Vec<BvhNode>,
    /// `order[i]` is the original index of the i-th triangle in leaf order.
    pub order: Vec<u32>,
    pub depth: u32,
    pub leaves: u32,
}

struct Builder<'a> {
    bounds: &'a [Aabb],
    centroids: &'a [Vec3],
    order: Vec<u32>,
    nodes: Vec<BvhNode>,
    depth: u32,
    leaves: u32,
}

pub fn build(triangles: &[[Vec3; 3]]) -> Bvh {
    let bounds: Vec<Aabb> = triangles
        .iter()
        .map(|t| {
            let mut b = Aabb::EMPTY;
            t.iter().for_each(|&p| b.grow(p));
            b
        })
        .collect();
    let centroids: Vec<Vec3> = bounds.iter().map(|b| 0.5 * (b.min + b.max)).collect();
    let mut builder = Builder {
        bounds: &bounds,
        centroids: &centroids,
        order: (0..triangles.len() as u32).collect(),
        nodes: vec![BvhNode::default()],
        depth: 0,
        leaves: 0,
    };
    builder.split(0, 0, triangles.len(), 0);
    Bvh {
        nodes: builder.nodes,
        order: builder.order,
        depth: builder.depth,
        leaves: builder.leaves,
    }
}

impl Builder<'_> {
    fn range_bounds(&self, start: usize, end: usize) -> (Aabb, Aabb) {
        let mut b = Aabb::EMPTY;
        let mut c = Aabb::EMPTY;
        for &i in &self.order[start..end] {
            b.merge(&self.bounds[i as usize]);
            c.grow(self.centroids[i as usize]);
        }
        (b, c)
    }

    fn split(&mut self, node: usize, start: usize, end: usize, depth: u32) {
        self.depth = self.depth.max(depth);
        let (bounds, centroid_bounds) = self.range_bounds(start, end);
        let count = end - start;
        self.nodes[node] = BvhNode {
            bmin: bounds.min.into(),
            first: start as u32,
            bmax: bounds.max.into(),
            count: count as u32,
        };
        if count <= MAX_LEAF {
            self.leaves += 1;
            return;
        }
        let extent = centroid_bounds.max - centroid_bounds.min;
        let axis = extent.max_position();
        if extent[axis] <= 0.0 {
            // All centroids coincide: no split separates them.
            self.leaves += 1;
            return;
        }
        let mid = if depth >= MEDIAN_DEPTH {
            self.median_split(start, end, axis)
        } else {
            match self.sah_split(start, end, axis, &centroid_bounds, bounds.area()) {
                Some(mid) => mid,
                None => {
                    self.leaves += 1;
                    return;
                }
            }
        };
        let left = self.nodes.len();
        self.nodes.push(BvhNode::default());
        self.nodes.push(BvhNode::default());
        self.nodes[node].first = left as u32;
        self.nodes[node].count = 0;
        self.split(left, start, mid, depth + 1);
        self.split(left + 1, mid, end, depth + 1);
    }

    fn median_split(&mut self, start: usize, end: usize, axis: usize) -> usize {
        let mid = (start + end) / 2;
        let centroids = self.centroids;
        self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        mid
    }

    /// Partitions at the cheapest of the bin planes on `axis`; `None` when a
    /// leaf is cheaper than any split.
    fn sah_split(
        &mut self,
        start: usize,
        end: usize,
        axis: usize,
        cb: &Aabb,
        parent_area: f32,
    ) -> Option<usize> {
        let lo = cb.min[axis];
        let scale = BINS as f32 / (cb.max[axis] - lo);
        let bin_of = |c: Vec3| (((c[axis] - lo) * scale) as usize).min(BINS - 1);
        let mut bins = [(Aabb::EMPTY, 0usize); BINS];
        for &i in &self.order[start..end] {
            let b = &mut bins[bin_of(self.centroids[i as usize])];
            b.0.merge(&self.bounds[i as usize]);
            b.1 += 1;
        }
        // Cost of splitting after bin k: left areas from the left, right from the right.
        let mut right_cost = [0.0f32; BINS];
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for k in (1..BINS).rev() {
            acc.merge(&bins[k].0);
            n += bins[k].1;
            right_cost[k] = if n > 0 { acc.area() * n as f32 } else { 0.0 };
        }
        let mut best = (f32::INFINITY, 0usize);
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for k in 0..BINS - 1 {
            acc.merge(&bins[k].0);
            n += bins[k].1;
            let cost = if n > 0 { acc.area() * n as f32 } else { 0.0 } + right_cost[k + 1];
            if n > 0 && n < end - start && cost < best.0 {
                best = (cost, k);
            }
        }
        let count = end - start;
        // Traversal step costs about as much as one triangle test.
        let leaf_cost = count as f32 * parent_area;
        let split_cost = parent_area + best.0;
        if best.0 == f32::INFINITY || (count <= 2 * MAX_LEAF && split_cost >= leaf_cost) {
            return if best.0 == f32::INFINITY {
                Some(self.median_split(start, end, axis))
            } else {
                None
            };
        }
        let split_bin = best.1;
        let centroids = self.centroids;
        let slice = &mut self.order[start..end];
        let mut left = 0;
        for i in 0..slice.len() {
            if bin_of(centroids[slice[i] as usize]) <= split_bin {
                slice.swap(i, left);
                left += 1;
            }
        }
        Some(start + left)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_triangle_is_in_exactly_one_leaf_inside_its_node() {
        let mut tris = Vec::new();
        let mut s = 1u32;
        let mut rnd = || {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            (s >> 8) as f32 / (1 << 24) as f32
        };
        for _ in 0..5000 {
            let p = Vec3::new(rnd(), rnd(), rnd()) * 100.0;
            tris.push([
                p,
                p + Vec3::new(rnd(), rnd(), 0.0),
                p + Vec3::new(0.0, rnd(), rnd()),
            ]);
        }
        let bvh = build(&tris);
        assert!(bvh.depth < BVH_STACK_SIZE);
        let mut seen = vec![0u32; tris.len()];
        for node in &bvh.nodes {
            if node.count > 0 {
                for i in node.first..node.first + node.count {
                    let t = bvh.order[i as usize] as usize;
                    seen[t] += 1;
                    for p in tris[t] {
                        assert!(
                            p.cmpge(Vec3::from(node.bmin)).all()
                                && p.cmple(Vec3::from(node.bmax)).all()
                        );
                    }
                }
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
    }
}
