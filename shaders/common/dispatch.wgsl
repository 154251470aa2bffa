// Indirect dispatch for passes over lists the GPU builds (surfels, probes, tiles): a pass that
// decides a list's length writes `dispatch_for(length)` into an arguments buffer, and the list
// pass (`pipelines::list_pass`) runs one invocation per element in workgroups of LIST_GROUP_SIZE.
#define_import_path gilab::dispatch

const LIST_GROUP_SIZE: u32 = 64u;

// Matches wgpu's indirect compute arguments: workgroup counts x, y, z.
struct DispatchArgs {
    x: u32,
    y: u32,
    z: u32,
}

fn dispatch_for(length: u32) -> DispatchArgs {
    return DispatchArgs((length + LIST_GROUP_SIZE - 1u) / LIST_GROUP_SIZE, 1u, 1u);
}
