// Adaptive screen probes: at every cell of half the probe spacing whose jittered pixel the uniform
// probes cannot interpolate (no probe on its plane: depth or normal discontinuities), one more
// probe is placed (up to the capacity); the cell's entry in the adaptive map names it.
#import gilab::primary::current_surface
#import gilab::frame::frame
#import gilab::lumen_probes::{pp, probe_state, max_probes, store_probe, parity, probes_flag, uniform_neighbours, ScreenProbe, NO_PROBE, PROBES_ADAPTIVE, STATE_PROBE_COUNT, STATE_ADAPTIVE}

// Below this summed interpolation weight the uniform probes "fail" for a pixel.
const FAIL_WEIGHT: f32 = 0.05;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cells = pp.adaptive.xy;
    if gid.x >= cells.x || gid.y >= cells.y {
        return;
    }
    let slot = pp.offsets.x + gid.y * cells.x + gid.x;
    var index = NO_PROBE;
    let pixel = min(gid.xy * pp.adaptive.z + pp.jitter.xy / 2u, frame.size - 1u);
    let s = current_surface(pixel.y * frame.size.x + pixel.x);
    if probes_flag(PROBES_ADAPTIVE) && s.pos.w > 0.5 {
        let nb = uniform_neighbours(pixel, s.pos.xyz, s.normal_alpha.xyz, s.wo_dist.w);
        let total = nb.weight[0] + nb.weight[1] + nb.weight[2] + nb.weight[3];
        if total < FAIL_WEIGHT {
            let i = atomicAdd(&probe_state[STATE_PROBE_COUNT], 1u);
            if i < max_probes() {
                index = i;
                atomicAdd(&probe_state[STATE_ADAPTIVE], 1u);
                store_probe(parity(), i, ScreenProbe(true, s.pos.xyz, s.wo_dist.w, s.normal_alpha.xyz, s.geo_specular.xyz, pixel, 0.0, true));
            }
        }
    }
    atomicStore(&probe_state[slot], index);
}
