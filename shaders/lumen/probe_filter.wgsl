// The seed's spatial filter in probe space (one workgroup per probe, one thread per cell): a
// uniform probe's cells are averaged with its 3x3 neighbouring uniform probes' samples, each
// neighbour weighted by how close it lies to the probe's plane. Adaptive probes and
// `spatial_filter = false` copy.
//
// The seed drops a neighbour's sample when the point its ray hit, seen from this probe, lies more
// than 10 degrees off the cell's direction (the angle error that keeps contact shadows). That
// test drops near hits far more often than far ones (parallax grows as the hit comes closer) and
// keeps every miss, so the filter reads mostly the far half of what the neighbours saw: Cornell
// came out 2.8% dark from it alone (issue 38). Here each neighbour's sample is instead moved to
// the cell its hit point falls in as seen from this probe (misses and empty cells stay in their
// direction), which is what the angle test approximates: a sample that lands in this cell is
// kept, one that lands elsewhere counts there, and near occluders (contact shadows) stay where
// this probe sees them. Hit points behind this probe's plane are dropped.
#import gilab::equal_area::{cell_dir, octa_cell}
#import gilab::lumen_probes::{probe_data, load_probe, parity, probe_count, probes_flag, cache_index, filtered_index, tiles, tile_probe, plane_weight, PROBE_RES, PROBE_CELLS, PROBES_SPATIAL}

const NO_CELL: u32 = 0xffffffffu;
// Hit distances at or beyond this are misses (the traces store 1e30).
const MISS_DISTANCE: f32 = 1e20;

// A neighbour's samples: their radiance, and per cell of this probe the set of its cells whose
// samples land there (a 64-bit mask: read in ascending order, so the sum is deterministic, and
// each thread reads only what lands in its cell).
var<workgroup> radiance: array<vec3<f32>, PROBE_CELLS>;
var<workgroup> landed_low: array<atomic<u32>, PROBE_CELLS>;
var<workgroup> landed_high: array<atomic<u32>, PROBE_CELLS>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    // Barriers follow, so no thread leaves early: `live` guards the work instead.
    let probe = wid.x;
    let in_range = probe < probe_count();
    let q = load_probe(parity(), min(probe, max(probe_count(), 1u) - 1u));
    let live = in_range && q.valid;
    var own = vec4<f32>(0.0);
    if live {
        own = probe_data[cache_index(parity(), probe, j)];
    }
    atomicStore(&landed_low[j], 0u);
    atomicStore(&landed_high[j], 0u);
    workgroupBarrier();
    var sum = own.xyz;
    var weight = 1.0;
    let filtered = probes_flag(PROBES_SPATIAL) && probe < tiles().x * tiles().y;
    let t = vec2<i32>(vec2<u32>(probe % tiles().x, probe / tiles().x));
    let d = cell_dir(j, PROBE_RES, vec2<f32>(0.5));
    for (var k = 0u; k < 9u; k++) {
        let o = vec2<i32>(i32(k % 3u) - 1, i32(k / 3u) - 1);
        let nt = t + o;
        let inside = all(nt >= vec2<i32>(0)) && all(nt < vec2<i32>(tiles()));
        let nb = tile_probe(vec2<u32>(clamp(nt, vec2<i32>(0), vec2<i32>(tiles()) - 1)));
        let p = load_probe(parity(), nb);
        let used = live && filtered && k != 4u && inside && p.valid;
        var w = 0.0;
        var cell = NO_CELL;
        if used {
            w = plane_weight(q.pos, q.normal, q.dist, p.pos, p.normal);
            let c = probe_data[cache_index(parity(), nb, j)];
            cell = j;
            if c.w >= 0.0 && c.w < MISS_DISTANCE {
                let seen = p.pos + d * c.w - q.pos;
                cell = select(NO_CELL, octa_cell(normalize(seen), PROBE_RES), dot(seen, q.normal) > 0.0);
            }
            radiance[j] = c.xyz;
        }
        if cell != NO_CELL {
            if j < 32u {
                atomicOr(&landed_low[cell], 1u << j);
            } else {
                atomicOr(&landed_high[cell], 1u << (j - 32u));
            }
        }
        workgroupBarrier();
        // Take this cell's set (and clear it for the next neighbour: only this thread reads it).
        var low = atomicExchange(&landed_low[j], 0u);
        var high = atomicExchange(&landed_high[j], 0u);
        if used && w > 1e-6 && (low | high) != 0u {
            let n = f32(countOneBits(low) + countOneBits(high));
            var s = vec3<f32>(0.0);
            while low != 0u {
                let m = firstTrailingBit(low);
                s += radiance[m];
                low &= low - 1u;
            }
            while high != 0u {
                let m = firstTrailingBit(high);
                s += radiance[32u + m];
                high &= high - 1u;
            }
            sum += w * s / n;
            weight += w;
        }
        workgroupBarrier();
    }
    if live {
        probe_data[filtered_index(probe, j)] = vec4<f32>(sum / weight, own.w);
    }
}
