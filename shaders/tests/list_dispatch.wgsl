// Test harness for tests/gpu.rs: a list length decided on the GPU, then one invocation per
// element through an indirect dispatch (gilab::dispatch, pipelines::list_pass).
#import gilab::dispatch::{DispatchArgs, dispatch_for, LIST_GROUP_SIZE}

struct ListHeader {
    length: u32,
}

// `make_list` binds header, args and wanted; `visit` binds header and visits only: the arguments
// buffer cannot be writable storage in the pass it drives.
@group(0) @binding(0) var<storage, read_write> header: ListHeader;
@group(0) @binding(1) var<storage, read_write> args: DispatchArgs;
@group(0) @binding(2) var<uniform> wanted: vec4<u32>;
@group(0) @binding(3) var<storage, read_write> visits: array<atomic<u32>>;

@compute @workgroup_size(1, 1, 1)
fn make_list() {
    header.length = wanted.x;
    args = dispatch_for(wanted.x);
}

@compute @workgroup_size(LIST_GROUP_SIZE, 1, 1)
fn visit(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < header.length {
        atomicAdd(&visits[gid.x], 1u);
    }
}
