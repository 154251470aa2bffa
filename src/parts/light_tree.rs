//! # Light tree (`light_sampling = "tree"`, issue 60)
//!
//! A bounding volume hierarchy over the light pool's local lights (emissive triangles, point
//! and spot lights) whose nodes carry what a light can give a point: spatial bounds, an
//! orientation cone (the directions it emits into) and power. A shading point picks a light by
//! one stochastic descent from the root, at each node choosing a child in proportion to its
//! importance there (power over squared distance, bounded by the cone's and the receiving
//! normal's angles), and the probability of any given light is the product of the choices on
//! its path (its "bit trail"), so a BSDF-sampled hit on an emitter can be weighted by MIS.
//! This follows pbrt-v4's `BVHLightSampler` (Pharr, Jakob, Humphreys, 4th edition, 12.6.3),
//! itself after Conty Estevez and Kulla 2018; directional lights stay outside the tree, as
//! pbrt's infinite lights do, and are picked by their share of the pool's power.
//!
//! The tree is built on the CPU with the light pool (on load, and again each frame the scene is
//! re-posed, so lights that move are followed; its build time is `SceneTimings::light_tree_ms`)
//! and travels in the light pool's buffer after the lights (one 96-byte record a node, the
//! lights' stride: a new binding would put the largest passes over 32 storage buffers).
//! Shader side: `shaders/parts/light_tree.wgsl`, used by `gilab::lights` when a pipeline sets
//! the `LIGHT_TREE` def. The CPU functions here ([`LightTree::sample`], [`LightTree::pmf`])
//! mirror it line by line; tests hold them to each other and to the GPU.
//!
//! Differences from pbrt-v4, all stated in docs/light-tree.md: node records are 96 bytes in
//! the light pool (pbrt: 32, quantised); the bit trail is 64 bits (as pbrt's), guaranteed by
//! median splits below depth 32; spot lights' cone is the outer angle with a 0.001 rad
//! falloff margin (pbrt uses the inner angle and the falloff width, which is 0 for a hard
//! spot and then rejects every point).

use glam::Vec3;

/// What one light (or a node's lights together) can give a point: spatial bounds, power, and
/// the cone of emitted directions: an axis, the spread of the normals around it (`cos_theta_o`)
/// and how far past them light still leaves (`cos_theta_e`, pi/2 for a surface).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightBounds {
    pub lo: Vec3,
    pub hi: Vec3,
    pub phi: f32,
    pub axis: Vec3,
    pub cos_theta_o: f32,
    pub cos_theta_e: f32,
    /// Emits from both faces (a double-sided emissive triangle).
    pub two_sided: bool,
}

impl LightBounds {
    /// A one- or two-sided emissive triangle of power `phi`.
    pub fn triangle(t: &[Vec3; 3], phi: f32, two_sided: bool) -> LightBounds {
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or(Vec3::Z);
        LightBounds {
            lo: t[0].min(t[1]).min(t[2]),
            hi: t[0].max(t[1]).max(t[2]),
            phi,
            axis: n,
            cos_theta_o: 1.0,
            cos_theta_e: 0.0,
            two_sided,
        }
    }

    /// A point light: every direction.
    pub fn point(p: Vec3, phi: f32) -> LightBounds {
        LightBounds {
            lo: p,
            hi: p,
            phi,
            axis: Vec3::Z,
            cos_theta_o: -1.0,
            cos_theta_e: 0.0,
            two_sided: false,
        }
    }

    /// A spot light pointing along `dir` with outer cone angle `outer` (radians).
    pub fn spot(p: Vec3, dir: Vec3, outer: f32, phi: f32) -> LightBounds {
        LightBounds {
            lo: p,
            hi: p,
            phi,
            axis: dir.normalize_or(Vec3::NEG_Y),
            cos_theta_o: outer.clamp(0.0, std::f32::consts::PI).cos(),
            cos_theta_e: SPOT_MARGIN.cos(),
            two_sided: false,
        }
    }

    pub fn centroid(&self) -> Vec3 {
        0.5 * (self.lo + self.hi)
    }

    /// Both lights' bounds together (pbrt-v4 `Union(LightBounds, LightBounds)`).
    pub fn union(&self, o: &LightBounds) -> LightBounds {
        if self.phi <= 0.0 {
            return *o;
        }
        if o.phi <= 0.0 {
            return *self;
        }
        let (axis, cos_theta_o) = cone_union(self.axis, self.cos_theta_o, o.axis, o.cos_theta_o);
        LightBounds {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
            phi: self.phi + o.phi,
            axis,
            cos_theta_o,
            cos_theta_e: self.cos_theta_e.min(o.cos_theta_e),
            two_sided: self.two_sided || o.two_sided,
        }
    }

