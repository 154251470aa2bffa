// Traces world radiance cache probes (one workgroup of 256 per probe, one ray per 16x16 cell,
// jittered within it each update): this frame's share of the new-then-stalest list of
// world_select.
// Rays start at the probe's centre; back faces closer than one probe spacing vote the probe
// inside geometry (over a quarter: unusable). A cell keeps the running mean of its radiance and
// hit distance (the lookup's visibility test) over at most `world_cache_history` updates while
// the probe stays at the same grid position (a short history follows the surface cache's light
// with less lag). The frame a probe was traced goes to the staleness word world_select reads.
// (Skipping hits closer than a spacing, as a screen ray that read the probe already covered that
// stretch, was tried: it continued rays through walls, a leak on thin-wall and 5% of the furnace
// lost.)
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_CACHE}
#import gilab::rng::{rng_init, rand_pair, STREAM_LUMEN_WORLD}
#import gilab::tracing::{trace_scene, hit_radiance}
#import gilab::equal_area::cell_dir
#import gilab::world_cache::{wc, world_lists, world_cache, world_header, world_slot_coord, world_probe_pos, world_slots, world_spacing, world_res, world_updates, world_list_offset, world_frames_index, WORLD_RES, WORLD_CELLS, WORLD_STATE_NEW, WORLD_STATE_OLD}
#import gilab::sky::sky_radiance

var<workgroup> back_faces: atomic<u32>;

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) j: u32) {
    var counts = no_counts();
    let total = world_slots();
    let n_new = world_lists[WORLD_STATE_NEW];
    let n_old = world_lists[WORLD_STATE_OLD];
    var slot = 0xffffffffu;
    if wid.x < n_new {
        slot = world_lists[world_list_offset() + wid.x];
    } else if wid.x - n_new < n_old {
        slot = world_lists[world_list_offset() + total + wid.x - n_new];
    }
    let live = slot < total;
    var g = vec3<i32>(0);
    var same = false;
    var old = vec4<f32>(0.0);
    var radiance = vec3<f32>(0.0);
    var dist = 0.0;
    var updates = 0.0;
    if live {
        let per = world_res() * world_res() * world_res();
        let l = slot / per;
        g = world_slot_coord(slot);
        let h = world_header(slot);
        same = h.w >= 0.0 && all(vec3<i32>(h.xyz) == g);
        updates = world_updates(h);
        let pos = world_probe_pos(l, g);
        var rng = rng_init(vec2<u32>(slot, j), frame.frame_index, STREAM_LUMEN_WORLD, frame.seed);
        let d = cell_dir(j, WORLD_RES, rand_pair(&rng));
        let skip = world_spacing(l);
        var hit = trace_scene(pos, d, d, 1e30);
        counts[RAY_CACHE] += 1u;
        if hit.hit && hit.back_face && hit.t < skip {
            atomicAdd(&back_faces, 1u);
        }
        radiance = hit_radiance(hit, sky_radiance(d));
        dist = select(1e20, hit.t, hit.hit);
        old = world_cache[slot * WORLD_CELLS + j];
    }
    workgroupBarrier();
    if live {
        var n = 1.0;
        var mean = vec4<f32>(radiance, dist);
        if same {
            n = min(updates + 1.0, f32(wc.update.x));
            mean = old + (vec4<f32>(radiance, dist) - old) / n;
        }
        world_cache[slot * WORLD_CELLS + j] = mean;
        if j == 0u {
            world_cache[world_frames_index(slot)].y = f32(frame.frame_index + 1u);
            let inside = f32(atomicLoad(&back_faces)) / f32(WORLD_CELLS);
            world_cache[total * WORLD_CELLS + slot] = vec4<f32>(vec3<f32>(g), 2.0 * n + min(inside, 0.999));
        }
    }
    flush_counts(j, counts);
}
