// The light tree (src/parts/light_tree.rs): a BVH over the light pool's local lights whose nodes
// bound position, emitted directions and power. One stochastic descent picks a light for a
// shading point by each node's importance there; a light's probability is the product of the
// choices on its bit trail (Light.trail), for MIS. Mirrors LightTree::sample and LightTree::pmf
// line by line (pbrt-v4's BVHLightSampler).
#define_import_path gilab::light_tree

#import gilab::scene::{light_pool, light_at}

// The largest f32 below 1: a remapped random number stays in [0, 1).
const TREE_ONE_MINUS_EPSILON: f32 = 0.99999994;
// Deepest possible leaf: bit trails are 64 bits.
const TREE_MAX_DEPTH: u32 = 64u;

struct LightTreeNode {
    leaf: bool,
    // Interior: the second child (the first is the next record). Leaf: its light.
    index: u32,
    phi: f32,
    cos_theta_o: f32,
    cos_theta_e: f32,
    two_sided: bool,
    lo: vec3<f32>,
    hi: vec3<f32>,
    axis: vec3<f32>,
}

// Node `i` of the tree: record count + i of the light pool, in a light's fields
// (GpuLightTreeNode: kind = leaf, tri = index, cdf = phi, pmf = cos_theta_o, class_cdf =
// cos_theta_e, class_pmf = two_sided (1 or 0), position = lo, intensity = hi, direction = axis;
// tests/cpu.rs checks the layout).
fn tree_node(i: u32) -> LightTreeNode {
    let r = light_at(light_pool.count + i);
    return LightTreeNode(r.kind == 1u, r.tri, r.cdf, r.pmf, r.class_cdf, r.class_pmf != 0.0, r.position.xyz, r.intensity.xyz, r.direction.xyz);
}

fn tree_safe_sqrt(x: f32) -> f32 {
    return sqrt(max(x, 0.0));
}

// cos(max(0, a - b)) from the sines and cosines of a and b.
fn cos_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        return 1.0;
    }
    return cos_a * cos_b + sin_a * sin_b;
}

// sin(max(0, a - b)) from the sines and cosines of a and b.
fn sin_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b {
        return 0.0;
    }
    return sin_a * cos_b - cos_a * sin_b;
}

// Cosine of the half-angle of the cone from p that holds the box's bounding sphere (-1: p
// inside it).
fn bound_subtended_cos(lo: vec3<f32>, hi: vec3<f32>, p: vec3<f32>) -> f32 {
    let c = 0.5 * (lo + hi);
    let r2 = dot(hi - c, hi - c);
    let d2 = dot(p - c, p - c);
    if d2 < r2 {
        return -1.0;
    }
    return tree_safe_sqrt(1.0 - r2 / max(d2, 1e-30));
}

// How much the node's lights may give point p with normal n (n = 0: no normal): zero only
// where none of them can reach the hemisphere around n (LightBounds::importance).
fn node_importance(b: LightTreeNode, p: vec3<f32>, n: vec3<f32>) -> f32 {
    let pc = 0.5 * (b.lo + b.hi);
    let d = p - pc;
    let d2 = max(max(dot(d, d), 0.5 * length(b.hi - b.lo)), 1e-12);
    let len = length(d);
    let wi = select(vec3<f32>(0.0), d / len, len > 0.0);
    var cos_w = dot(b.axis, wi);
    if b.two_sided {
        cos_w = abs(cos_w);
    }
    let sin_w = tree_safe_sqrt(1.0 - cos_w * cos_w);
    let cos_b = bound_subtended_cos(b.lo, b.hi, p);
    let sin_b = tree_safe_sqrt(1.0 - cos_b * cos_b);
    let sin_o = tree_safe_sqrt(1.0 - b.cos_theta_o * b.cos_theta_o);
    let cos_x = cos_sub_clamped(sin_w, cos_w, sin_o, b.cos_theta_o);
    let sin_x = sin_sub_clamped(sin_w, cos_w, sin_o, b.cos_theta_o);
    let cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
    if cos_p <= b.cos_theta_e {
        return 0.0;
    }
    var importance = b.phi * cos_p / d2;
    if any(n != vec3<f32>(0.0)) {
        let cos_i = -dot(wi, n);
        let sin_i = tree_safe_sqrt(1.0 - cos_i * cos_i);
        importance *= cos_sub_clamped(sin_i, cos_i, sin_b, cos_b);
    }
    return max(importance, 0.0);
}

// The most a lightcut's error bound grows over the importance near a node (LightTree's
// LIGHTCUT_NEAR_LIMIT).
const LIGHTCUT_NEAR_LIMIT: f32 = 1e6;

