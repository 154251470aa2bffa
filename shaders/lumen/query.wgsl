// Queries for tests and tools (never part of a frame), `query_mode`:
// 0: SDF at points: in queries[2i].xyz, out queries[2i + 1] = (distance, object, level, 0);
// 1: SDF sphere trace of rays (origin queries[2i].xyz, direction queries[2i + 1].xyz), from the
//    origin itself with no surface bias and no expand (the bare field): out queries[2i] = (t, hit, steps, level);
// 2: the same rays through the BVH: out queries[2i] = (t, hit, 0, 0), queries[2i + 1] = the hit
//    triangle's normal.
#import gilab::bvh::{trace_closest, NO_HIT}
#import gilab::scene::tri_geom
#import gilab::lumen::{params, queries, sdf_sample, sdf_object, sdf_trace, finest_level}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.query_count {
        return;
    }
    let a = queries[2u * i].xyz;
    let b = queries[2u * i + 1u].xyz;
    switch params.query_mode {
        case 0u: {
            let l = finest_level(a);
            var object = 0xffffu;
            if l < params.levels_built {
                object = sdf_object(l, a);
            }
            queries[2u * i + 1u] = vec4<f32>(sdf_sample(a), f32(object), f32(l), 0.0);
        }
        case 1u: {
            let h = sdf_trace(a, b, 1e30, false, false);
            queries[2u * i] = vec4<f32>(h.t, select(0.0, 1.0, h.hit), f32(h.steps), f32(h.level));
        }
        default: {
            let h = trace_closest(a, b, 0.0, 1e30);
            queries[2u * i] = vec4<f32>(h.t, select(0.0, 1.0, h.tri != NO_HIT), 0.0, 0.0);
            if h.tri != NO_HIT {
                let g = tri_geom[h.tri];
                queries[2u * i + 1u] = vec4<f32>(normalize(cross(g.edge_b.xyz, g.edge_c.xyz)), 0.0);
            }
        }
    }
}
