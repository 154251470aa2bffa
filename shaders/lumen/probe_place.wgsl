// Uniform screen probes: one per tile of `probe_spacing` pixels, at this frame's jittered pixel of
// the tile (the seed jitters the placement grid every frame), on the surface the G-buffer holds.
#import gilab::primary::current_surface
#import gilab::frame::frame
#import gilab::lumen_probes::{pp, probe_state, tiles, spacing, tile_probe, store_probe, parity, ScreenProbe, STATE_PROBE_COUNT, STATE_WORLD_RAYS}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if all(gid.xy == vec2<u32>(0u)) {
        atomicStore(&probe_state[STATE_PROBE_COUNT], pp.adaptive.w);
        atomicStore(&probe_state[STATE_WORLD_RAYS], 0u);
    }
    if gid.x >= tiles().x || gid.y >= tiles().y {
        return;
    }
    let pixel = min(gid.xy * spacing() + pp.jitter.xy, frame.size - 1u);
    let s = current_surface(pixel.y * frame.size.x + pixel.x);
    let probe = ScreenProbe(s.pos.w > 0.5, s.pos.xyz, s.wo_dist.w, s.normal_alpha.xyz, s.geo_specular.xyz, pixel, 0.0, false);
    store_probe(parity(), tile_probe(gid.xy), probe);
}
