//! Binned-SAH BVH over triangles, flattened for the GPU (see shaders/common/bvh.wgsl).
//!
//! Why our own builder rather than `bvh`/`obvhs`: the GPU layout is the point (32-byte nodes in
//! depth-first order with skip pointers, so traversal needs no stack: per-lane stacks in private
//! arrays are gather/scatter on CPU rasterisers such as lavapipe and ran ~10x slower; triangles
//! re-ordered into leaf order so shading attributes are fetched without indirection), and the
//! build must be deterministic for bit-identical renders. A binned SAH builder (Wald 2007) in
//! ~200 lines gives both; tests compare it with brute force.

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

#[derive(Clone, Debug, Default)]
pub struct Bvh {
    pub nodes: Vec<BvhNode>,
    /// `order[i]` = original index of the i-th triangle in BVH order.
    pub order: Vec<u32>,
    pub depth: usize,
}

#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::MAX),
        max: Vec3::splat(f32::MIN),
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
        if self.min.x > self.max.x {
            return 0.0;
        }
        let d = self.max - self.min;
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

impl Bvh {
    pub fn build(tris: &[[Vec3; 3]]) -> Bvh {
        let n = tris.len();
        let boxes: Vec<Aabb> = tris
            .iter()
            .map(|t| {
                let mut b = Aabb::EMPTY;
                t.iter().for_each(|p| b.grow(*p));
                b
            })
            .collect();
        let centroids: Vec<Vec3> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = vec![BuildNode::default()];
        let mut max_depth = 0;
        // (node index, first, count, depth)
        let mut work = vec![(0usize, 0usize, n, 0usize)];
        while let Some((ni, first, count, depth)) = work.pop() {
            max_depth = max_depth.max(depth);
            let mut bounds = Aabb::EMPTY;
            let mut cbounds = Aabb::EMPTY;
            for &t in &order[first..first + count] {
                bounds.merge(&boxes[t as usize]);
                cbounds.grow(centroids[t as usize]);
            }
            let leaf = |nodes: &mut Vec<BuildNode>| {
                nodes[ni] = BuildNode {
                    min: bounds.min.to_array(),
                    max: bounds.max.to_array(),
                    left_or_first: first as u32,
                    count: count as u32,
                };
            };
            if count <= 1 {
                leaf(&mut nodes);
                continue;
            }
            let split = best_split(&order[first..first + count], &boxes, &centroids, &cbounds);
            let leaf_cost = count as f32;
            let mid = match split {
                Some((axis, pos, cost)) if cost < leaf_cost || count > MAX_LEAF => {
                    partition(&mut order[first..first + count], |t| {
                        centroids[t as usize][axis] < pos
                    })
                }
                _ if count <= MAX_LEAF => {
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
        if n == 0 {
            // Nothing to hit: no nodes at all, traversal ends at once.
            return Bvh {
                nodes: Vec::new(),
                order,
                depth: 0,
            };
        }
        Bvh {
            nodes: flatten_depth_first(&nodes),
            order,
            depth: max_depth,
        }
    }

    /// CPU closest hit, the same algorithm as the WGSL traversal: (t, original triangle index).
    pub fn closest_hit(
        &self,
        tris: &[[Vec3; 3]],
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
    ) -> Option<(f32, u32)> {
        let mut best: Option<(f32, u32)> = None;
        let mut t_best = t_max;
        let inv = Vec3::ONE / dir;
        let mut i = 0usize;
        while i < self.nodes.len() {
            let node = &self.nodes[i];
            if !ray_box(
                origin,
                inv,
                Vec3::from(node.min),
                Vec3::from(node.max),
                t_best,
            ) {
                i = node.skip as usize;
                continue;
            }
            if node.tri_count() == 0 {
                i += 1;
                continue;
            }
            for k in node.first_tri()..node.first_tri() + node.tri_count() {
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

#[allow(clippy::needless_range_loop)] // `axis` indexes vectors, not one array.
fn best_split(
    refs: &[u32],
    boxes: &[Aabb],
    centroids: &[Vec3],
    cbounds: &Aabb,
) -> Option<(usize, f32, f32)> {
    let mut best: Option<(usize, f32, f32)> = None;
    let mut parent = Aabb::EMPTY;
    refs.iter().for_each(|&t| parent.merge(&boxes[t as usize]));
    let parent_area = parent.area().max(1e-30);
    for axis in 0..3 {
        let lo = cbounds.min[axis];
        let extent = cbounds.max[axis] - lo;
        if extent <= 1e-12 {
            continue;
        }
        let mut bins = [(Aabb::EMPTY, 0usize); BINS];
        let scale = BINS as f32 / extent;
        for &t in refs {
            let b = (((centroids[t as usize][axis] - lo) * scale) as usize).min(BINS - 1);
            bins[b].0.merge(&boxes[t as usize]);
            bins[b].1 += 1;
        }
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
