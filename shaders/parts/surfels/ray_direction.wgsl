// A surfel ray's direction, shared by the trace pass and the ray-binning pass (which sorts the
// rays by it before they are traced): cosine-weighted, or once the surfel's guiding map is
// populated, from the map with probability GUIDE_MIX (texel by the map's CDF, uniform within the
// texel); the pdf is the true mixed pdf, so each surfel's estimate stays unbiased. It takes the
// ray's first four random numbers, so both passes draw the same direction.
#define_import_path gilab::surfel_rays

#import gilab::math::INV_PI
#import gilab::rng::{Rng, rand, rand_pair}
#import gilab::sampling::sample_cosine_hemisphere
#import gilab::surfels::{states, has_flag, guide_value, hemi_oct_encode, hemi_oct_decode, hemi_oct_jacobian, texel_of, FLAG_GUIDING, GUIDE_RES, GUIDE_TEXELS, GUIDE_POPULATED, GUIDE_MIX}

struct SurfelRayDirection {
    // In the surfel's frame (z along its normal).
    v: vec3<f32>,
    // Solid-angle pdf of v.
    pdf: f32,
    guide_texel: u32,
}

fn surfel_ray_direction(slot: u32, rng: ptr<function, Rng>) -> SurfelRayDirection {
    let guided = has_flag(FLAG_GUIDING) && states[slot].info.y >= GUIDE_POPULATED;
    var guide_sum = 0.0;
    if guided {
        for (var t = 0u; t < GUIDE_TEXELS; t++) {
            guide_sum += guide_value(slot, t);
        }
    }
    var v: vec3<f32>;
    let u_mix = rand(rng);
    let u_texel = rand(rng);
    let u_dir = rand_pair(rng);
    if guided && guide_sum > 0.0 && u_mix < GUIDE_MIX {
        // Walk the map's CDF (the seed's discrete inversion), then a uniform point in the texel.
        let target_sum = u_texel * guide_sum;
        var acc = 0.0;
        var texel = GUIDE_TEXELS - 1u;
        for (var t = 0u; t < GUIDE_TEXELS; t++) {
            acc += guide_value(slot, t);
            if acc > target_sum {
                texel = t;
                break;
            }
        }
        let cell = vec2<f32>(f32(texel % GUIDE_RES), f32(texel / GUIDE_RES));
        v = hemi_oct_decode((cell + u_dir) / f32(GUIDE_RES) * 2.0 - 1.0);
    } else {
        v = sample_cosine_hemisphere(u_dir);
    }
    var pdf = v.z * INV_PI;
    let e = hemi_oct_encode(v);
    let guide_texel = texel_of(e, GUIDE_RES);
    if guided && guide_sum > 0.0 {
        let texel_area = 4.0 / f32(GUIDE_TEXELS);
        let guide_pdf = guide_value(slot, guide_texel) / guide_sum / texel_area * hemi_oct_jacobian(e);
        pdf = (1.0 - GUIDE_MIX) * pdf + GUIDE_MIX * guide_pdf;
    }
    return SurfelRayDirection(v, pdf, guide_texel);
}
