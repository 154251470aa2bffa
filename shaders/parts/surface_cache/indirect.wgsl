// Surface cache indirect lighting, step 2 (the seed's "Indirect Lighting Gather"): every texel
// of this frame's probe tiles interpolates the four nearest probes of its card (bilinear), each
// weighted by its plane (texels behind a probe get nothing from it), by its mean hit distance
// (a probe whose rays stop short of the texel is likely on the other side of something) and by
// normal agreement; the result is blended into the indirect atlas over at most 4 frames.
#import gilab::surface_cache_lighting::{cache_tiles, probes}
#import gilab::surface_cache::{card_at, atlas_indirect, atlas_index, cache_texel}

const MAX_FRAMES: f32 = 4.0;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let k = wg.x * 4u + li / 16u;
    if k >= cache_tiles.params.probe_tile_count || cache_tiles.params.probe_tiles_total == 0u {
        return;
    }
    let entry = cache_tiles.tiles[cache_tiles.params.direct_tiles_total + (cache_tiles.params.probe_tile_first + k) % cache_tiles.params.probe_tiles_total];
    let tile = vec2<u32>(entry.x & 0xffffu, entry.x >> 16u);
    let texel = tile * 4u + vec2<u32>((li % 16u) % 4u, (li % 16u) / 4u);
    let t = cache_texel(entry.y, texel);
    if !t.valid {
        return;
    }
    let c = card_at(entry.y);
    let tile_lo = vec2<i32>(c.rect.xy / 4u);
    let tile_hi = vec2<i32>((c.rect.xy + c.rect.zw) / 4u) - 1;
    let f = (vec2<f32>(texel) + 0.5) / 4.0 - 0.5;
    let i0 = vec2<i32>(floor(f));
    let frac = f - floor(f);
    var sum = vec3<f32>(0.0);
    var weight = 0.0;
    let tiles_x = cache_tiles.params.atlas_size / 4u;
    for (var j = 0u; j < 4u; j++) {
        let o = vec2<i32>(i32(j & 1u), i32(j >> 1u));
        let pt = clamp(i0 + o, tile_lo, tile_hi);
        let p = probes[u32(pt.y) * tiles_x + u32(pt.x)];
        if p.pos.w < 0.5 {
            continue;
        }
        let bw = select(1.0 - frac, frac, vec2<bool>(o == vec2<i32>(1)));
        let to_texel = t.position - p.pos.xyz;
        let dist = length(to_texel);
        let plane = select(1.0, clamp(1.0 + 4.0 * dot(to_texel / dist, p.normal_dist.xyz), 0.0, 1.0), dist > 1e-6);
        let visible = clamp(p.normal_dist.w / max(dist, 1e-6), 0.0, 1.0);
        let w = (bw.x * bw.y + 1e-3) * plane * visible * max(dot(t.normal, p.normal_dist.xyz), 0.05);
        sum += w * p.irradiance.xyz;
        weight += w;
    }
    if weight <= 1e-6 {
        return;
    }
    let e = sum / weight;
    let ai = atlas_index(texel);
    let old = atlas_indirect[ai];
    let n = min(old.w + 1.0, MAX_FRAMES);
    atlas_indirect[ai] = vec4<f32>(old.xyz + (e - old.xyz) / n, n);
}
