// The direct-light part's shading (src/parts/restir_direct.rs): each pixel's ReSTIR DI reservoir
// (ReSTIR's own passes ran before in this frame, GI off) shaded with one visibility ray
// (gilab::restir::shade_reservoir): f · Le · G · V · W, no emission. Group 2 is ReSTIR's; group
// 3 holds only the per-pixel output that the family's own pass reads (surfels' and Lumen's
// `apply`). Counted as shadow rays, like the NEE it replaces.
#import gilab::frame::frame
#import gilab::counters::{flush_counts, no_counts, RAY_SHADOW}
#import gilab::primary::current_surface
#import gilab::restir::{reservoir_index, parity, shade_reservoir}

@group(3) @binding(0) var<storage, read_write> direct_out: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    var counts = no_counts();
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let idx = gid.y * frame.size.x + gid.x;
        let s = current_surface(idx);
        let shaded = shade_reservoir(s, reservoir_index(parity(), idx));
        counts[RAY_SHADOW] += shaded.shadow_rays;
        direct_out[idx] = vec4<f32>(shaded.radiance, 0.0);
    }
    flush_counts(local_index, counts);
}