    /// How much this node's lights may give point `p` with normal `n` (zero: `n` = 0 leaves the
    /// normal out): power over squared distance, times the cosine of the smallest angle any of
    /// its points and normals can make with `p`, times the receiving cosine bounded the same
    /// way. Zero only where no light of the node can reach the hemisphere around `n`: the
    /// bounds are conservative, so sampling by it stays unbiased. pbrt-v4
    /// `LightBounds::Importance`, with a one-sided receiver (gilab's BSDFs only reflect).
    pub fn importance(&self, p: Vec3, n: Vec3) -> f32 {
        let pc = self.centroid();
        let d2 = (p - pc)
            .length_squared()
            .max(0.5 * (self.hi - self.lo).length())
            .max(1e-12);
        let wi = (p - pc).normalize_or_zero();
        let mut cos_w = self.axis.dot(wi);
        if self.two_sided {
            cos_w = cos_w.abs();
        }
        let sin_w = safe_sqrt(1.0 - cos_w * cos_w);
        let cos_b = bound_subtended_cos(self.lo, self.hi, p);
        let sin_b = safe_sqrt(1.0 - cos_b * cos_b);
        let sin_o = safe_sqrt(1.0 - self.cos_theta_o * self.cos_theta_o);
        let cos_x = cos_sub_clamped(sin_w, cos_w, sin_o, self.cos_theta_o);
        let sin_x = sin_sub_clamped(sin_w, cos_w, sin_o, self.cos_theta_o);
        let cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
        if cos_p <= self.cos_theta_e {
            return 0.0;
        }
        let mut importance = self.phi * cos_p / d2;
        if n != Vec3::ZERO {
            let cos_i = -wi.dot(n);
            let sin_i = safe_sqrt(1.0 - cos_i * cos_i);
            importance *= cos_sub_clamped(sin_i, cos_i, sin_b, cos_b);
        }
        importance.max(0.0)
    }

    /// A lightcut's error bound for the node at `p`: its importance with the squared distance
    /// to the box's nearest point in place of the centre's (lightcuts bound a node's error by
    /// its largest possible contribution; Walter et al. 2005, Yuksel 2019). Near or around `p`
    /// it grows without limit, so the cut splits there first.
    pub fn lightcut_error(&self, p: Vec3, n: Vec3) -> f32 {
        let d2 = (p - self.centroid())
            .length_squared()
            .max(0.5 * (self.hi - self.lo).length())
            .max(1e-12);
        let nearest = p.clamp(self.lo, self.hi);
        let near2 = (p - nearest).length_squared().max(1e-12);
        self.importance(p, n) * (d2 / near2).min(LIGHTCUT_NEAR_LIMIT)
    }

    /// pbrt-v4's surface area orientation heuristic: the cost of a node with these bounds,
    /// split along `dim` of `extent` (the parent's bounds).
    fn cost(&self, extent: Vec3, dim: usize) -> f32 {
        use std::f32::consts::PI;
        let theta_o = self.cos_theta_o.clamp(-1.0, 1.0).acos();
        let theta_e = self.cos_theta_e.clamp(-1.0, 1.0).acos();
        let theta_w = (theta_o + theta_e).min(PI);
        let sin_o = safe_sqrt(1.0 - self.cos_theta_o * self.cos_theta_o);
        let m_omega = 2.0 * PI * (1.0 - self.cos_theta_o)
            + PI / 2.0
                * (2.0 * theta_w * sin_o - (theta_o - 2.0 * theta_w).cos() - 2.0 * theta_o * sin_o
                    + self.cos_theta_o);
        let kr = extent.max_element() / extent[dim].max(1e-12);
        let d = self.hi - self.lo;
        let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
        self.phi * m_omega * kr * area
    }
}

/// Spot lights' falloff margin past their outer angle (radians): a cone that ends exactly at
/// its normals' spread would give a point inside it zero importance.
const SPOT_MARGIN: f32 = 1e-3;
/// Below this depth a node splits at the median, so that every bit trail fits in 64 bits.
const MEDIAN_DEPTH: u32 = 32;
/// SAOH buckets per axis (pbrt-v4's 12).
const BUCKETS: usize = 12;
/// The largest u32 below 1 as f32: a remapped random number stays in [0, 1).
const ONE_MINUS_EPSILON: f32 = 0.99999994;

fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// cos(max(0, a - b)) from the sines and cosines of a and b.
fn cos_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        1.0
    } else {
        cos_a * cos_b + sin_a * sin_b
    }
}

