//! Binned-SAH BVH over triangles, flattened for the GPU (see shaders/common/bvh.wgsl).
//!
//! Why our own builder rather than `bvh`/`obvhs`: the GPU layout is the point (32-byte nodes in
//! depth-first order with skip pointers, so traversal needs no stack: per-lane stacks in private
//! arrays are gather/scatter on CPU rasterisers such as lavapipe and ran ~10x slower; triangles
//! re-ordered into leaf order so shading attributes are fetched without indirection), and the
//! build must be deterministic for bit-identical renders. A binned SAH builder (Wald 2007) in
//! ~300 lines gives both, built in parallel with rayon (bit for bit the sequential result);
//! tests compare it with brute force and with the sequential build.

use glam::Vec3;

/// Matches `BvhNode` in shaders/common/scene.wgsl. Nodes are in depth-first order: a hit on an
/// interior node continues at the next node (its left child), a miss or a finished leaf at `skip`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BvhNode {
    pub min: [f32; 3],
    /// Index of the next node after this subtree (== node count at the end).
    pub skip: u32,
    pub max: [f32; 3],
    /// Leaf: first triangle (BVH order) << 8 | count. Interior: 0.
    pub tris: u32,
}

impl BvhNode {
    pub fn tri_count(&self) -> u32 {
        self.tris & 0xff
    }
    pub fn first_tri(&self) -> u32 {
        self.tris >> 8
    }
}

pub const MAX_LEAF: usize = 4;
/// Leaves hold at most 255 triangles and 2^24 triangles in all (the packing of `BvhNode::tris`).
pub const MAX_TRIANGLES: usize = 1 << 24;
const BINS: usize = 16;

/// Build-time node: children adjacent (left, left + 1).
#[derive(Clone, Copy, Default)]
struct BuildNode {
    min: [f32; 3],
    max: [f32; 3],
    left_or_first: u32,
    count: u32,
}

impl BuildNode {
    /// The node of a subtree whose local nodes 1.. are appended at `base` (leaves unchanged:
    /// their triangle ranges are global).
    fn moved_to(self, base: u32) -> BuildNode {
        let mut b = self;
        if b.count == 0 {
            b.left_or_first = base + b.left_or_first - 1;
        }
        b
    }
}

/// Subtrees of at most this many triangles are built as independent parallel jobs.
const SUBTREE: usize = 16 * 1024;
/// Ranges at least this large reduce their bounds and SAH bins in parallel.
const PARALLEL_REDUCE: usize = 32 * 1024;

/// A range left for a parallel job: its node, triangles `order[first..first + count]`, depth.
struct Job {
    node: usize,
    first: usize,
    count: usize,
    depth: usize,
}

/// Nodes built over one range (root at 0, children adjacent), and the ranges left as jobs.
struct Subtree {
    nodes: Vec<BuildNode>,
    jobs: Vec<Job>,
    max_depth: usize,
}

struct BuildContext<'a> {
    boxes: &'a [Aabb],
    centroids: &'a [Vec3],
    parallel: bool,
    /// Most primitives per leaf (MAX_LEAF for triangles, 1 for the instances of a top level).
    max_leaf: usize,
}

