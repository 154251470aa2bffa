// Primary surfaces shared by every technique that declares it needs them (`FrameInputs`): the
// engine's `frame/primary_surfaces.wgsl` pass traces one jittered camera ray per pixel (the
// reference's jitter sequence) and stores the hit here; last frame's copy stays for reprojection.
// Layout must match src/render/primary.rs.
#define_import_path gilab::primary

#import gilab::frame::{frame, FLAG_NO_PRIMARY_EMISSION}
#import gilab::brdf::Surface
#import gilab::scene::{materials, material_at}
#import gilab::surface_point::HitSurface

struct GSurface {
    // xyz: position, w: 1 valid / 0 miss.
    pos: vec4<f32>,
    // xyz: shading normal, w: GGX alpha.
    normal_alpha: vec4<f32>,
    // xyz: geometric normal, w: specular factor.
    geo_specular: vec4<f32>,
    // rgb: base colour, w: metallic.
    base_metal: vec4<f32>,
    // xyz: direction to the viewer, w: distance to the camera (depth along the ray).
    wo_dist: vec4<f32>,
    // rgb: emitted radiance towards the camera (or sky radiance for a miss).
    emission: vec4<f32>,
    // Screen motion in pixels: this frame's pixel position minus last frame's, camera and
    // object motion (0 on a miss or where the point was off screen last frame).
    motion: vec2<f32>,
    // Object id: the hit triangle's index in the scene (NO_SURFACE on a miss), and its material.
    triangle: u32,
    material: u32,
    // xyz: where this surface point was last frame (its object's previous transform; equal to
    // pos unless the object moved), what temporal passes reproject; w: the hit triangle in BVH
    // order + 1 (exact as f32 up to 2^24 triangles), 0 on a miss: the id a cache keeps to
    // follow the object (`next_position`).
    prev_pos: vec4<f32>,
}

const NO_SURFACE: u32 = 0xffffffffu;

// Two segments of width x height surfaces, by frame parity: this frame's and last frame's.
@group(1) @binding(2) var<storage, read_write> surfaces: array<GSurface>;

fn surface_slot(frame_index: u32, pixel: u32) -> u32 {
    return (frame_index & 1u) * frame.size.x * frame.size.y + pixel;
}

fn current_surface(pixel: u32) -> GSurface {
    return surfaces[surface_slot(frame.frame_index, pixel)];
}

// What the camera sees emitted at a primary surface, or nothing where the frame asks for the
// light sources' own radiance to be left out (FLAG_NO_PRIMARY_EMISSION): every technique's
// final pass starts its pixel from this.
fn primary_emission(s: GSurface) -> vec3<f32> {
    return select(s.emission.xyz, vec3<f32>(0.0), (frame.flags & FLAG_NO_PRIMARY_EMISSION) != 0u);
}

fn previous_surface(pixel: u32) -> GSurface {
    return surfaces[surface_slot(frame.frame_index + 1u, pixel)];
}

// The surface where it stood last frame (its object's motion undone), to compare with last
// frame's surfaces; the surface itself when nothing moved.
fn at_last_frame(s: GSurface) -> GSurface {
    var o = s;
    o.pos = vec4<f32>(s.prev_pos.xyz, s.pos.w);
    return o;
}

// Continuous previous-frame pixel position of a world point; x < 0 when it was behind the camera.
fn previous_pixel_position(p: vec3<f32>) -> vec2<f32> {
    let clip = frame.prev_clip_from_world * vec4<f32>(p, 1.0);
    if clip.w <= 0.0 {
        return vec2<f32>(-1.0);
    }
    let ndc = clip.xy / clip.w;
    return vec2<f32>((ndc.x * 0.5 + 0.5) * f32(frame.size.x), (0.5 - ndc.y * 0.5) * f32(frame.size.y));
}

// Whether the camera sees world point p this frame: p projects into the image and the primary
// surface of that pixel lies at p's distance from the camera, within 5% (a surface the camera
// has seen, for a still camera; the cache-coverage counters split ray hits by it).
fn camera_sees(p: vec3<f32>) -> bool {
    let clip = frame.clip_from_world * vec4<f32>(p, 1.0);
    if clip.w <= 0.0 {
        return false;
    }
    let ndc = clip.xy / clip.w;
    let f = vec2<f32>((ndc.x * 0.5 + 0.5) * f32(frame.size.x), (0.5 - ndc.y * 0.5) * f32(frame.size.y));
    if f.x < 0.0 || f.y < 0.0 || f.x >= f32(frame.size.x) || f.y >= f32(frame.size.y) {
        return false;
    }
    let s = current_surface(u32(f.y) * frame.size.x + u32(f.x));
    if s.pos.w < 0.5 {
        return false;
    }
    let d = distance(p, frame.camera_pos.xyz);
    return abs(d - s.wo_dist.w) <= 0.05 * d;
}

// Previous-frame pixel of a surface point, or -1 when it was off screen.
fn reproject(p: vec3<f32>) -> i32 {
    let f = previous_pixel_position(p);
    if f.x < 0.0 || f.y < 0.0 || f.x >= f32(frame.size.x) || f.y >= f32(frame.size.y) {
        return -1;
    }
    return i32(u32(f.y) * frame.size.x + u32(f.x));
}

// The surface's BRDF parameters (alpha already squared; the model and Callisto's parameters
// from its material).
fn surface_material(s: GSurface) -> Surface {
    return Surface(s.base_metal.xyz, s.base_metal.w, s.normal_alpha.w, s.geo_specular.w, material_at(s.material).shading);
}

// The surface as a path vertex (gilab::path_vertex's NEE, a path continued from the pixel);
// the camera sees its front.
fn primary_hit_surface(s: GSurface) -> HitSurface {
    return HitSurface(s.pos.xyz, s.geo_specular.xyz, s.normal_alpha.xyz, true, surface_material(s), s.material);
}

// A random pixel in a disk of `radius` pixels around `pixel` (uniform in area), or -1 off
// screen: where spatial reuse looks for neighbours.
fn disk_neighbour(pixel: vec2<u32>, radius: f32, u: vec2<f32>) -> i32 {
    let r = radius * sqrt(u.x);
    let angle = 6.28318530717959 * u.y;
    let px = i32(pixel.x) + i32(round(r * cos(angle)));
    let py = i32(pixel.y) + i32(round(r * sin(angle)));
    if px < 0 || py < 0 || px >= i32(frame.size.x) || py >= i32(frame.size.y) {
        return -1;
    }
    return py * i32(frame.size.x) + px;
}

// Similar enough surfaces to share samples: normals within ~25 degrees, depths within 10%.
fn similar(a: GSurface, b: GSurface) -> bool {
    if a.pos.w < 0.5 || b.pos.w < 0.5 {
        return false;
    }
    if dot(a.normal_alpha.xyz, b.normal_alpha.xyz) < 0.9 {
        return false;
    }
    let plane = abs(dot(b.pos.xyz - a.pos.xyz, a.geo_specular.xyz));
    return plane < 0.1 * a.wo_dist.w && abs(a.wo_dist.w - b.wo_dist.w) < 0.1 * a.wo_dist.w;
}
