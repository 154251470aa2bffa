// Equal-area octahedral mapping (Clarberg 2008): uv in [0, 1]^2 <-> unit direction, and square
// grids of cells on it (equal solid angle per cell, so a cell's radiance integrates with one
// weight). Lumen's screen probes and the world radiance cache store radiance in such cells.
#define_import_path gilab::equal_area

#import gilab::math::PI

fn copy_sign(v: vec2<f32>, s: vec2<f32>) -> vec2<f32> {
    return select(abs(v), -abs(v), s < vec2<f32>(0.0));
}

fn equal_area_dir(uv_in: vec2<f32>) -> vec3<f32> {
    let uv = 2.0 * uv_in - 1.0;
    let a = abs(uv);
    let sd = 1.0 - a.x - a.y;
    let r = 1.0 - abs(sd);
    var phi = 0.0;
    if r > 0.0 {
        phi = (PI / 4.0) * ((a.y - a.x) / r + 1.0);
    }
    let s = r * sqrt(max(2.0 - r * r, 0.0));
    let xy = copy_sign(vec2<f32>(s * cos(phi), s * sin(phi)), uv);
    return normalize(vec3<f32>(xy, select(-1.0, 1.0, sd >= 0.0) * (1.0 - r * r)));
}

fn equal_area_uv(d: vec3<f32>) -> vec2<f32> {
    let ad = abs(d);
    let r = sqrt(max(1.0 - ad.z, 0.0));
    let a = max(ad.x, ad.y);
    let b = min(ad.x, ad.y);
    var phi = 0.0;
    if a > 0.0 {
        phi = atan(b / a) * 2.0 / PI;
    }
    if ad.x < ad.y {
        phi = 1.0 - phi;
    }
    var uv = vec2<f32>(r - phi * r, phi * r);
    if d.z < 0.0 {
        uv = 1.0 - uv.yx;
    }
    return copy_sign(uv, d.xy) * 0.5 + 0.5;
}

fn octa_cell(d: vec3<f32>, res: u32) -> u32 {
    let c = min(vec2<u32>(equal_area_uv(d) * f32(res)), vec2<u32>(res - 1u));
    return c.y * res + c.x;
}

fn cell_dir(cell: u32, res: u32, offset: vec2<f32>) -> vec3<f32> {
    let c = vec2<f32>(f32(cell % res), f32(cell / res));
    return equal_area_dir((c + offset) / f32(res));
}
