// The hierarchical Z's mips past 4, by one workgroup (each mip waits on the one before).
#import gilab::lumen_probes::{pp, hzb_load, hzb_store}

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(local_invocation_index) li: u32) {
    for (var l = 5u; l < pp.counts.x; l++) {
        let mip = pp.hzb_mips[l];
        let below = pp.hzb_mips[l - 1u];
        for (var i = li; i < mip.y * mip.z; i += 256u) {
            let cell = vec2<u32>(i % mip.y, i / mip.y);
            var m = 0.0;
            for (var k = 0u; k < 4u; k++) {
                let c = 2u * cell + vec2<u32>(k & 1u, k >> 1u);
                if c.x < below.y && c.y < below.z {
                    m = max(m, hzb_load(l - 1u, c));
                }
            }
            hzb_store(l, cell, m);
        }
        storageBarrier();
        workgroupBarrier();
    }
}
