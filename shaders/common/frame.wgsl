// Per-frame uniforms shared by every technique: camera, frame index, seed, sky, samples so far.
#define_import_path gilab::frame

struct FrameUniforms {
    clip_from_world: mat4x4<f32>,
    prev_clip_from_world: mat4x4<f32>,
    // Camera basis for ray generation: right and up are pre-scaled by tan(fov/2) (and aspect).
    camera_pos: vec4<f32>,
    camera_right: vec4<f32>,
    camera_up: vec4<f32>,
    camera_forward: vec4<f32>,
    sky: vec4<f32>,
    size: vec2<u32>,
    frame_index: u32,
    seed: u32,
    // Total samples already accumulated per pixel before this frame.
    sample_offset: u32,
    flags: u32,
    pad: vec2<u32>,
}

@group(1) @binding(0) var<uniform> frame: FrameUniforms;

// flags bit: leave out emission seen directly by the camera (render::FLAG_NO_PRIMARY_EMISSION).
const FLAG_NO_PRIMARY_EMISSION: u32 = 1u;

// Primary ray through a pixel position given in pixels (jitter included by the caller).
fn camera_ray_dir(pixel_pos: vec2<f32>) -> vec3<f32> {
    let ndc = vec2<f32>(
        2.0 * pixel_pos.x / f32(frame.size.x) - 1.0,
        1.0 - 2.0 * pixel_pos.y / f32(frame.size.y),
    );
    return normalize(frame.camera_forward.xyz + ndc.x * frame.camera_right.xyz + ndc.y * frame.camera_up.xyz);
}
