// Probe rays the screen traces could not resolve (the compacted list), continued from their last
// free point in the `tracing` mode (SDF or BVH) and lit from the surface cache. With the world
// radiance cache the ray stops at `world_cache_distance` (or a probe diagonal) and a miss
// reads the world probes around its end point in its direction; where none is traced yet, it
// goes on to the end.
#import gilab::counters::{flush_counts, no_counts, RAY_PROBE}
#import gilab::frame::frame
#import gilab::tracing::{trace_scene_on, hit_radiance, has_flag, FLAG_BVH}
#import gilab::equal_area::equal_area_dir
#import gilab::lumen_probes::{pp, probe_state, probe_data, load_probe, parity, probes_flag, ray_index, PROBES_WORLD_CACHE, PROBE_CELLS, STATE_WORLD_RAYS, STATE_WORLD_CONTINUED, STATE_WORLD_READS}
#import gilab::world_cache::{world_lookup, world_tmin_at}
#import gilab::sky::sky_radiance

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    var counts = no_counts();
    if gid.x < atomicLoad(&probe_state[STATE_WORLD_RAYS]) {
        let entry = atomicLoad(&probe_state[pp.offsets.y + gid.x]);
        let probe = entry / PROBE_CELLS;
        let q = load_probe(parity(), probe);
        let r = ray_index(probe, entry % PROBE_CELLS);
        let d = equal_area_dir(probe_data[r].xy);
        var t_free = -1.0 - probe_data[r + 1u].w;
        if !has_flag(FLAG_BVH) {
            // The SDF mode restarts from the probe: continuing its march from the screen trace's
            // last free point lost 3% of Cornell's light (rays passing thin walls and stopping
            // on the wrong surface, whatever the back-off or expand; README, Known gaps). The
            // BVH continues where the screen trace stopped.
            t_free = 0.0;
        }
        var o = q.pos;
        var n = q.geo;
        if t_free > 0.0 {
            o = q.pos + d * t_free;
            n = d;
        }
        let cached = probes_flag(PROBES_WORLD_CACHE);
        // The seed's probe TMin (gilab::world_cache).
        let t_cache = world_tmin_at(q.pos);
        let reach = select(1e30, max(t_cache - t_free, 0.0), cached);
        var h = trace_scene_on(o, n, d, reach, t_free);
        counts[RAY_PROBE] += 1u;
        var radiance = vec3<f32>(0.0);
        var found = false;
        if !h.hit && cached {
            let end = o + d * reach;
            let w = world_lookup(end, d, true);
            if w.weight > 0.0 {
                radiance = w.radiance;
                found = true;
                atomicAdd(&probe_state[STATE_WORLD_READS], 1u);
            } else {
                h = trace_scene_on(end, d, d, 1e30, t_free + reach);
                counts[RAY_PROBE] += 1u;
                h.t += reach;
            }
        }
        if !found {
            radiance = hit_radiance(h, sky_radiance(d));
        }
        probe_data[r + 1u] = vec4<f32>(radiance, t_free + select(reach, h.t, h.hit));
        probe_data[r].z = -probe_data[r].z;
        atomicAdd(&probe_state[STATE_WORLD_CONTINUED], 1u);
    }
    flush_counts(li, counts);
}
