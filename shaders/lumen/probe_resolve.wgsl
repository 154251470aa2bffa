// A probe's cells from its rays (one workgroup per probe, one thread per cell): the sum of
// radiance x weight over the rays that landed in the cell, an unbiased estimate of the cell's mean
// radiance whatever pdf chose the rays; the hit distance is their mean. Then the seed's temporal
// accumulation of probes: blended with last frame's probe on the same plane (reprojected),
// 1 / (frames + 1) down to `probe_temporal_weight`.
#import gilab::lumen_probes::{pp, probe_data, load_probe, store_probe, parity, probe_count, probes_flag, previous_match, cache_index, ray_index, NO_PROBE, PROBE_CELLS, PROBES_TEMPORAL}

var<workgroup> screen_rays: atomic<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    let probe = wid.x;
    var q = load_probe(parity(), probe);
    let live = probe < probe_count() && q.valid;
    var history = 0.0;
    if live {
        var sum = vec3<f32>(0.0);
        var dist = 0.0;
        var n = 0.0;
        for (var k = 0u; k < PROBE_CELLS; k++) {
            let r = ray_index(probe, k);
            let rec = probe_data[r];
            if bitcast<u32>(rec.w) != j {
                continue;
            }
            let l = probe_data[r + 1u];
            sum += abs(rec.z) * l.xyz;
            if l.w >= 0.0 {
                dist += l.w;
                n += 1.0;
            }
        }
        var hit = select(-1.0, dist / max(n, 1.0), n > 0.0);
        var out = sum;
        let prev = previous_match(q);
        if probes_flag(PROBES_TEMPORAL) && prev != NO_PROBE {
            let p = load_probe(1u - parity(), prev);
            history = min(p.history + 1.0, 255.0);
            let alpha = max(1.0 / (history + 1.0), pp.misc.z);
            let old = probe_data[cache_index(1u - parity(), prev, j)];
            out = mix(old.xyz, sum, alpha);
            if hit < 0.0 {
                hit = old.w;
            } else if old.w >= 0.0 {
                hit = mix(old.w, hit, alpha);
            }
        }
        probe_data[cache_index(parity(), probe, j)] = vec4<f32>(out, hit);
        // Share of this probe's rays the screen traces resolved (a debug view).
        if probe_data[ray_index(probe, j)].z > 0.0 {
            atomicAdd(&screen_rays, 1u);
        }
    }
    workgroupBarrier();
    if live && j == 0u {
        q.history = history;
        store_probe(parity(), probe, q);
        probe_data[4u * (parity() * pp.grid.w + probe) + 3u].z = f32(atomicLoad(&screen_rays)) / f32(PROBE_CELLS);
    }
}
