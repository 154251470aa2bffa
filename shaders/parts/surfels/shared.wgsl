// Surfel GI (GIBS, shared/seeds/001): the surfel pool, its non-linear grid, the radial maps
// (guiding, Gaussian depth), the multiscale mean estimator and the gather that every surfel pass
// shares. Bind group 2; layout must match src/techniques/surfels/resources.rs.
#define_import_path gilab::surfels

#import gilab::math::{PI, INV_PI, luminance, to_local, to_world, max_component}
#import gilab::frame::frame
#import gilab::primary::camera_sees

struct SurfelParams {
    max_surfels: u32,
    // Surfel rays per frame (the global ray budget) and the most the ray buffers hold.
    ray_budget: u32,
    ray_capacity: u32,
    flags: u32,
    // Spawning stops where a tile's least-covered pixel has at least this much surfel weight.
    coverage_target: f32,
    // Surfel radius as a fraction of the image height (constant screen size at any distance).
    surfel_size: f32,
    // Half the side of the uniform centre grid (world units); its cells are 2 * this / GRID_N.
    grid_half_extent: f32,
    tiles_x: u32,
    tiles: u32,
    cells: u32,
    max_rays_per_surfel: u32,
    // Side of a spawn tile in pixels (1, 2, 4, 8 or 16): `spawn_tiles`.
    spawn_tile: u32,
}

const FLAG_GUIDING: u32 = 1u;
const FLAG_RADIAL_DEPTH: u32 = 2u;
const FLAG_MSME: u32 = 4u;
const FLAG_SKY: u32 = 8u;
const FLAG_ACCUMULATE: u32 = 16u;
const FLAG_REFLECTIONS: u32 = 32u;
const FLAG_CACHE_ONLY: u32 = 64u;
const FLAG_SHARING: u32 = 128u;
const FLAG_QUARTER_APPLY: u32 = 256u;
// The trace pass runs its rays in bin order (`ray_binning`).
const FLAG_BINNING: u32 = 512u;
// With FLAG_RADIAL_DEPTH: a point past its depth texel's mean is hidden (`depth_test = "hard"`).
const FLAG_HARD_DEPTH: u32 = 1024u;

// One surfel's geometry. radius 0 marks a free slot.
struct Surfel {
    pos_radius: vec4<f32>,
    // xyz: normal (the geometric normal of the surface it sits on, facing the camera at spawn);
    // w: bitcast id of the object it sits on: its triangle in BVH order + 1 (0: none), whose
    // instance's motion record moves the surfel with it (GIBS's transform ids).
    normal_id: vec4<f32>,
    // rgb: diffuse albedo; w: bitcast frame it spawned in.
    albedo_spawn: vec4<f32>,
}

// One surfel's irradiance integrator (multiscale mean estimator, or a plain running mean).
struct SurfelState {
    // rgb: irradiance (long-term mean); w: rays integrated (the running mean's count).
    mean: vec4<f32>,
    // rgb: short-term mean; w: variance-based blend reduction (MSME's vbbr).
    short_mean: vec4<f32>,
    // rgb: short-term variance of a frame's estimate; w: inconsistency.
    variance: vec4<f32>,
    // x: rays traced this frame; y: guiding samples so far; z: frames with rays; w: unused.
    info: vec4<u32>,
}

// The stack counter and per-frame totals. Pops and pushes take their positions from prefix sums
// over slots and tiles (scan.wgsl) instead of one atomic per thread, so which slot a surfel gets
// does not depend on thread scheduling: a fixed seed gives the same image. One thread per pass
// moves the counters, atomically.
struct Pool {
    free_count: atomic<u32>,
    live_count: atomic<u32>,
    // Sum of this frame's ray requests, in units of 1/REQUEST_SCALE ray.
    request_total: atomic<u32>,
    spawned: u32,
    recycled: u32,
    pad_a: u32,
    pad_b: u32,
    pad_c: u32,
    // The camera cell the grid was last built around (xyz), w = 1 once built.
    grid_center: vec4<f32>,
}

const REQUEST_SCALE: f32 = 64.0;
const NONE: u32 = 0xffffffffu;

