//! Binned-SAH BVH built on the host and flattened for the GPU. Every leaf is
//! one triangle, and every node holds its two children: an inner child's box,
//! or a leaf's triangle itself. The traversal kernel visits inner nodes only,
//! reads one node per step and does the same work at each (on lavapipe both
//! sides of a branch cost, so uniform steps are what pays).

use crate::shaders::{BvhNode, BVH_LEAF, BVH_NO_CHILD};
use glam::{Vec3, Vec3A, Vec4};

const BINS: usize = 16;
/// Deepest tree the builder makes (the recursion stays shallow).
const MAX_DEPTH: u32 = 64;
/// Past this depth nodes split at the median, which halves them: 32 more levels
/// hold 2^32 triangles, so the depth stays below MAX_DEPTH whatever the geometry.
const MEDIAN_DEPTH: u32 = MAX_DEPTH - 33;

/// A box; four lanes each, so the builder's passes use SIMD.
#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3A,
    max: Vec3A,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: Vec3A::splat(f32::INFINITY),
        max: Vec3A::splat(f32::NEG_INFINITY),
    };
    fn grow(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    fn merge(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    fn area(&self) -> f32 {
        let d = (self.max - self.min).max(Vec3A::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

/// The flattened tree and the triangle order its leaves refer to.
pub struct Bvh {
    /// Interior nodes; node 0 is the root (it has one child, or none, when
    /// the scene has fewer than two triangles).
    pub nodes: Vec<BvhNode>,
    /// `order[i]` is the original index of the triangle leaf `i` refers to.
    pub order: Vec<u32>,
    /// Levels of interior nodes on the longest root-to-leaf path.
    pub depth: u32,
    /// The box around every triangle.
    pub bounds: (Vec3, Vec3),
}

/// A child as a node stores it: three points (an inner child's box min and
/// max, or a leaf triangle's v0, e1 and e2) and its reference.
struct Child {
    points: [Vec3; 3],
    reference: u32,
}

const NO_CHILD: Child = Child {
    points: [Vec3::ZERO; 3],
    reference: BVH_NO_CHILD,
};

/// A triangle as the builder moves it: its box and its index together, so
/// that each pass over a range reads memory in order rather than gathering
/// from tables indexed by triangle. The index rides in `lo.w`, offset so
/// that its bits read as a float of 1 or more: a denormal in that unused
/// lane (as small indices, or half of one, would be) slows every SIMD op.
#[derive(Clone, Copy)]
struct Prim {
    lo: Vec4,
    hi: Vec4,
}

/// The bits of 1.0; triangle indices stay below 2^30.
const INDEX_OFFSET: u32 = 0x3f80_0000;

impl Prim {
    fn min(&self) -> Vec3A {
        Vec3A::from_vec4(self.lo)
    }
    fn max(&self) -> Vec3A {
        Vec3A::from_vec4(self.hi)
    }
    fn index(&self) -> u32 {
        self.lo.w.to_bits() - INDEX_OFFSET
    }
    fn centroid(&self) -> Vec3A {
        0.5 * (self.min() + self.max())
    }
}

/// A range's box and the box of its centroids.
type Boxes = (Aabb, Aabb);

/// Builds the tree over `prims`, a slice of the whole triangle order that
/// starts at `base`; subtrees of large ranges are built on other threads
/// into builders of their own, whose nodes their parent then adopts.
struct Builder<'a, 'o> {
    triangles: &'a [[Vec3; 3]],
    prims: &'o mut [Prim],
    base: usize,
    /// The nodes this builder fills, the next to fill, and the index of
    /// the first in the whole tree: a subtree over k triangles has k - 1
    /// nodes, so each thread's share is known before it starts.
    nodes: &'o mut [BvhNode],
    next: usize,
    node_base: usize,
    depth: u32,
    /// Levels below which subtrees still go to threads of their own.
    parallel_levels: u32,
}

/// Ranges smaller than this are built on the thread that holds them.
const PARALLEL_MIN: usize = 1 << 15;

pub fn build(triangles: &[[Vec3; 3]]) -> Bvh {
    build_with(
        triangles,
        std::thread::available_parallelism().map_or(1, |n| n.get()),
    )
}

/// [`build`] on up to `threads` threads: the same tree whatever their number.
fn build_with(triangles: &[[Vec3; 3]], threads: usize) -> Bvh {
    let mut prims: Vec<Prim> = triangles
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut b = Aabb::EMPTY;
            t.iter().for_each(|&p| b.grow(p.into()));
            Prim {
                lo: b.min.extend(f32::from_bits(i as u32 + INDEX_OFFSET)),
                hi: b.max.extend(0.0),
            }
        })
        .collect();
    let n = triangles.len();
    // The root always exists: with one leaf child, or none, below two triangles.
    let mut nodes = vec![BvhNode::default(); n.max(2) - 1];
    let mut builder = Builder {
        triangles,
        prims: &mut prims,
        base: 0,
        nodes: &mut nodes,
        next: 0,
        node_base: 0,
        depth: 0,
        parallel_levels: threads.max(1).next_power_of_two().trailing_zeros(),
    };
    let boxes = builder.range_boxes(0, n);
    if n >= 2 {
        builder.split(0, n, 0, &boxes);
    } else {
        let only = if n == 1 { builder.leaf(0) } else { NO_CHILD };
        builder.nodes[0] = node_of(&only, &NO_CHILD);
        builder.depth = 1;
    }
    let depth = builder.depth;
    set_escapes(&mut nodes);
    Bvh {
        nodes,
        order: prims.iter().map(Prim::index).collect(),
        depth,
        bounds: (boxes.0.min.into(), boxes.0.max.into()),
    }
}

/// The children of `node` in the order a ray of direction octant `octant`
/// meets them along the node's axis (child 0 holds the lower side).
pub fn ordered_children(node: &BvhNode, octant: usize) -> [u32; 2] {
    if (octant >> node.axis) & 1 == 0 {
        [node.child0, node.child1]
    } else {
        [node.child1, node.child0]
    }
}

fn inner(c: u32) -> bool {
    c != BVH_NO_CHILD && c & BVH_LEAF == 0
}

/// Where a walk in direction octant `o` goes once a node's subtree is done:
/// the first inner child goes on to its sibling (if inner), anything else to
/// where its parent goes. A parent comes before its children, so one pass
/// in order does it (all octants at each node: the nodes are read once).
fn set_escapes(nodes: &mut [BvhNode]) {
    for n in 0..nodes.len() {
        for o in 0..8 {
            let [first, second] = ordered_children(&nodes[n], o);
            let escape = nodes[n].escapes[o];
            if inner(first) {
                nodes[first as usize].escapes[o] = if inner(second) { second } else { escape };
            }
            if inner(second) {
                nodes[second as usize].escapes[o] = escape;
            }
        }
    }
}

fn node_of(a: &Child, b: &Child) -> BvhNode {
    BvhNode {
        a0: a.points[0].into(),
        child0: a.reference,
        b0: a.points[1].into(),
        axis: 0,
        c0: a.points[2].into(),
        pad0: 0,
        a1: b.points[0].into(),
        child1: b.reference,
        b1: b.points[1].into(),
        pad1: 0,
        c1: b.points[2].into(),
        pad2: 0,
        escapes: [BVH_NO_CHILD; 8],
    }
}

impl Builder<'_, '_> {
    fn range_boxes(&self, start: usize, end: usize) -> Boxes {
        let mut b = Aabb::EMPTY;
        let mut c = Aabb::EMPTY;
        for p in &self.prims[start..end] {
            b.grow(p.min());
            b.grow(p.max());
            c.grow(p.centroid());
        }
        (b, c)
    }

    fn leaf(&self, position: usize) -> Child {
        let [v0, v1, v2] = self.triangles[self.prims[position].index() as usize];
        Child {
            points: [v0, v1 - v0, v2 - v0],
            reference: BVH_LEAF | (self.base + position) as u32,
        }
    }

    /// The child for triangles `start..end`, whose boxes are `boxes`: a
    /// leaf, or a subtree.
    fn child(&mut self, start: usize, end: usize, depth: u32, boxes: &Boxes) -> Child {
        if end - start == 1 {
            self.leaf(start)
        } else {
            let index = self.split(start, end, depth, boxes);
            Child {
                points: [boxes.0.min.into(), boxes.0.max.into(), Vec3::ZERO],
                reference: index,
            }
        }
    }

    /// The children for `start..mid` and `mid..end`, each built on a
    /// thread of its own into its share of the nodes, numbered as one
    /// thread would have numbered them.
    fn children_in_parallel(
        &mut self,
        (start, mid, end): (usize, usize, usize),
        depth: u32,
        halves: &[Boxes; 2],
    ) -> [Child; 2] {
        let triangles = self.triangles;
        let levels = self.parallel_levels - 1;
        let (lo, hi) = self.prims[start..end].split_at_mut(mid - start);
        let left_nodes = (mid - start).max(1) - 1;
        let right_nodes = (end - mid).max(1) - 1;
        let rest = &mut self.nodes[self.next..];
        let (nodes_lo, rest) = rest.split_at_mut(left_nodes);
        let nodes_hi = &mut rest[..right_nodes];
        let first = self.node_base + self.next;
        let sub = |prims: &mut [Prim], base, nodes: &mut [BvhNode], node_base, boxes| {
            let n = prims.len();
            let mut b = Builder {
                triangles,
                prims,
                base,
                nodes,
                next: 0,
                node_base,
                depth: 0,
                parallel_levels: levels,
            };
            let child = b.child(0, n, depth + 1, boxes);
            (child, b.depth)
        };
        let (base_lo, base_hi) = (self.base + start, self.base + mid);
        let (a, b) = std::thread::scope(|s| {
            let right = s.spawn(move || sub(hi, base_hi, nodes_hi, first + left_nodes, &halves[1]));
            let left = sub(lo, base_lo, nodes_lo, first, &halves[0]);
            (left, right.join().expect("a BVH builder thread"))
        });
        self.next += left_nodes + right_nodes;
        self.depth = self.depth.max(a.1).max(b.1);
        [a.0, b.0]
    }

    /// Builds the subtree of triangles `start..end` (at least two), whose
    /// boxes are `boxes`, and returns its root node's index.
    fn split(&mut self, start: usize, end: usize, depth: u32, boxes: &Boxes) -> u32 {
        self.depth = self.depth.max(depth + 1);
        let node = self.next;
        self.next += 1;
        let centroid_bounds = &boxes.1;
        let extent = centroid_bounds.max - centroid_bounds.min;
        let axis = extent.max_position();
        let sah = if extent[axis] <= 0.0 || depth >= MEDIAN_DEPTH {
            None // Coinciding centroids (or a deep tree): halve by position.
        } else {
            self.sah_split(start, end, axis, centroid_bounds)
        };
        let (mid, halves) = sah.unwrap_or_else(|| {
            let mid = self.median_split(start, end, axis);
            (
                mid,
                [self.range_boxes(start, mid), self.range_boxes(mid, end)],
            )
        });
        let children = if self.parallel_levels > 0 && end - start >= PARALLEL_MIN {
            self.children_in_parallel((start, mid, end), depth, &halves)
        } else {
            [(start, mid, &halves[0]), (mid, end, &halves[1])]
                .map(|(s, e, h)| self.child(s, e, depth + 1, h))
        };
        self.nodes[node] = BvhNode {
            axis: axis as u32,
            ..node_of(&children[0], &children[1])
        };
        (self.node_base + node) as u32
    }

    fn median_split(&mut self, start: usize, end: usize, axis: usize) -> usize {
        let mid = (start + end) / 2;
        self.prims[start..end].select_nth_unstable_by(mid - start, |a, b| {
            a.centroid()[axis].total_cmp(&b.centroid()[axis])
        });
        mid
    }

    /// Partitions at the cheapest of the bin planes on `axis` (both sides
    /// non-empty) and returns where, with the two sides' boxes; `None`
    /// when every centroid falls in one bin.
    fn sah_split(
        &mut self,
        start: usize,
        end: usize,
        axis: usize,
        cb: &Aabb,
    ) -> Option<(usize, [Boxes; 2])> {
        let lo = cb.min[axis];
        let scale = BINS as f32 / (cb.max[axis] - lo);
        let bin_of = |c: Vec3A| (((c[axis] - lo) * scale) as usize).min(BINS - 1);
        // Each bin's box, its centroids' box and its count: the sides'
        // boxes come from them, so no pass over a side is needed later.
        let mut bins = [(Aabb::EMPTY, Aabb::EMPTY, 0usize); BINS];
        for p in &self.prims[start..end] {
            let c = p.centroid();
            let b = &mut bins[bin_of(c)];
            b.0.grow(p.min());
            b.0.grow(p.max());
            b.1.grow(c);
            b.2 += 1;
        }
        // Cost of splitting after bin k: left areas from the left, right from the right.
        let mut right_cost = [0.0f32; BINS];
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for k in (1..BINS).rev() {
            acc.merge(&bins[k].0);
            n += bins[k].2;
            right_cost[k] = if n > 0 { acc.area() * n as f32 } else { 0.0 };
        }
        let mut best = (f32::INFINITY, 0usize);
        let mut acc = Aabb::EMPTY;
        let mut n = 0;
        for k in 0..BINS - 1 {
            acc.merge(&bins[k].0);
            n += bins[k].2;
            let cost = if n > 0 { acc.area() * n as f32 } else { 0.0 } + right_cost[k + 1];
            if n > 0 && n < end - start && cost < best.0 {
                best = (cost, k);
            }
        }
        if best.0 == f32::INFINITY {
            return None;
        }
        let split_bin = best.1;
        let mut halves = [(Aabb::EMPTY, Aabb::EMPTY); 2];
        for (k, bin) in bins.iter().enumerate() {
            let h = &mut halves[usize::from(k > split_bin)];
            h.0.merge(&bin.0);
            h.1.merge(&bin.1);
        }
        let slice = &mut self.prims[start..end];
        let mut left = 0;
        for i in 0..slice.len() {
            if bin_of(slice[i].centroid()) <= split_bin {
                slice.swap(i, left);
                left += 1;
            }
        }
        Some((start + left, halves))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(tris: &[[Vec3; 3]]) {
        let bvh = build(tris);
        assert!(bvh.depth < MAX_DEPTH);
        let mut seen = vec![0u32; tris.len()];
        for node in &bvh.nodes {
            let children = [
                (node.child0, node.a0, node.b0, node.c0),
                (node.child1, node.a1, node.b1, node.c1),
            ];
            for (child, a, b, c) in children {
                if child == BVH_NO_CHILD {
                    continue;
                }
                let (bmin, bmax) = (Vec3::from(a), Vec3::from(b));
                let leaves: Vec<usize> = if child & BVH_LEAF != 0 {
                    // A leaf holds its triangle as v0, e1, e2.
                    let t = bvh.order[(child & !BVH_LEAF) as usize] as usize;
                    seen[t] += 1;
                    let [v0, v1, v2] = tris[t];
                    assert_eq!((bmin, bmax, Vec3::from(c)), (v0, v1 - v0, v2 - v0));
                    vec![]
                } else {
                    // Every triangle under an interior child lies in its box.
                    let mut under = Vec::new();
                    let mut stack = vec![child];
                    while let Some(c) = stack.pop() {
                        let n = &bvh.nodes[c as usize];
                        for r in [n.child0, n.child1] {
                            if r == BVH_NO_CHILD {
                            } else if r & BVH_LEAF != 0 {
                                under.push(bvh.order[(r & !BVH_LEAF) as usize] as usize);
                            } else {
                                stack.push(r);
                            }
                        }
                    }
                    under
                };
                for t in leaves {
                    for p in tris[t] {
                        assert!(p.cmpge(bmin).all() && p.cmple(bmax).all());
                    }
                }
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
        // In every octant, a stackless walk that enters every inner child
        // visits every node exactly once.
        for o in 0..8 {
            let mut order = Vec::new();
            let mut node = if bvh.nodes.is_empty() {
                BVH_NO_CHILD
            } else {
                0
            };
            while node != BVH_NO_CHILD {
                order.push(node);
                let n = &bvh.nodes[node as usize];
                node = match ordered_children(n, o) {
                    [f, _] if inner(f) => f,
                    [_, s] if inner(s) => s,
                    _ => n.escapes[o],
                };
            }
            order.sort_unstable();
            assert_eq!(order, (0..bvh.nodes.len() as u32).collect::<Vec<_>>());
        }
    }

    #[test]
    fn threads_build_the_tree_one_thread_builds() {
        let mut tris = Vec::new();
        let mut s = 7u32;
        let mut rnd = || {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            (s >> 8) as f32 / (1 << 24) as f32
        };
        for _ in 0..5 * PARALLEL_MIN {
            let p = Vec3::new(rnd(), rnd(), rnd()) * 100.0;
            tris.push([p, p + Vec3::X, p + Vec3::Y * rnd()]);
        }
        let one = build_with(&tris, 1);
        for threads in [2, 3, 8] {
            let many = build_with(&tris, threads);
            assert!(
                many.nodes == one.nodes && many.order == one.order,
                "{threads} threads"
            );
            assert_eq!(many.depth, one.depth);
        }
        check(&tris);
    }

    #[test]
    fn every_triangle_is_in_exactly_one_leaf_inside_its_boxes() {
        let mut tris = Vec::new();
        let mut s = 1u32;
        let mut rnd = || {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            (s >> 8) as f32 / (1 << 24) as f32
        };
        for _ in 0..2000 {
            let p = Vec3::new(rnd(), rnd(), rnd()) * 100.0;
            tris.push([
                p,
                p + Vec3::new(rnd(), rnd(), 0.0),
                p + Vec3::new(0.0, rnd(), rnd()),
            ]);
        }
        check(&tris);
        // Coinciding triangles, and the smallest scenes.
        check(&vec![[Vec3::ZERO, Vec3::X, Vec3::Y]; 9]);
        check(&tris[..1]);
        check(&tris[..2]);
        check(&[]);
    }
}
