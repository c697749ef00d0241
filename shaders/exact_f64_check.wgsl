// The exact f64 operations (shared/exact_f64.wgsl) applied to test cases, for comparison with
// the CPU's (src/gpu/exact_f64.rs, `F64Op::cpu`). One invocation per case. Shared files and
// bindings: src/gpu/shaders.rs.

// Per case, 5 words: the operation (`F64Op` as u32), a's bits (low, high), b's bits.
@group(0) @binding(0) var<storage, read> cases: array<u32>;
// Per case, 3 words: the result's bits (low, high; an f32, an i32 or a bool in the low word)
// and the status (1 where the arithmetic left the finite values).
@group(0) @binding(1) var<storage, read_write> results: array<u32>;

fn apply(op: u32, a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    switch op {
        case 0u: {
            return f64_add(a, b);
        }
        case 1u: {
            return f64_sub(a, b);
        }
        case 2u: {
            return f64_mul(a, b);
        }
        case 3u: {
            return f64_div(a, b);
        }
        case 4u: {
            return vec2<u32>(f64_to_f32(a), 0u);
        }
        case 5u: {
            return f64_from_f32(a.x);
        }
        case 6u: {
            return vec2<u32>(bitcast<u32>(f64_floor_i32(a)), 0u);
        }
        case 7u: {
            return vec2<u32>(select(0u, 1u, f64_less(a, b)), 0u);
        }
        case 8u: {
            return f64_from_i32(bitcast<i32>(a.x));
        }
        default: {
            return f64_sqrt(a);
        }
    }
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) num_wg: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = flat_index(wg, num_wg, local);
    if (i >= arrayLength(&cases) / 5u) {
        return;
    }
    let at = i * 5u;
    let r = apply(
        cases[at],
        vec2<u32>(cases[at + 1u], cases[at + 2u]),
        vec2<u32>(cases[at + 3u], cases[at + 4u]),
    );
    results[i * 3u] = r.x;
    results[i * 3u + 1u] = r.y;
    results[i * 3u + 2u] = f64_status;
}