impl BuildContext<'_> {
    /// Bounds of the triangles and of their centroids.
    fn bounds(&self, refs: &[u32]) -> (Aabb, Aabb) {
        let fold = |(mut b, mut c): (Aabb, Aabb), &t: &u32| {
            b.merge(&self.boxes[t as usize]);
            c.grow(self.centroids[t as usize]);
            (b, c)
        };
        if self.parallel && refs.len() >= PARALLEL_REDUCE {
            use rayon::prelude::*;
            refs.par_chunks(4096)
                .map(|c| c.iter().fold((Aabb::EMPTY, Aabb::EMPTY), fold))
                .reduce(
                    || (Aabb::EMPTY, Aabb::EMPTY),
                    |(mut a, mut b), (c, d)| {
                        a.merge(&c);
                        b.merge(&d);
                        (a, b)
                    },
                )
        } else {
            refs.iter().fold((Aabb::EMPTY, Aabb::EMPTY), fold)
        }
    }

    /// Builds the tree over `order` (global triangle offset `offset`, root depth `depth`);
    /// ranges of at most `stop` triangles that would be split are left as jobs instead.
    fn build_range(&self, order: &mut [u32], offset: usize, depth: usize, stop: usize) -> Subtree {
        let mut nodes = vec![BuildNode::default()];
        let mut jobs = Vec::new();
        let mut max_depth = depth;
        // (node index, first, count, depth), `first` relative to `order`.
        let mut work = vec![(0usize, 0usize, order.len(), depth)];
        while let Some((ni, first, count, depth)) = work.pop() {
            max_depth = max_depth.max(depth);
            if count <= stop && count > 1 {
                jobs.push(Job {
                    node: ni,
                    first: offset + first,
                    count,
                    depth,
                });
                continue;
            }
            let range = &mut order[first..first + count];
            let (bounds, cbounds) = self.bounds(range);
            let leaf = |nodes: &mut Vec<BuildNode>| {
                nodes[ni] = BuildNode {
                    min: bounds.min.to_array(),
                    max: bounds.max.to_array(),
                    left_or_first: (offset + first) as u32,
                    count: count as u32,
                };
            };
            if count <= 1 {
                leaf(&mut nodes);
                continue;
            }
            let split = best_split(range, self, &bounds, &cbounds);
            let leaf_cost = count as f32;
            let mid = match split {
                Some((axis, pos, cost)) if cost < leaf_cost || count > self.max_leaf => {
                    partition(range, |t| self.centroids[t as usize][axis] < pos)
                }
                _ if count <= self.max_leaf => {
                    leaf(&mut nodes);
                    continue;
                }
                _ => 0,
            };
            // Degenerate split (all centroids equal): halve the range so the tree still shrinks.
            let mid = if mid == 0 || mid == count {
                count / 2
            } else {
                mid
            };
            let left = nodes.len();
            nodes.push(BuildNode::default());
            nodes.push(BuildNode::default());
            nodes[ni] = BuildNode {
                min: bounds.min.to_array(),
                max: bounds.max.to_array(),
                left_or_first: left as u32,
                count: 0,
            };
            work.push((left + 1, first + mid, count - mid, depth + 1));
            work.push((left, first, mid, depth + 1));
        }
        Subtree {
            nodes,
            jobs,
            max_depth,
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// A flat tree, or with instances (`build_instanced`): the top level, then one bottom
    /// level per mesh, then the instance records (two nodes each, see `InstanceRecord`).
    pub nodes: Vec<BvhNode>,
    /// `order[i]` = original index of the i-th triangle in BVH order.
    pub order: Vec<u32>,
    /// Deepest leaf (top level plus bottom level with instances).
    pub depth: usize,
    /// Instances traced through their mesh's bottom-level tree (0: a flat tree).
    pub instances: usize,
    /// Meshes with a bottom-level tree of their own (the rest of the scene not counted).
    pub instanced_meshes: usize,
    /// What rebuilding the top level needs (two levels only): `Bvh::rebuild_top`.
    pub top: Option<TopLevel>,
}

/// The top level of a two-level BVH, kept so that it can be rebuilt when instances move while
/// the bottom levels stay (src/scene/instancing.rs).
#[derive(Clone, Debug, Default)]
pub struct TopLevel {
    pub entries: Vec<TopEntry>,
    /// Nodes of the top level (the first ones of `Bvh::nodes`).
    pub nodes: usize,
    /// Where the instance records start in `Bvh::nodes` (two nodes an entry).
    pub records_at: usize,
    /// The deepest bottom-level tree.
    pub bottom_depth: usize,
}

/// One leaf of the top level: the rest of the scene (no instance) or one instance.
#[derive(Clone, Copy, Debug)]
pub struct TopEntry {
    /// The bottom-level tree's root box (object space; world space for the rest).
    pub object_min: Vec3,
    pub object_max: Vec3,
    /// The tree's nodes `root..end` in `Bvh::nodes`, its triangles from `tri_offset` on.
    pub root: u32,
    pub end: u32,
    pub tri_offset: u32,
    /// Index in `Scene::instances` (None: the rest of the scene).
    pub instance: Option<usize>,
}

#[derive(Clone, Copy)]
pub(crate) struct Aabb {
    pub(crate) min: Vec3,
    pub(crate) max: Vec3,
}

impl Aabb {
    pub(crate) const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::MAX),
        max: Vec3::splat(f32::MIN),
    };
    pub(crate) fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    pub(crate) fn merge(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    fn area(&self) -> f32 {
        if self.min.x > self.max.x {
            return 0.0;
        }
        let d = self.max - self.min;
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

impl Bvh {
    /// Parallel build (rayon): bit for bit the same BVH as `build_sequential`.
    pub fn build(tris: &[[Vec3; 3]]) -> Bvh {
        Self::build_with(tris, true)
    }

    /// Single-threaded build (the reference the parallel build is tested against).
    pub fn build_sequential(tris: &[[Vec3; 3]]) -> Bvh {
        Self::build_with(tris, false)
    }

    /// Top-down binned SAH. Parallel without changing the result: the top of the tree is split
    /// on one thread with parallel reductions (bounds and SAH bins are min/max and integer
    /// sums, exact in any order), down to subtrees of at most `SUBTREE` triangles; those are
    /// built independently on disjoint ranges of `order` and stitched in. Every split decision
    /// is the same function of its range's contents as in the sequential build.
    fn build_with(tris: &[[Vec3; 3]], parallel: bool) -> Bvh {
        use rayon::prelude::*;
        let bbox = |t: &[Vec3; 3]| {
            let mut b = Aabb::EMPTY;
            t.iter().for_each(|p| b.grow(*p));
            b
        };
        let boxes: Vec<Aabb> = if parallel {
            tris.par_iter().map(bbox).collect()
        } else {
            tris.iter().map(bbox).collect()
        };
        Self::build_boxes(&boxes, parallel, MAX_LEAF)
    }

    /// The same builder over boxes (triangles' bounds, or instances' for a top level).
    pub(crate) fn build_boxes(boxes: &[Aabb], parallel: bool, max_leaf: usize) -> Bvh {
        use rayon::prelude::*;
        let n = boxes.len();
        let centroids: Vec<Vec3> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        if n == 0 {
            // Nothing to hit: no nodes at all, traversal ends at once.
            return Bvh {
                order,
                ..Default::default()
            };
        }
        let ctx = BuildContext {
            boxes,
            centroids: &centroids,
            parallel,
            max_leaf,
        };
        // The top of the tree; ranges of at most SUBTREE triangles come back as jobs.
        let stop = if parallel { SUBTREE } else { 0 };
        let top = ctx.build_range(&mut order, 0, 0, stop);
        let mut nodes = top.nodes;
        let mut max_depth = top.max_depth;
        // Subtrees on disjoint slices of `order`, in parallel, then stitched in job order.
        let mut jobs = top.jobs;
        jobs.sort_by_key(|j| j.first);
        let mut slices = Vec::with_capacity(jobs.len());
        let mut rest: &mut [u32] = &mut order;
        let mut at = 0;
        for j in &jobs {
            let (_, tail) = rest.split_at_mut(j.first - at);
            let (mine, tail) = tail.split_at_mut(j.count);
            slices.push(mine);
            rest = tail;
            at = j.first + j.count;
        }
        let subtrees: Vec<Subtree> = slices
            .into_par_iter()
            .zip(jobs.par_iter())
            .map(|(slice, j)| ctx.build_range(slice, j.first, j.depth, 0))
            .collect();
        for (j, sub) in jobs.iter().zip(subtrees) {
            max_depth = max_depth.max(sub.max_depth);
            // Local node k >= 1 goes to base + k - 1; local 0 replaces the job's node.
            let base = nodes.len() as u32;
            nodes[j.node] = sub.nodes[0].moved_to(base);
            nodes.extend(sub.nodes[1..].iter().map(|b| b.moved_to(base)));
        }
        Bvh {
            nodes: flatten_depth_first(&nodes),
            order,
            depth: max_depth,
            ..Default::default()
        }
    }

    /// CPU closest hit, the same algorithm as the WGSL traversal (instances included):
    /// (t, original triangle index).
    pub fn closest_hit(
        &self,
        tris: &[[Vec3; 3]],
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
    ) -> Option<(f32, u32)> {
        let mut best: Option<(f32, u32)> = None;
        let mut t_best = t_max;
        let world_inv = Vec3::ONE / dir;
        // Node tests use the ray in the current tree's space; triangles are tested in world
        // space (the flattened triangles), so `t` is one parameter throughout.
        let (mut o, mut inv) = (origin, world_inv);
        let top_end = self.nodes.first().map_or(0, |n| n.skip as usize);
        let (mut end, mut resume, mut tri_base, mut inside) = (top_end, 0usize, 0u32, false);
        let mut i = 0usize;
        loop {
            if i >= end {
                if !inside {
                    break;
                }
                (i, end, o, inv, tri_base, inside) = (resume, top_end, origin, world_inv, 0, false);
                continue;
            }
            let node = &self.nodes[i];
            if !ray_box(o, inv, Vec3::from(node.min), Vec3::from(node.max), t_best) {
                i = node.skip as usize;
                continue;
            }
            if node.tri_count() == 0 {
                i += 1;
                continue;
            }
            if node.tri_count() == INSTANCE_LEAF {
                let r = self.instance_record(node.first_tri() as usize);
                o = r.to_object_point(origin);
                inv = Vec3::ONE / r.to_object_vector(dir);
                (resume, i, end) = (node.skip as usize, r.root as usize, r.end as usize);
                (tri_base, inside) = (r.tri_offset, true);
                continue;
            }
            let first = tri_base + node.first_tri();
            for k in first..first + node.tri_count() {
                let orig = self.order[k as usize];
                if let Some(t) = intersect_triangle(origin, dir, &tris[orig as usize]) {
                    if t > 0.0 && t < t_best {
                        t_best = t;
                        best = Some((t, orig));
                    }
                }
            }
            i = node.skip as usize;
        }
        best
    }

    /// The instance record stored in nodes `at` and `at + 1`.
    pub fn instance_record(&self, at: usize) -> InstanceRecord {
        bytemuck::cast_slice::<BvhNode, InstanceRecord>(&self.nodes[at..at + 2])[0]
    }
}

/// The spectral norm of `m`: the square root of the largest eigenvalue of the symmetric mᵀm
/// (closed form, Smith 1961, in f64), rounded up a little so that 1 / it stays a lower bound;
/// 1 for the identity.
fn largest_singular_value(m: glam::Mat3) -> f32 {
    if m == glam::Mat3::IDENTITY {
        return 1.0;
    }
    let a = (m.transpose() * m).as_dmat3();
    let (a00, a11, a22) = (a.x_axis.x, a.y_axis.y, a.z_axis.z);
    let (a01, a02, a12) = (a.y_axis.x, a.z_axis.x, a.z_axis.y);
    let p1 = a01 * a01 + a02 * a02 + a12 * a12;
    let largest = if p1 <= 0.0 {
        a00.max(a11).max(a22)
    } else {
        let q = (a00 + a11 + a22) / 3.0;
        let p2 = (a00 - q).powi(2) + (a11 - q).powi(2) + (a22 - q).powi(2) + 2.0 * p1;
        let p = (p2 / 6.0).sqrt();
        let b = (a - glam::DMat3::from_diagonal(glam::DVec3::splat(q))) * (1.0 / p);
        let phi = (b.determinant() / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
        q + 2.0 * p * phi.cos()
    };
    ((largest.max(0.0).sqrt() * (1.0 + 1e-5)) as f32).max(f32::MIN_POSITIVE)
}

/// `BvhNode::tri_count` of a top-level leaf: `first_tri` is then the node index of an
/// `InstanceRecord` (triangle leaves hold at most MAX_LEAF triangles).
pub const INSTANCE_LEAF: u32 = 0xff;

/// One instance in the node array (two nodes' worth, so no extra binding): the world-to-object
/// transform as three columns and a translation in the nodes' float slots, the bottom-level
/// tree's node range and the instance's first triangle (BVH order) in their integer slots.
/// Matches `instance_record` in shaders/common/bvh.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct InstanceRecord {
    pub column_x: [f32; 3],
    /// First node of the instance's bottom-level tree.
    pub root: u32,
    pub column_y: [f32; 3],
    /// One past its last node.
    pub end: u32,
    pub column_z: [f32; 3],
    /// Added to the bottom-level leaves' triangle indices.
    pub tri_offset: u32,
    pub translation: [f32; 3],
    /// A lower bound of world length per object length (1 / the largest singular value of the
    /// world-to-object matrix): point queries prune object-space boxes with it.
    pub distance_scale: f32,
}

impl InstanceRecord {
    pub fn new(world_to_object: glam::Mat4, root: u32, end: u32, tri_offset: u32) -> Self {
        let c = |v: glam::Vec4| v.truncate().to_array();
        InstanceRecord {
            column_x: c(world_to_object.x_axis),
            root,
            column_y: c(world_to_object.y_axis),
            end,
            column_z: c(world_to_object.z_axis),
            tri_offset,
            translation: c(world_to_object.w_axis),
            distance_scale: 1.0 / largest_singular_value(glam::Mat3::from_mat4(world_to_object)),
        }
    }
    pub fn to_object_vector(&self, v: Vec3) -> Vec3 {
        Vec3::from(self.column_x) * v.x
            + Vec3::from(self.column_y) * v.y
            + Vec3::from(self.column_z) * v.z
    }
    pub fn to_object_point(&self, p: Vec3) -> Vec3 {
        self.to_object_vector(p) + Vec3::from(self.translation)
    }
}

/// Re-lays the tree out depth-first and sets each node's skip pointer.
fn flatten_depth_first(build: &[BuildNode]) -> Vec<BvhNode> {
    let mut out: Vec<BvhNode> = Vec::with_capacity(build.len());
    // Iterative pre-order; a node's skip is out.len() once its whole subtree is emitted.
    enum Visit {
        Enter(usize),
        Exit(usize),
    }
    let mut work = vec![Visit::Enter(0)];
    while let Some(v) = work.pop() {
        match v {
            Visit::Enter(bi) => {
                let b = &build[bi];
                let tris = if b.count > 0 {
                    (b.left_or_first << 8) | b.count.min(255)
                } else {
                    0
                };
                out.push(BvhNode {
                    min: b.min,
                    skip: 0,
                    max: b.max,
                    tris,
                });
                let oi = out.len() - 1;
                work.push(Visit::Exit(oi));
                if b.count == 0 {
                    work.push(Visit::Enter(b.left_or_first as usize + 1));
                    work.push(Visit::Enter(b.left_or_first as usize));
                }
            }
            Visit::Exit(oi) => out[oi].skip = out.len() as u32,
        }
    }
    out
}

/// The SAH bins of one axis: (bounds, count) per bin.
type Bins = [(Aabb, usize); BINS];

#[allow(clippy::needless_range_loop)] // `axis` indexes vectors, not one array.
fn best_split(
    refs: &[u32],
    ctx: &BuildContext,
    parent: &Aabb,
    cbounds: &Aabb,
) -> Option<(usize, f32, f32)> {
    let mut best: Option<(usize, f32, f32)> = None;
    let parent_area = parent.area().max(1e-30);
    for axis in 0..3 {
        let lo = cbounds.min[axis];
        let extent = cbounds.max[axis] - lo;
        if extent <= 1e-12 {
            continue;
        }
        let scale = BINS as f32 / extent;
        let fill = |mut bins: Bins, &t: &u32| {
            let b = (((ctx.centroids[t as usize][axis] - lo) * scale) as usize).min(BINS - 1);
            bins[b].0.merge(&ctx.boxes[t as usize]);
            bins[b].1 += 1;
            bins
        };
        let empty: Bins = [(Aabb::EMPTY, 0usize); BINS];
        let bins = if ctx.parallel && refs.len() >= PARALLEL_REDUCE {
            use rayon::prelude::*;
            // Bin bounds merge by min/max and counts add: exact in any order.
            refs.par_chunks(4096)
                .map(|c| c.iter().fold(empty, fill))
                .reduce(
                    || empty,
                    |mut a, b| {
                        for i in 0..BINS {
                            a[i].0.merge(&b[i].0);
                            a[i].1 += b[i].1;
                        }
                        a
                    },
                )
        } else {
            refs.iter().fold(empty, fill)
        };
        // Sweep from the right to get right-side areas, then from the left.
        let mut right_area = [0.0f32; BINS];
        let mut right_count = [0usize; BINS];
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for i in (1..BINS).rev() {
            acc.merge(&bins[i].0);
            cnt += bins[i].1;
            right_area[i] = acc.area();
            right_count[i] = cnt;
        }
        let mut left = Aabb::EMPTY;
        let mut left_count = 0;
        for i in 0..BINS - 1 {
            left.merge(&bins[i].0);
            left_count += bins[i].1;
            if left_count == 0 || right_count[i + 1] == 0 {
                continue;
            }
            let cost = 1.0
                + (left.area() * left_count as f32 + right_area[i + 1] * right_count[i + 1] as f32)
                    / parent_area;
            if best.is_none_or(|b| cost < b.2) {
                best = Some((axis, lo + extent * (i + 1) as f32 / BINS as f32, cost));
            }
        }
    }
    best
}

fn partition(slice: &mut [u32], pred: impl Fn(u32) -> bool) -> usize {
    let mut i = 0;
    for j in 0..slice.len() {
        if pred(slice[j]) {
            slice.swap(i, j);
            i += 1;
        }
    }
    i
}

fn ray_box(o: Vec3, inv: Vec3, min: Vec3, max: Vec3, t_max: f32) -> bool {
    let t0 = (min - o) * inv;
    let t1 = (max - o) * inv;
    let tmin = t0.min(t1);
    let tmax = t0.max(t1);
    let enter = tmin.max_element().max(0.0);
    let exit = tmax.min_element().min(t_max);
    enter <= exit
}

/// Moller-Trumbore, as in the shader; None for misses and zero-area triangles.
pub fn intersect_triangle(o: Vec3, d: Vec3, t: &[Vec3; 3]) -> Option<f32> {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - t[0];
    let b1 = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = s.cross(e1);
    let b2 = d.dot(q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    Some(e2.dot(q) * inv)
}

/// Brute-force closest hit over all triangles (tests and benchmarks).
pub fn brute_force_closest(tris: &[[Vec3; 3]], origin: Vec3, dir: Vec3) -> Option<(f32, u32)> {
    let mut best: Option<(f32, u32)> = None;
    for (i, t) in tris.iter().enumerate() {
        if let Some(h) = intersect_triangle(origin, dir, t) {
            if h > 0.0 && best.is_none_or(|b| h < b.0) {
                best = Some((h, i as u32));
            }
        }
    }
    best
}
