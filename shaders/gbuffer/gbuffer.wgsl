// G-buffer raster pass: the shared primary-visibility input of every technique (normal+roughness, albedo+metallic, emission, motion, view distance).
#import gilab::frame::frame
#import gilab::scene::{materials, base_color}

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) material: u32,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world_pos: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) @interpolate(flat) material: u32,
    @location(4) prev_clip: vec4<f32>,
    @location(5) cur_clip: vec4<f32>,
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
fn vs_main(v: VertexIn) -> VertexOut {
    var o: VertexOut;
    let p = vec4<f32>(v.position, 1.0);
    o.clip = frame.clip_from_world * p;
    o.cur_clip = o.clip;
    o.prev_clip = frame.prev_clip_from_world * p;
    o.world_pos = v.position;
    o.normal = v.normal;
    o.uv = v.uv;
    o.material = v.material;
    return o;
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front_facing: bool) -> GBufferOut {
    var o: GBufferOut;
    let m = materials[in.material];
    let view = in.world_pos - frame.camera_pos.xyz;
    let dist = length(view);
    let geo_n = normalize(cross(dpdx(in.world_pos), dpdy(in.world_pos)));
    // Facing decided from the geometric normal; robust to missing or flipped vertex normals.
    let to_cam = -view / max(dist, 1e-20);
    var ng = select(-geo_n, geo_n, dot(geo_n, to_cam) >= 0.0);
    var n = in.normal;
    let len = length(n);
    n = select(ng, n / max(len, 1e-20), len > 1e-6);
    n = select(-n, n, dot(n, ng) >= 0.0);
    o.normal_roughness = vec4<f32>(n, m.params.y);
    let base = base_color(m, in.uv);
    o.albedo_metallic = vec4<f32>(base.xyz, m.params.x);
    // Counter-clockwise winding (glTF's convention) is the emitting side unless double-sided.
    let emits = m.emissive.w > 0.5 || front_facing;
    o.emissive = vec4<f32>(select(vec3<f32>(0.0), m.emissive.xyz, emits), 1.0);
    let cur = in.cur_clip.xy / in.cur_clip.w;
    let prev = in.prev_clip.xy / in.prev_clip.w;
    o.motion = (cur - prev) * vec2<f32>(0.5, -0.5) * vec2<f32>(frame.size);
    o.view_distance = dist;
    return o;
}