@group(#{SURFELS_GROUP}) @binding(0) var<uniform> params: SurfelParams;
@group(#{SURFELS_GROUP}) @binding(1) var<storage, read_write> surfels: array<Surfel>;
@group(#{SURFELS_GROUP}) @binding(2) var<storage, read_write> states: array<SurfelState>;
@group(#{SURFELS_GROUP}) @binding(3) var<storage, read_write> pool: Pool;
@group(#{SURFELS_GROUP}) @binding(4) var<storage, read_write> free_stack: array<u32>;
// Per slot: last frame the surfel lit a visible pixel, pixels it lit last frame, of which crowded.
@group(#{SURFELS_GROUP}) @binding(5) var<storage, read_write> seen: array<atomic<u32>>;
// Per slot GUIDE_WORDS words: the 6x6 guiding map, 8 bits per texel, normalised to max 1.
@group(#{SURFELS_GROUP}) @binding(6) var<storage, read_write> guide: array<u32>;
// Per slot DEPTH_TEXELS texels: mean and mean square hit distance (radial Gaussian depth).
@group(#{SURFELS_GROUP}) @binding(7) var<storage, read_write> depth: array<vec2<f32>>;
// Prefix-sum buffers (exclusive scan in place, total after the last element; scan.wgsl).
@group(#{SURFELS_GROUP}) @binding(8) var<storage, read_write> slot_scan: array<u32>;
@group(#{SURFELS_GROUP}) @binding(9) var<storage, read_write> tile_scan: array<u32>;
@group(#{SURFELS_GROUP}) @binding(10) var<storage, read_write> cell_offsets: array<atomic<u32>>;
@group(#{SURFELS_GROUP}) @binding(11) var<storage, read_write> ray_offsets: array<u32>;
// Per tile: the pixel a surfel spawns at (NONE: no spawn).
@group(#{SURFELS_GROUP}) @binding(12) var<storage, read_write> tile_pixel: array<u32>;
// Counters, cleared every frame before the grid is built: first ray binning's (`ray_binning`;
// bin.wgsl, bin_order.wgsl): RAY_BINS bin counts, then their exclusive prefix sum in place with
// the total after them, and RAY_BINS cursors; then per cell its insertion cursor
// (CELL_CURSORS + cell); then per ray its bin (ray_bin_keys() + ray) and the rays in bin order
// (ray_bin_order() + place). One buffer, as a stage may bind only 32 storage buffers.
@group(#{SURFELS_GROUP}) @binding(13) var<storage, read_write> counters: array<atomic<u32>>;
const RAY_BINS: u32 = 65536u;
const CELL_CURSORS: u32 = 131073u;
// The cells' surfel lists (slots, sorted within a cell).
@group(#{SURFELS_GROUP}) @binding(14) var<storage, read_write> cell_surfels: array<u32>;
// Per ray: the surfel that owns it; its result (two vec4 per ray).
@group(#{SURFELS_GROUP}) @binding(15) var<storage, read_write> ray_owner: array<u32>;
@group(#{SURFELS_GROUP}) @binding(16) var<storage, read_write> ray_results: array<vec4<f32>>;
// Per pixel: direct light (NEE or ReSTIR DI), written before the apply pass.
@group(#{SURFELS_GROUP}) @binding(17) var<storage, read_write> pixel_direct: array<vec4<f32>>;
// Per pixel, two planes of vec4 (technique debug views).
@group(#{SURFELS_GROUP}) @binding(18) var<storage, read_write> debug_out: array<vec4<f32>>;
// Per pixel, from the reflections part (src/parts/reflections.rs): (specular radiance, 0), then
// a second plane (directional albedo of a lobe too rough to trace, hit kind).
@group(#{SURFELS_GROUP}) @binding(19) var<storage, read_write> pixel_specular: array<vec4<f32>>;
// Per slot: this frame's irradiance estimate (mean of its rays) and its ray count (0: no rays),
// which integrate's irradiance sharing reads for the neighbours (estimate.wgsl).
@group(#{SURFELS_GROUP}) @binding(20) var<storage, read_write> frame_estimates: array<vec4<f32>>;
// Where the rays in bin order start in `counters`.
fn ray_bin_order() -> u32 {
    return ray_bin_keys() + params.ray_capacity;
}

// Where the rays' bins start in `counters` (after the cells' cursors).
fn ray_bin_keys() -> u32 {
    return CELL_CURSORS + params.cells;
}

fn has_flag(f: u32) -> bool {
    return (params.flags & f) != 0u;
}

fn is_live(slot: u32) -> bool {
    return surfels[slot].pos_radius.w > 0.0;
}

fn surfel_id(s: Surfel) -> u32 {
    return bitcast<u32>(s.normal_id.w);
}

fn spawn_frame(s: Surfel) -> u32 {
    return bitcast<u32>(s.albedo_spawn.w);
}

// ---------------------------------------------------------------------------------------------
// The non-linear grid (the seed's acceleration structure): a uniform GRID_N^3 grid around the
// camera cell, and outside it six trapezoidal grids, one per principal axis direction, whose
// slices thicken with distance so that cells stay about as wide as they are deep and grow in
// proportion to distance, as surfels do.
const GRID_N: u32 = 32u;
const GRID_SLICES: u32 = 64u;
const CENTER_CELLS: u32 = 32768u;
const REGION_CELLS: u32 = 65536u;
// Slice d_k = h * SLICE_GROWTH^k: each slice as thick as a cell is wide at its distance.
const SLICE_GROWTH: f32 = 1.0625;

fn center_cell_size() -> f32 {
    return 2.0 * params.grid_half_extent / f32(GRID_N);
}

// The grid centre for a camera position: snapped to whole cells, so a moving camera shifts the
// grid by cells.
fn grid_center_for(camera: vec3<f32>) -> vec3<f32> {
    let c = center_cell_size();
    return (floor(camera / c) + 0.5) * c;
}

// Cell index of a world point for a grid built around `center`.
fn cell_of(p: vec3<f32>, center: vec3<f32>) -> u32 {
    let h = params.grid_half_extent;
    let d = p - center;
    let a = abs(d);
    if max_component(a) < h {
        let i = clamp(vec3<i32>(floor((d + h) / center_cell_size())), vec3<i32>(0), vec3<i32>(i32(GRID_N) - 1));
        return (u32(i.z) * GRID_N + u32(i.y)) * GRID_N + u32(i.x);
    }
    // Dominant axis and its sign pick the trapezoid; the other two axes, divided by the
    // distance along it, are its cross-section coordinates in [-1, 1].
    var axis = 0u;
    var along = d.x;
    var uv = d.yz;
    if a.y >= a.x && a.y >= a.z {
        axis = 1u;
        along = d.y;
        uv = d.xz;
    } else if a.z >= a.x && a.z >= a.y {
        axis = 2u;
        along = d.z;
        uv = d.xy;
    }
    let dist = abs(along);
    let region = axis * 2u + select(0u, 1u, along < 0.0);
    let slice = min(u32(max(log(dist / h) / log(SLICE_GROWTH), 0.0)), GRID_SLICES - 1u);
    let iuv = clamp(vec2<i32>(floor((uv / dist + 1.0) * 0.5 * f32(GRID_N))), vec2<i32>(0), vec2<i32>(i32(GRID_N) - 1));
    return CENTER_CELLS + region * REGION_CELLS + (slice * GRID_N + u32(iuv.y)) * GRID_N + u32(iuv.x);
}

// Side of the cell around p (centre grid: fixed; trapezoids: grows with distance).
fn cell_side_at(p: vec3<f32>, center: vec3<f32>) -> f32 {
    let dist = max_component(abs(p - center));
    return max(center_cell_size(), 2.0 * dist / f32(GRID_N));
}

// Surfel radius at p: a constant fraction of the image height, never more than half the side
// of the cell it sits in, so its bounding box touches at most two cells per axis (8 in all).
fn surfel_radius(p: vec3<f32>) -> f32 {
    let tan_half_fov = length(frame.camera_up.xyz);
    let dist = max(length(p - frame.camera_pos.xyz), 1e-4);
    let r = params.surfel_size * 2.0 * tan_half_fov * dist;
    return min(r, 0.5 * cell_side_at(p, grid_center_for(frame.camera_pos.xyz)));
}

// The distinct cells the surfel's bounding box overlaps (corner cells; unused entries NONE).
fn overlapped_cells(p: vec3<f32>, r: f32, center: vec3<f32>) -> array<u32, 8> {
    var cells = array<u32, 8>(NONE, NONE, NONE, NONE, NONE, NONE, NONE, NONE);
    for (var k = 0u; k < 8u; k++) {
        let corner = p + r * vec3<f32>(select(-1.0, 1.0, (k & 1u) != 0u), select(-1.0, 1.0, (k & 2u) != 0u), select(-1.0, 1.0, (k & 4u) != 0u));
        let c = cell_of(corner, center);
        var dup = false;
        for (var j = 0u; j < k; j++) {
            dup = dup || cells[j] == c;
        }
        if !dup {
            cells[k] = c;
        }
    }
    return cells;
}

// ---------------------------------------------------------------------------------------------
// Radial maps over the surfel's hemisphere: hemi-octahedral mapping (Cigolle et al. 2014).
const GUIDE_RES: u32 = 6u;
const GUIDE_TEXELS: u32 = 36u;
const GUIDE_WORDS: u32 = 9u;
const DEPTH_RES: u32 = 4u;
const DEPTH_TEXELS: u32 = 16u;
// Guiding starts once a surfel has this many samples in its map.
const GUIDE_POPULATED: u32 = 64u;
// Probability of a guided direction once populated (the rest cosine-sampled).
const GUIDE_MIX: f32 = 0.5;

// Local direction (z >= 0) to [-1, 1]^2.
fn hemi_oct_encode(v: vec3<f32>) -> vec2<f32> {
    let p = v.xy / (abs(v.x) + abs(v.y) + max(v.z, 0.0));
    return vec2<f32>(p.x + p.y, p.x - p.y);
}

fn hemi_oct_decode(e: vec2<f32>) -> vec3<f32> {
    let p = vec2<f32>(e.x + e.y, e.x - e.y) * 0.5;
    return normalize(vec3<f32>(p, 1.0 - abs(p.x) - abs(p.y)));
}

// Solid-angle density per unit area of [-1, 1]^2 at e: dA = 2 |q|^3 dw, q on the octahedron.
fn hemi_oct_jacobian(e: vec2<f32>) -> f32 {
    let p = vec2<f32>(e.x + e.y, e.x - e.y) * 0.5;
    let q = vec3<f32>(p, 1.0 - abs(p.x) - abs(p.y));
    let l = length(q);
    return 2.0 * l * l * l;
}

fn texel_of(e: vec2<f32>, res: u32) -> u32 {
    let t = clamp(vec2<u32>((e * 0.5 + 0.5) * f32(res)), vec2<u32>(0u), vec2<u32>(res - 1u));
    return t.y * res + t.x;
}

// Texel of a world direction in the surfel's hemisphere (directions below it clamp to the horizon).
fn radial_texel(n: vec3<f32>, dir: vec3<f32>, res: u32) -> u32 {
    var v = to_local(dir, n);
    v.z = max(v.z, 0.0);
    return texel_of(hemi_oct_encode(v), res);
}

fn guide_value(slot: u32, texel: u32) -> f32 {
    let word = guide[slot * GUIDE_WORDS + texel / 4u];
    return unpack4x8unorm(word)[texel % 4u];
}

// ---------------------------------------------------------------------------------------------
// The gather: the surfels of p's cell, weighted by Mahalanobis distance within their radius,
// normal agreement and (radial_depth) the Chebyshev test against their depth maps.
const MAX_GATHER: u32 = 64u;
// Off-plane distance counts this many times more than in-plane distance (Mahalanobis).
const PLANE_STRETCH: f32 = 4.0;

struct Gather {
    // Weighted irradiance of surfels with samples, and their summed weight.
    irradiance: vec3<f32>,
    weight: f32,
    // The same weight without the depth test: occluded surfels still count as "covered, dark".
    geo_weight: f32,
    // Weight of every live surfel, sampled or not (spawning's coverage).
    coverage: f32,
    // Cell average over surfels facing the same way and visible from p (gap filler).
    cell_irradiance: vec3<f32>,
    cell_weight: f32,
    // The surfel with the largest weight (NONE if none), for the debug views.
    best: u32,
    cell: u32,
}

// How visible a point at distance t in direction dir is from the surfel (1 when no closer depth
// was seen): past the texel's mean hit distance, hidden (`depth_test = "hard"`, the default) or
// the Chebyshev upper bound of the probability that nothing lies closer (the seed's, as DDGI).
// The bound leaks where a texel mixes a near wall with open directions: a point just behind the
// wall sits within a standard deviation of the mean, so it passes (docs/surfels.md, thin walls).
fn depth_visibility(slot: u32, n: vec3<f32>, dir: vec3<f32>, t: f32) -> f32 {
    let m = depth[slot * DEPTH_TEXELS + radial_texel(n, dir, DEPTH_RES)];
    if t <= m.x {
        return 1.0;
    }
    if has_flag(FLAG_HARD_DEPTH) {
        return 0.0;
    }
    let variance = max(m.y - m.x * m.x, 1e-6 * m.x * m.x + 1e-12);
    let d = t - m.x;
    // Cubed, as DDGI does, to sharpen the test: a 4x4 map is coarse near the horizon.
    let p = variance / (variance + d * d);
    return p * p * p;
}

// Squared distance of offset v from a surfel's centre in units of `radius`, its off-plane part
// stretched by PLANE_STRETCH (the footprint is an ellipsoid flattened along the normal n): under
// 1 inside. The gather's weights and the estimate sharing's use it.
fn footprint_d2(v: vec3<f32>, n: vec3<f32>, radius: f32) -> f32 {
    let off_plane = dot(v, n);
    let in_plane = v - off_plane * n;
    return (dot(in_plane, in_plane) + PLANE_STRETCH * PLANE_STRETCH * off_plane * off_plane) / (radius * radius);
}

// mark_seen: the surfels that weigh in have lit a visible pixel this frame (recycling).
// With `mark_seen`: how far past its radius a surfel counts as seen (quarter-area apply: the
// block's other pixels, which do not gather); 0 elsewhere.
var<private> mark_reach: f32 = 0.0;

fn gather(p: vec3<f32>, n: vec3<f32>, center: vec3<f32>, mark_seen: bool) -> Gather {
    var g = Gather(vec3<f32>(0.0), 0.0, 0.0, 0.0, vec3<f32>(0.0), 0.0, NONE, 0u);
    let cell = cell_of(p, center);
    g.cell = cell;
    let first = atomicLoad(&cell_offsets[cell]);
    let end = min(atomicLoad(&cell_offsets[cell + 1u]), first + MAX_GATHER);
    var best_w = 0.0;
    for (var i = first; i < end; i++) {
        let slot = cell_surfels[i];
        let s = surfels[slot];
        let r = s.pos_radius.w;
        if r <= 0.0 {
            continue;
        }
        let sn = s.normal_id.xyz;
        let n_w = dot(n, sn);
        if n_w <= 0.0 {
            continue;
        }
        let v = p - s.pos_radius.xyz;
        let t = length(v);
        var vis = 1.0;
        if has_flag(FLAG_RADIAL_DEPTH) && t > 1e-6 {
            vis = depth_visibility(slot, sn, v / t, t);
        }
        let st = states[slot];
        let sampled = st.mean.w > 0.0;
        // The cell average (gap filling): with radial depth, only surfels whose depth map
        // reaches p (within their diameter) may vouch for it; beyond, light would leak through
        // any wall their maps never saw.
        if sampled && (!has_flag(FLAG_RADIAL_DEPTH) || t < 2.0 * r) {
            g.cell_irradiance += st.mean.xyz * n_w * vis;
            g.cell_weight += n_w * vis;
        }
        if mark_seen && mark_reach > 0.0 && t < r + mark_reach {
            atomicMax(&seen[3u * slot], frame.frame_index);
        }
        let d2 = footprint_d2(v, sn, r);
        if d2 >= 1.0 {
            continue;
        }
        let w = (1.0 - d2) * n_w * vis;
        g.coverage += w;
        if mark_seen && w > 0.0 {
            atomicMax(&seen[3u * slot], frame.frame_index);
        }
        if sampled {
            g.irradiance += st.mean.xyz * w;
            g.weight += w;
            g.geo_weight += (1.0 - d2) * n_w;
        }
        if w > best_w {
            best_w = w;
            g.best = slot;
        }
    }
    return g;
}

// A ray's hit counts as covered by the surfels with this much surfel (or cell-average) weight:
// the surfels' own rays (trace.wgsl) and GI paths ending in them (common/path.wgsl) take the
// cache's irradiance there, and are traced on where it does not hold.
const COVERED_WEIGHT: f32 = 0.25;

fn gather_covers(g: Gather) -> bool {
    return g.weight >= COVERED_WEIGHT || g.cell_weight >= COVERED_WEIGHT;
}

// A lookup's outcome for the coverage counters (gilab::counters::count_cache_lookup): covered by
// surfel footprints, by the cell average only, or not, + 3 where the camera does not see p.
fn gather_outcome(g: Gather, p: vec3<f32>) -> u32 {
    let o = coverage_class(g);
    return select(o + 3u, o, camera_sees(p));
}

// 1: surfel footprints cover the gather (weight >= COVERED_WEIGHT), 2: the cell average only,
// 3: neither (a ray hit there goes on as a path).
fn coverage_class(g: Gather) -> u32 {
    if g.weight >= COVERED_WEIGHT {
        return 1u;
    }
    if g.cell_weight >= COVERED_WEIGHT {
        return 2u;
    }
    return 3u;
}

// Irradiance at p from a gather: the surfels' weighted mean where they cover p (weight >= 1),
// topped up with the cell average where they do not (the seed's gap filling). Surfels the depth
// test rejects still hold the normalisation up (to at most 1): light from behind a wall is
// scaled by its visibility instead of being renormalised to full strength.
fn gathered_irradiance(g: Gather) -> vec3<f32> {
    var e = g.irradiance;
    var w = max(g.weight, min(g.geo_weight, 1.0));
    if w < 1.0 && g.cell_weight > 0.0 {
        e += (1.0 - w) * g.cell_irradiance / g.cell_weight;
        w = 1.0;
    }
    if w <= 0.0 {
        return vec3<f32>(0.0);
    }
    return e / w;
}

// Debug planes: plane 0 = (surfel id, coverage, rays of the surfel, MSME variance), plane 1 =
// (grid cell, surfel age, coverage class of a ray hit at the pixel's surface, 0).
// Coverage above this multiple of the target counts a pixel as crowded (recycling thins it).
const CROWDED: f32 = 4.0;

// A pixel gather's two debug planes.
struct GatherDebug {
    first: vec4<f32>,
    second: vec4<f32>,
}

// What apply records of a gather: the debug planes (best surfel id, coverage, rays, relative
// variance; cell, age), and its best surfel counted as lighting `pixels` pixels, crowded or not
// (recycling's over-coverage test).
fn note_gather(g: Gather, pixels: u32) -> GatherDebug {
    var d = GatherDebug(vec4<f32>(0.0, g.coverage, 0.0, 0.0), vec4<f32>(f32(g.cell + 1u), 0.0, f32(coverage_class(g)), 0.0));
    if g.best != NONE {
        let st = states[g.best];
        let mean = max(luminance(st.mean.xyz), 1e-6);
        d.first.x = f32(g.best + 1u);
        d.first.z = f32(st.info.x);
        d.first.w = luminance(st.variance.xyz) / (mean * mean);
        d.second.y = f32(frame.frame_index - spawn_frame(surfels[g.best])) + 1.0;
        atomicAdd(&seen[3u * g.best + 1u], pixels);
        if g.coverage > CROWDED * params.coverage_target {
            atomicAdd(&seen[3u * g.best + 2u], pixels);
        }
    }
    return d;
}

// Quarter-area apply: the pixel a 2x2 block gathers at (its top-left), by block index.
fn block_sample_pixel(block: u32) -> u32 {
    let bx = (frame.size.x + 1u) / 2u;
    return (2u * (block / bx)) * frame.size.x + 2u * (block % bx);
}

fn write_debug(pixel: u32, first_plane: vec4<f32>, second_plane: vec4<f32>) {
    let px = frame.size.x * frame.size.y;
    debug_out[pixel] = first_plane;
    debug_out[px + pixel] = second_plane;
}
