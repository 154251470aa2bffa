// Toroidal grids: a window of cells that scrolls with the camera reuses the slots it leaves, so a
// cell's slot is its coordinate modulo the window's size (the distance field's bricks, the world
// radiance cache's probes, world ReGIR's cells, DDGI's probes).
#define_import_path gilab::toroidal

// v modulo n in [0, n) for either sign of v (n > 0, |v| < 2^24). Not by integer `%`: lavapipe
// divides integers one SIMD lane at a time, and the distance field's brick lookup, which wraps
// at every brick a step enters, spent 40% of Lumen's frame there. A float quotient, off by at
// most one where the division rounds, then corrected: exact.
fn wrap_grid(v: vec3<i32>, n: vec3<i32>) -> vec3<i32> {
    let s = v - n * vec3<i32>(floor((vec3<f32>(v) + 0.5) / vec3<f32>(n)));
    return select(select(s, s - n, s >= n), s + n, s < vec3<i32>(0));
}
