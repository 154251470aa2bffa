// G-buffer raster pass: the shared primary-visibility input of every technique (normal+roughness, albedo+metallic, emission, motion, view distance).
#import gilab::frame::frame
#import gilab::scene::{materials, alpha_hole, tri_material}
#import gilab::surface_point::surface_at
#import gilab::surface::pixel_spread
#import gilab::lights::triangle_emission

struct VertexIn {
    @location(0) position: vec3<f32>,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world_pos: vec3<f32>,
    @location(1) prev_clip: vec4<f32>,
    @location(2) cur_clip: vec4<f32>,
    // The triangle (vertices are triangles expanded in BVH order) and barycentrics of its
    // second and third vertex, so the fragment shades through gilab::surface like a ray hit.
    @location(3) @interpolate(flat) tri: u32,
    @location(4) bary: vec2<f32>,
}

struct GBufferOut {
    // xyz: world shading normal facing the camera, w: roughness.
    @location(0) normal_roughness: vec4<f32>,
    // rgb: base colour (linear), a: metallic.
    @location(1) albedo_metallic: vec4<f32>,
    // rgb: emitted radiance towards the camera.
    @location(2) emissive: vec4<f32>,
    // Screen-space motion in pixels: current position minus previous position.
    @location(3) motion: vec2<f32>,
    // Distance from the camera along the view ray (world units).
    @location(4) view_distance: f32,
}

@vertex
fn vs_main(v: VertexIn, @builtin(vertex_index) vertex: u32) -> VertexOut {
    var o: VertexOut;
    let p = vec4<f32>(v.position, 1.0);
    o.clip = frame.clip_from_world * p;
    o.cur_clip = o.clip;
    o.prev_clip = frame.prev_clip_from_world * p;
    o.world_pos = v.position;
    o.tri = vertex / 3u;
    let k = vertex % 3u;
    o.bary = vec2<f32>(select(0.0, 1.0, k == 1u), select(0.0, 1.0, k == 2u));
    return o;
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front_facing: bool) -> GBufferOut {
    // Alpha-masked holes are cut out like the any-hit test cuts them for rays.
    if alpha_hole(in.tri, in.bary) {
        discard;
    }
    var o: GBufferOut;
    let m = materials[tri_material(in.tri)];
    let view = in.world_pos - frame.camera_pos.xyz;
    let dist = length(view);
    let dir = view / max(dist, 1e-20);
    // The same surface a camera ray would find (textures at the camera ray cone's level,
    // normal map, facing), so raster and traced primary surfaces agree.
    let s = surface_at(in.tri, in.bary, dir, dist * pixel_spread());
    o.normal_roughness = vec4<f32>(s.normal, sqrt(s.material.alpha));
    o.albedo_metallic = vec4<f32>(s.material.base_color, s.material.metallic);
    // Counter-clockwise winding (glTF's convention) is the emitting side unless double-sided.
    let emits = m.emissive.w > 0.5 || front_facing;
    o.emissive = vec4<f32>(select(vec3<f32>(0.0), triangle_emission(in.tri, in.bary, -dir), emits), 1.0);
    let cur = in.cur_clip.xy / in.cur_clip.w;
    let prev = in.prev_clip.xy / in.prev_clip.w;
    o.motion = (cur - prev) * vec2<f32>(0.5, -0.5) * vec2<f32>(frame.size);
    o.view_distance = dist;
    return o;
}
