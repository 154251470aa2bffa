// Hierarchical Z of last frame for the screen traces, mips 0..4: each 16x16 workgroup loads its
// pixels' closest 1/w (from last frame's surfaces and camera; 0 on a miss, infinitely far) and
// reduces them with max (closest) in shared memory. `hzb_top` builds the coarser mips.
#import gilab::frame::frame
#import gilab::primary::previous_surface
#import gilab::lumen_probes::{pp, hzb_store}

var<workgroup> tile: array<f32, 256>;

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    var v = 0.0;
    if gid.x < frame.size.x && gid.y < frame.size.y {
        let s = previous_surface(gid.y * frame.size.x + gid.x);
        if s.pos.w > 0.5 {
            let w = (frame.prev_clip_from_world * vec4<f32>(s.pos.xyz, 1.0)).w;
            v = select(0.0, 1.0 / w, w > 0.0);
        }
        hzb_store(0u, gid.xy, v);
    }
    tile[lid.y * 16u + lid.x] = v;
    workgroupBarrier();
    for (var l = 1u; l < 5u; l++) {
        let n = 16u >> l;
        var m = 0.0;
        let inside = lid.x < n && lid.y < n;
        if inside {
            let src = 2u * n;
            let c = 2u * lid.xy;
            m = max(
                max(tile[c.y * src + c.x], tile[c.y * src + c.x + 1u]),
                max(tile[(c.y + 1u) * src + c.x], tile[(c.y + 1u) * src + c.x + 1u]),
            );
        }
        workgroupBarrier();
        if inside {
            tile[lid.y * n + lid.x] = m;
            let cell = wid.xy * n + lid.xy;
            let mip = pp.hzb_mips[l];
            if l < pp.counts.x && cell.x < mip.y && cell.y < mip.z {
                hzb_store(l, cell, m);
            }
        }
        workgroupBarrier();
    }
}