/// sin(max(0, a - b)) from the sines and cosines of a and b.
fn sin_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        0.0
    } else {
        sin_a * cos_b - cos_a * sin_b
    }
}

/// Cosine of the half-angle of the cone from `p` that holds the box's bounding sphere (-1: `p`
/// inside it, every direction).
fn bound_subtended_cos(lo: Vec3, hi: Vec3, p: Vec3) -> f32 {
    let c = 0.5 * (lo + hi);
    let r2 = (hi - c).length_squared();
    let d2 = (p - c).length_squared();
    if d2 < r2 {
        return -1.0;
    }
    safe_sqrt(1.0 - r2 / d2.max(1e-30))
}

/// The smallest cone holding two cones (pbrt-v4 `Union(DirectionCone, DirectionCone)`).
fn cone_union(a: Vec3, cos_a: f32, b: Vec3, cos_b: f32) -> (Vec3, f32) {
    use std::f32::consts::PI;
    let theta_a = cos_a.clamp(-1.0, 1.0).acos();
    let theta_b = cos_b.clamp(-1.0, 1.0).acos();
    let theta_d = a.dot(b).clamp(-1.0, 1.0).acos();
    if (theta_d + theta_b).min(PI) <= theta_a {
        return (a, cos_a);
    }
    if (theta_d + theta_a).min(PI) <= theta_b {
        return (b, cos_b);
    }
    let theta_o = 0.5 * (theta_a + theta_d + theta_b);
    if theta_o >= PI {
        return (a, -1.0);
    }
    let wr = a.cross(b);
    if wr.length_squared() < 1e-12 {
        return (a, -1.0);
    }
    let axis = glam::Quat::from_axis_angle(wr.normalize(), theta_o - theta_a) * a;
    (axis.normalize(), theta_o.cos())
}

/// Splits a lightcut may try (`LIGHTCUT_STEPS` in shaders/parts/cache_light.wgsl): a split
/// whose children both cannot reach the point shrinks the cut, so growing it takes a bounded
/// loop on the GPU.
pub const LIGHTCUT_STEPS: usize = 64;
/// The most a lightcut's error bound grows over the importance near a node
/// (`LIGHTCUT_NEAR_LIMIT` in shaders/parts/light_tree.wgsl).
pub const LIGHTCUT_NEAR_LIMIT: f32 = 1e6;

/// One node as the GPU reads it, in a light record's slot of the light pool (96 bytes, the
/// layout of `GpuLight`: shaders/parts/light_tree.wgsl `tree_node` decodes it). Children of an
/// interior node: the next record, and `index`. A leaf: `index` is its light.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuLightTreeNode {
    /// 1 for a leaf.
    pub leaf: u32,
    pub index: u32,
    pub phi: f32,
    pub cos_theta_o: f32,
    pub cos_theta_e: f32,
    /// 1 when two-sided.
    pub two_sided: f32,
    pub pad: [u32; 2],
    pub lo: [f32; 4],
    pub hi: [f32; 4],
    pub axis: [f32; 4],
    pub pad_b: [f32; 4],
}

impl GpuLightTreeNode {
    pub fn bounds(&self) -> LightBounds {
        LightBounds {
            lo: Vec3::from_slice(&self.lo[..3]),
            hi: Vec3::from_slice(&self.hi[..3]),
            phi: self.phi,
            axis: Vec3::from_slice(&self.axis[..3]),
            cos_theta_o: self.cos_theta_o,
            cos_theta_e: self.cos_theta_e,
            two_sided: self.two_sided != 0.0,
        }
    }
}

/// The flattened tree (depth first: a node's first child follows it) and each light's bit
/// trail (bit k: the second child at depth k), as uploaded.
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    pub nodes: Vec<GpuLightTreeNode>,
    /// Per local light: its bit trail, low word then high word.
    pub trails: Vec<[u32; 2]>,
    /// Deepest leaf.
    pub depth: u32,
}

impl LightTree {
    /// Builds the tree over these lights (index i: the pool's light i; lights of zero power
    /// are left out and get no trail). Top-down, splitting where pbrt-v4's surface area
    /// orientation heuristic is least over 12 buckets per axis.
    pub fn build(lights: &[LightBounds]) -> LightTree {
        let mut ids: Vec<u32> = (0..lights.len() as u32)
            .filter(|&i| lights[i as usize].phi > 0.0)
            .collect();
        let mut tree = LightTree {
            nodes: Vec::with_capacity(2 * ids.len()),
            trails: vec![[0, 0]; lights.len()],
            depth: 0,
        };
        if !ids.is_empty() {
            tree.build_node(lights, &mut ids, 0, 0);
        }
        tree
    }

