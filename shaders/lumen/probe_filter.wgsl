// The seed's spatial filter in probe space (one workgroup per probe, one thread per cell): a
// uniform probe's cell is averaged with the same cell of its 3x3 neighbouring uniform probes,
// each weighted by how close it lies to the probe's plane, and dropped when the point its ray
// hit, seen from this probe, is more than 10 degrees off the cell's direction (the angle error
// that keeps contact shadows). Adaptive probes and `spatial_filter = false` copy.
#import gilab::equal_area::cell_dir
#import gilab::lumen_probes::{probe_data, load_probe, parity, probe_count, probes_flag, cache_index, filtered_index, tiles, tile_probe, plane_weight, PROBE_RES, PROBES_SPATIAL}

const MAX_ANGLE_COS: f32 = 0.9848;

// The angle test alone drops near hits more often than far ones (parallax grows as the hit comes
// closer), which darkened Cornell by 4.7%: a neighbour whose ray ended within 25% of this cell's
// own hit distance hit the same surface, so it is kept whatever its parallax (-3.8% left).
fn same_depth(own: f32, other: f32) -> bool {
    return own > 0.0 && own < 1e20 && abs(own - other) < 0.25 * max(own, other);
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    let probe = wid.x;
    if probe >= probe_count() {
        return;
    }
    let q = load_probe(parity(), probe);
    if !q.valid {
        return;
    }
    let own = probe_data[cache_index(parity(), probe, j)];
    var sum = own.xyz;
    var weight = 1.0;
    let uniform_probe = probe < tiles().x * tiles().y;
    if probes_flag(PROBES_SPATIAL) && uniform_probe {
        let d = cell_dir(j, PROBE_RES, vec2<f32>(0.5));
        let t = vec2<i32>(vec2<u32>(probe % tiles().x, probe / tiles().x));
        for (var k = 0u; k < 9u; k++) {
            let o = vec2<i32>(i32(k % 3u) - 1, i32(k / 3u) - 1);
            let nt = t + o;
            if k == 4u || any(nt < vec2<i32>(0)) || any(nt >= vec2<i32>(tiles())) {
                continue;
            }
            let nb = tile_probe(vec2<u32>(nt));
            let p = load_probe(parity(), nb);
            if !p.valid {
                continue;
            }
            var w = plane_weight(q.pos, q.normal, q.dist, p.pos, p.normal);
            let c = probe_data[cache_index(parity(), nb, j)];
            if c.w >= 0.0 && c.w < 1e20 {
                let seen = normalize(p.pos + d * c.w - q.pos);
                if dot(seen, d) < MAX_ANGLE_COS && !same_depth(own.w, c.w) {
                    w = 0.0;
                }
            }
            sum += w * c.xyz;
            weight += w;
        }
    }
    probe_data[filtered_index(probe, j)] = vec4<f32>(sum / weight, own.w);
}
