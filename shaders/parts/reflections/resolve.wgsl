// Reflections, pass 2 (full resolution): spatial reuse. Each pixel weights its own block's ray
// and `reuse` neighbours' (within `reuse_radius` traced pixels, on a similar surface) by its own
// lobe over the pdf that drew them, w = f·cos / pdf, and takes the ratio estimator
// sum(w L) / sum(w) times the lobe's directional albedo from the table (Stachowiak 2015, as
// the seed's spatial reuse "reweights neighbours by their BRDF"). The ratio is biased (it
// normalises by the sampled weights) but consistent; a neighbour's ray starts at its own pixel,
// so contact detail blurs by the reuse radius. Mirror rays (no pdf) are never reused: a mirror
// pixel takes its own block's ray. Pixels rougher than max_roughness get only the albedo
// plane, which the family multiplies by its own irradiance.
#import gilab::frame::frame
#import gilab::math::luminance
#import gilab::rng::{rng_init, rand, rand_pair, STREAM_REFLECTION_REUSE}
#import gilab::primary::{current_surface, surface_material, GSurface}
#import gilab::brdf::{specular_eval, DELTA_ALPHA}
#import gilab::reflections::{rparams, ray_samples, resolved, specular_albedo, KIND_NONE, KIND_ROUGH, KIND_MIRROR}

// A neighbour's ray is reused only from a surface like the pixel's (normal and depth).
fn similar_source(s: GSurface, source: u32) -> bool {
    let o = current_surface(source);
    if o.pos.w < 0.5 {
        return false;
    }
    let depth_ok = abs(o.wo_dist.w - s.wo_dist.w) < 0.05 * s.wo_dist.w;
    return depth_ok && dot(o.normal_alpha.xyz, s.normal_alpha.xyz) > 0.9;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.size.x || gid.y >= frame.size.y {
        return;
    }
    let idx = gid.y * frame.size.x + gid.x;
    let px = frame.size.x * frame.size.y;
    let s = current_surface(idx);
    var spec = vec3<f32>(0.0);
    var dist = 0.0;
    var rough = vec3<f32>(0.0);
    var kind = KIND_NONE;
    if s.pos.w > 0.5 {
        let m = surface_material(s);
        let n = s.normal_alpha.xyz;
        let wo = s.wo_dist.xyz;
        let albedo = specular_albedo(m, max(dot(n, wo), 0.0));
        let ds = rparams.downsample;
        let own = min(gid.xy / ds, vec2<u32>(rparams.trace_width, rparams.trace_height) - 1u);
        let own_idx = own.y * rparams.trace_width + own.x;
        let own_kind = ray_samples[3u * own_idx + 2u].y;
        if sqrt(m.alpha) > rparams.max_roughness {
            rough = albedo;
            kind = KIND_ROUGH;
        } else if m.alpha < DELTA_ALPHA || own_kind == KIND_MIRROR {
            // The mirror lobe: this block's ray is the only one in the pixel's lobe.
            let r = ray_samples[3u * own_idx];
            spec = albedo * r.xyz;
            dist = r.w;
            kind = own_kind;
        } else {
            var rng = rng_init(gid.xy, frame.sample_offset, STREAM_REFLECTION_REUSE, frame.seed);
            var sum = vec3<f32>(0.0);
            var weight = 0.0;
            var dist_sum = 0.0;
            let hi = vec2<i32>(i32(rparams.trace_width), i32(rparams.trace_height)) - 1;
            for (var k = 0u; k <= rparams.reuse; k++) {
                var t = vec2<i32>(own);
                if k > 0u {
                    let o = (rand_pair(&rng) * 2.0 - 1.0) * rparams.reuse_radius;
                    t = clamp(t + vec2<i32>(round(o)), vec2<i32>(0), hi);
                }
                let ti = u32(t.y) * rparams.trace_width + u32(t.x);
                let dir_pdf = ray_samples[3u * ti + 1u];
                let info = ray_samples[3u * ti + 2u];
                if dir_pdf.w <= 0.0 || (k > 0u && !similar_source(s, u32(info.x))) {
                    continue;
                }
                let e = specular_eval(m, n, wo, dir_pdf.xyz);
                let w = luminance(e.f) * max(dot(n, dir_pdf.xyz), 0.0) / dir_pdf.w;
                if w <= 0.0 {
                    continue;
                }
                let r = ray_samples[3u * ti];
                sum += w * r.xyz;
                dist_sum += w * min(r.w, 1e4);
                weight += w;
            }
            if weight > 0.0 {
                spec = albedo * sum / weight;
                dist = dist_sum / weight;
                kind = own_kind;
            }
        }
    }
    resolved[idx] = vec4<f32>(spec, dist);
    resolved[px + idx] = vec4<f32>(rough, kind);
}