    fn build_node(&mut self, lights: &[LightBounds], ids: &mut [u32], depth: u32, trail: u64) {
        self.depth = self.depth.max(depth);
        let bounds = ids
            .iter()
            .map(|&i| lights[i as usize])
            .reduce(|a, b| a.union(&b))
            .expect("a node holds at least one light");
        if ids.len() == 1 {
            self.trails[ids[0] as usize] = [trail as u32, (trail >> 32) as u32];
            self.nodes.push(node_record(&bounds, true, ids[0]));
            return;
        }
        let mid = split(lights, ids, &bounds, depth);
        let at = self.nodes.len();
        self.nodes.push(node_record(&bounds, false, 0));
        let (first, second) = ids.split_at_mut(mid);
        self.build_node(lights, first, depth + 1, trail);
        self.nodes[at].index = self.nodes.len() as u32;
        self.build_node(lights, second, depth + 1, trail | (1u64 << depth));
    }

    /// The probability of choosing the first child of interior node `at` at `p` (normal `n`),
    /// or None when neither child can light it.
    fn first_child_probability(&self, at: usize, p: Vec3, n: Vec3) -> Option<f32> {
        let i0 = self.nodes[at + 1].bounds().importance(p, n);
        let i1 = self.nodes[self.nodes[at].index as usize]
            .bounds()
            .importance(p, n);
        if i0 <= 0.0 && i1 <= 0.0 {
            return None;
        }
        Some(i0 / (i0 + i1))
    }

    /// One light for point `p` (normal `n`, or zero) from random number `u` in [0, 1): its
    /// index and probability, None when no light can reach `p`. The GPU's `tree_sample`.
    pub fn sample(&self, p: Vec3, n: Vec3, u: f32) -> Option<(u32, f32)> {
        self.sample_from(0, p, n, u)
    }

    /// One light under node `start`: its index and probability among that node's lights (a
    /// lightcut descends from each of its nodes). The GPU's `tree_descend`.
    pub fn sample_from(&self, start: usize, p: Vec3, n: Vec3, mut u: f32) -> Option<(u32, f32)> {
        let mut at = start;
        let mut pmf = 1.0f32;
        loop {
            let node = self.nodes.get(at)?;
            if node.leaf == 1 {
                if at != start || node.bounds().importance(p, n) > 0.0 {
                    return Some((node.index, pmf));
                }
                return None;
            }
            let p0 = self.first_child_probability(at, p, n)?;
            if u < p0 {
                u = (u / p0).min(ONE_MINUS_EPSILON);
                pmf *= p0;
                at += 1;
            } else {
                u = ((u - p0) / (1.0 - p0)).min(ONE_MINUS_EPSILON);
                pmf *= 1.0 - p0;
                at = node.index as usize;
            }
        }
    }

    /// A stochastic lightcut's cut at `p` (normal `n`, or zero): at most `size` nodes that
    /// together hold every light that can reach `p`, each with its error bound there
    /// ([`LightBounds::lightcut_error`]). Grown from the root by splitting the interior node of
    /// largest bound (Yuksel, "Stochastic Lightcuts", HPG 2019; GIBS's "lightcut 4", seed 001);
    /// a child that cannot reach `p` leaves the cut. The GPU's `lightcut_direct`
    /// (shaders/parts/cache_light.wgsl) grows it the same way.
    pub fn lightcut(&self, p: Vec3, n: Vec3, size: usize) -> Vec<(usize, f32)> {
        let mut cut = Vec::with_capacity(size);
        let Some(root) = self.nodes.first() else {
            return cut;
        };
        let w = root.bounds().lightcut_error(p, n);
        if w > 0.0 {
            cut.push((0usize, w));
        }
        for _ in 0..LIGHTCUT_STEPS {
            if cut.len() >= size {
                break;
            }
            // First of the largest, as the GPU's strict comparison picks it.
            let mut best: Option<usize> = None;
            for (k, &(at, w)) in cut.iter().enumerate() {
                if self.nodes[at].leaf == 0 && best.is_none_or(|b| w > cut[b].1) {
                    best = Some(k);
                }
            }
            let Some(k) = best else {
                break;
            };
            let at = cut[k].0;
            let children = [at + 1, self.nodes[at].index as usize];
            let reaching: Vec<(usize, f32)> = children
                .iter()
                .map(|&c| (c, self.nodes[c].bounds().lightcut_error(p, n)))
                .filter(|&(_, w)| w > 0.0)
                .collect();
            match reaching.as_slice() {
                [] => {
                    cut.swap_remove(k);
                }
                [one] => cut[k] = *one,
                [a, b] => {
                    cut[k] = *a;
                    cut.push(*b);
                }
                _ => unreachable!(),
            }
        }
        cut
    }