// A lightcut's error bound for node b at p: its importance with the squared distance to the
// box's nearest point in place of the centre's (LightBounds::lightcut_error).
fn lightcut_error(b: LightTreeNode, p: vec3<f32>, n: vec3<f32>) -> f32 {
    let d = p - 0.5 * (b.lo + b.hi);
    let d2 = max(max(dot(d, d), 0.5 * length(b.hi - b.lo)), 1e-12);
    let near = p - clamp(p, b.lo, b.hi);
    let near2 = max(dot(near, near), 1e-12);
    return node_importance(b, p, n) * min(d2 / near2, LIGHTCUT_NEAR_LIMIT);
}

// Node b with its box grown by `grow` on every side. The directions from any point within
// `grow` of p to b's box lie among those from p to the grown box, so importance at p with grown
// boxes (and no normal) is zero only for lights that light no point of that ball: a region's
// importance (a ReGIR cell's, `tree_sample_region`). grow = 0 leaves the box as it is.
fn grown(b: LightTreeNode, grow: f32) -> LightTreeNode {
    var out = b;
    out.lo = b.lo - vec3<f32>(grow);
    out.hi = b.hi + vec3<f32>(grow);
    return out;
}

// Probability of the first child of interior node `at` at p (boxes grown by `grow`); negative
// when neither child can light p.
fn first_child_probability(at: u32, node: LightTreeNode, p: vec3<f32>, n: vec3<f32>, grow: f32) -> f32 {
    let i0 = node_importance(grown(tree_node(at + 1u), grow), p, n);
    let i1 = node_importance(grown(tree_node(node.index), grow), p, n);
    if i0 <= 0.0 && i1 <= 0.0 {
        return -1.0;
    }
    return i0 / (i0 + i1);
}

struct TreeSample {
    light: u32,
    // 0: no light can reach the point.
    pmf: f32,
}

// One local light for p (normal n or 0) from u in [0, 1) by a descent from the root.
fn tree_sample(p: vec3<f32>, n: vec3<f32>, u_in: f32) -> TreeSample {
    return tree_descend(0u, p, n, u_in);
}

// One light under node `start` for p (normal n or 0) from u in [0, 1): its probability among
// that node's lights (LightTree::sample_from). A lightcut descends from each of its nodes.
fn tree_descend(start: u32, p: vec3<f32>, n: vec3<f32>, u_in: f32) -> TreeSample {
    return tree_descend_grown(start, p, n, 0.0, u_in);
}

// One local light for the ball of radius `radius` around p from u in [0, 1), by importance
// with every box grown by the radius and no normal: a light that can light some point of the
// ball has a non-zero probability (ReGIR's cell fill, `regir_fill = "tree"`).
fn tree_sample_region(p: vec3<f32>, radius: f32, u_in: f32) -> TreeSample {
    return tree_descend_grown(0u, p, vec3<f32>(0.0), radius, u_in);
}

fn tree_descend_grown(start: u32, p: vec3<f32>, n: vec3<f32>, grow: f32, u_in: f32) -> TreeSample {
    var out = TreeSample(0u, 0.0);
    if light_pool.local_count == 0u {
        return out;
    }
    var u = u_in;
    var at = start;
    var pmf = 1.0;
    for (var depth = 0u; depth <= TREE_MAX_DEPTH; depth++) {
        let node = tree_node(at);
        if node.leaf {
            if at != start || node_importance(grown(node, grow), p, n) > 0.0 {
                out = TreeSample(node.index, pmf);
            }
            break;
        }
        let p0 = first_child_probability(at, node, p, n, grow);
        if p0 < 0.0 {
            break;
        }
        if u < p0 {
            u = min(u / p0, TREE_ONE_MINUS_EPSILON);
            pmf *= p0;
            at += 1u;
        } else {
            u = min((u - p0) / (1.0 - p0), TREE_ONE_MINUS_EPSILON);
            pmf *= 1.0 - p0;
            at = node.index;
        }
    }
    return out;
}

// The probability that tree_sample picks local light `light` at p (normal n): the product of
// the choices along its bit trail.
fn tree_pmf(light: u32, p: vec3<f32>, n: vec3<f32>) -> f32 {
    return tree_pmf_grown(light, p, n, 0.0);
}

fn tree_pmf_grown(light: u32, p: vec3<f32>, n: vec3<f32>, grow: f32) -> f32 {
    if light >= light_pool.local_count {
        return 0.0;
    }
    let trail = light_at(light).trail;
    var at = 0u;
    var pmf = 1.0;
    for (var depth = 0u; depth <= TREE_MAX_DEPTH; depth++) {
        let node = tree_node(at);
        if node.leaf {
            if node.index != light || (at == 0u && node_importance(grown(node, grow), p, n) <= 0.0) {
                return 0.0;
            }
            return pmf;
        }
        let p0 = first_child_probability(at, node, p, n, grow);
        if p0 < 0.0 {
            return 0.0;
        }
        let bit = select(trail.y >> (depth - 32u), trail.x >> depth, depth < 32u) & 1u;
        if bit == 0u {
            pmf *= p0;
            at += 1u;
        } else {
            pmf *= 1.0 - p0;
            at = node.index;
        }
    }
    return 0.0;
}