    /// The probability that [`LightTree::sample`] picks local light `light` at `p` (normal
    /// `n`): the product of the choices along its bit trail. The GPU's `tree_pmf`.
    pub fn pmf(&self, light: u32, p: Vec3, n: Vec3) -> f32 {
        let Some(trail) = self.trails.get(light as usize) else {
            return 0.0;
        };
        let mut trail = trail[0] as u64 | ((trail[1] as u64) << 32);
        let mut at = 0usize;
        let mut pmf = 1.0f32;
        loop {
            let Some(node) = self.nodes.get(at) else {
                return 0.0;
            };
            if node.leaf == 1 {
                if node.index != light {
                    return 0.0;
                }
                if at == 0 && node.bounds().importance(p, n) <= 0.0 {
                    return 0.0;
                }
                return pmf;
            }
            let Some(p0) = self.first_child_probability(at, p, n) else {
                return 0.0;
            };
            if trail & 1 == 0 {
                pmf *= p0;
                at += 1;
            } else {
                pmf *= 1.0 - p0;
                at = node.index as usize;
            }
            trail >>= 1;
        }
    }
}

fn node_record(b: &LightBounds, leaf: bool, index: u32) -> GpuLightTreeNode {
    GpuLightTreeNode {
        leaf: leaf as u32,
        index,
        phi: b.phi,
        cos_theta_o: b.cos_theta_o,
        cos_theta_e: b.cos_theta_e,
        two_sided: if b.two_sided { 1.0 } else { 0.0 },
        pad: [0; 2],
        lo: b.lo.extend(0.0).to_array(),
        hi: b.hi.extend(0.0).to_array(),
        axis: b.axis.extend(0.0).to_array(),
        pad_b: [0.0; 4],
    }
}

/// Reorders `ids` into two non-empty halves and returns where the second starts: at the
/// least-cost bucket boundary, or at the median of the widest centroid axis below
/// `MEDIAN_DEPTH` or where no boundary separates the lights.
fn split(lights: &[LightBounds], ids: &mut [u32], bounds: &LightBounds, depth: u32) -> usize {
    let (clo, chi) = ids.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &i| {
            let c = lights[i as usize].centroid();
            (lo.min(c), hi.max(c))
        },
    );
    let extent = bounds.hi - bounds.lo;
    let widest = (chi - clo).max_position();
    let median = |ids: &mut [u32], dim: usize| {
        let mid = ids.len() / 2;
        ids.select_nth_unstable_by(mid, |&a, &b| {
            lights[a as usize].centroid()[dim].total_cmp(&lights[b as usize].centroid()[dim])
        });
        mid
    };
    if depth >= MEDIAN_DEPTH {
        return median(ids, widest);
    }
    let bucket_of = |c: Vec3, dim: usize| -> usize {
        let t = (c[dim] - clo[dim]) / (chi[dim] - clo[dim]);
        ((t * BUCKETS as f32) as usize).min(BUCKETS - 1)
    };
    let mut best: Option<(f32, usize, usize)> = None;
    for dim in 0..3 {
        if chi[dim] <= clo[dim] {
            continue;
        }
        let mut buckets: [Option<LightBounds>; BUCKETS] = [None; BUCKETS];
        for &i in ids.iter() {
            let l = &lights[i as usize];
            let b = &mut buckets[bucket_of(l.centroid(), dim)];
            *b = Some(b.map_or(*l, |x| x.union(l)));
        }
        for boundary in 1..BUCKETS {
            let side = |range: std::ops::Range<usize>| {
                buckets[range]
                    .iter()
                    .flatten()
                    .copied()
                    .reduce(|a, b| a.union(&b))
            };
            let (Some(a), Some(b)) = (side(0..boundary), side(boundary..BUCKETS)) else {
                continue;
            };
            let cost = a.cost(extent, dim) + b.cost(extent, dim);
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, dim, boundary));
            }
        }
    }
    let Some((_, dim, boundary)) = best else {
        return median(ids, widest);
    };
    let mut mid = 0;
    for k in 0..ids.len() {
        if bucket_of(lights[ids[k] as usize].centroid(), dim) < boundary {
            ids.swap(k, mid);
            mid += 1;
        }
    }
    if mid == 0 || mid == ids.len() {
        return median(ids, widest);
    }
    mid
}
