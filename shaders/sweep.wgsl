// Conservative sweep (paper section 4) as a compute shader: one invocation per posed triangle
// renders the triangle's δ-offset into the three axis images by exact ray casts, folding hits in
// with atomic min/max. CPU twin: src/sweep/cpu.rs (`splat`, `pose_triangle`) and
// src/sweep/offset.rs (`PreparedTriangle`, `encode`). Keep them in step, formula for formula.
//
// Units: grid units (1 = one voxel edge) from the grid's min corner. Pixel (col, row) of the
// image of axis a is the ray through (col + 1/2, height - 1 - row + 1/2) in the image plane
// (columns along COLUMN_AXIS[a], rows along ROW_AXIS[a]); each pixel holds two u32 slots,
// encode(D-) and encode(D+).

// Must match `GpuParams` in src/sweep/gpu.rs.
struct Params {
    tri_start: u32,   // first triangle of this dispatch
    tri_count: u32,   // triangles in this dispatch (global_id.x)
    pose_start: u32,  // first pose of this dispatch
    pose_count: u32,  // poses in this dispatch (global_id.y)
    dim_x: u32,
    dim_y: u32,
    dim_z: u32,
    radius: f32,      // δ + rounding term, grid units
    flags: u32,       // bit 0: also set the reach (x axis only; see reach_bits)
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Triangles: 9 floats each, three vertices in the part's local frame.
@group(0) @binding(1) var<storage, read> triangles: array<f32>;
// Poses: 12 floats each, a row-major 3x4 matrix from the local frame to grid units.
@group(0) @binding(2) var<storage, read> poses: array<f32>;
@group(0) @binding(3) var<storage, read_write> image_x: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> image_y: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> image_z: array<atomic<u32>>;

// The reach (src/sweep/reach.rs, cpu.rs `set_centres`): one bit per voxel, set where the voxel's
// centre lies in the offset of a posed triangle, from the x axis's ray casts (columns along z,
// rows along y: each pixel's ray is a row of voxel centres). Row (y, z) of voxels along x starts
// at u32 word (z * dim_y + y) * words with words = 2 * ceil(dim_x / 64); voxel x is bit x % 32
// of word x / 32 (the CPU's u64 words, little-endian). Written only when params.flags bit 0 is
// set; otherwise a one-word placeholder is bound.
@group(0) @binding(6) var<storage, read_write> reach_bits: array<atomic<u32>>;

// Set bits lo..=hi (0 <= lo <= hi < dim_x) of the row starting at word `base`.
fn set_span(base: u32, lo: u32, hi: u32) {
    for (var w = lo / 32u; w <= hi / 32u; w++) {
        var first = 0u;
        if w == lo / 32u {
            first = lo % 32u;
        }
        var last = 31u;
        if w == hi / 32u {
            last = hi % 32u;
        }
        let mask = (0xffffffffu >> (31u - last)) & (0xffffffffu << first);
        // A plain load first: most spans are already set by a neighbouring triangle.
        if (atomicLoad(&reach_bits[base + w]) & mask) != mask {
            atomicOr(&reach_bits[base + w], mask);
        }
    }
}

// cpu.rs `set_centres`: the voxels of row (j, k) along x whose centres i + 1/2 lie in [t0, t1];
// ceil/floor of t - 1/2 are exact in f32 below 2^22 voxels.
fn set_centres(j: u32, k: u32, t0: f32, t1: f32) {
    let lo = max(ceil(t0 - 0.5), 0.0);
    let hi = min(floor(t1 - 0.5), f32(params.dim_x) - 1.0);
    if lo <= hi {
        let words = 2u * ((params.dim_x + 63u) / 64u);
        set_span((k * params.dim_y + j) * words, u32(lo), u32(hi));
    }
}

// Same constant as MIN_PROJECTED_EDGE2 in offset.rs.
const MIN_PROJECTED_EDGE2: f32 = 1e-20;
// Stands in for +inf as the empty interval's start (WGSL has no infinity literal).
const BIG: f32 = 3.0e38;

// Order-preserving f32 -> u32 (offset.rs `encode`).
fn encode_depth(x: f32) -> u32 {
    let b = bitcast<u32>(x);
    if (b & 0x80000000u) != 0u {
        return ~b;
    }
    return b | 0x80000000u;
}

// offset.rs `PreparedTriangle`: one posed triangle seen along one axis, with everything that does
// not depend on the pixel computed once. Vertices are (u, v, a) in grid units.
struct Prepared {
    d2: f32,
    q0: vec3<f32>,
    q1: vec3<f32>,
    q2: vec3<f32>,
    // Edge k runs from q_k to q_(k+1)%3.
    e0: vec3<f32>,
    e1: vec3<f32>,
    e2: vec3<f32>,
    // 1/|e_uv|^2 per edge, 0 for an edge (nearly) parallel to the ray.
    inv_e_uv2: vec3<f32>,
    // e_a / (|e| |e_uv|) per edge.
    shift_scale: vec3<f32>,
    caps: bool,
    // Entry foot d*sign(n_a)*n_uv/|n|; the exit foot is its negative.
    foot: vec2<f32>,
    inv_na: f32,
    cap_shift: f32,
}

// offset.rs `diff_of_products`: a*b - c*d with about one rounding (Kahan, fused multiply-adds).
// Assumes fma() is fused, as on the GPUs tested; the GPU-vs-CPU test on thin triangles checks it.
fn diff_of_products(a: f32, b: f32, c: f32, d: f32) -> f32 {
    let w = c * d;
    let e = fma(-c, d, w);
    let f = fma(a, b, -w);
    return f + e;
}

fn prepare(q0: vec3<f32>, q1: vec3<f32>, q2: vec3<f32>, d: f32) -> Prepared {
    var t: Prepared;
    t.d2 = d * d;
    t.q0 = q0;
    t.q1 = q1;
    t.q2 = q2;
    t.e0 = q1 - q0;
    t.e1 = q2 - q1;
    t.e2 = q0 - q2;
    var edges = array<vec3<f32>, 3>(t.e0, t.e1, t.e2);
    for (var k = 0u; k < 3u; k++) {
        let e = edges[k];
        let e_uv2 = e.x * e.x + e.y * e.y;
        if e_uv2 > MIN_PROJECTED_EDGE2 {
            t.inv_e_uv2[k] = 1.0 / e_uv2;
            let e_len = sqrt(e_uv2 + e.z * e.z);
            t.shift_scale[k] = e.z / (e_len * sqrt(e_uv2));
        }
    }
    let e1 = t.e0;
    let e2 = q2 - q0;
    let n = vec3<f32>(
        diff_of_products(e1.y, e2.z, e1.z, e2.y),
        diff_of_products(e1.z, e2.x, e1.x, e2.z),
        diff_of_products(e1.x, e2.y, e1.y, e2.x),
    );
    let n_len = sqrt(n.x * n.x + n.y * n.y + n.z * n.z);
    t.caps = n_len > 0.0 && n.z != 0.0;
    if t.caps {
        let scale = d * sign(n.z) / n_len;
        t.foot = vec2<f32>(scale * n.x, scale * n.y);
        t.inv_na = 1.0 / n.z;
        t.cap_shift = d * (abs(n.z) / n_len);
    }
    return t;
}

// offset.rs `PreparedTriangle::interval_at`: the ray through (pu, pv) against the offset.
// Returns (t0, t1); empty when t0 > t1.
fn interval_at(t: Prepared, pu: f32, pv: f32) -> vec2<f32> {
    let d2 = t.d2;
    var t0 = BIG;
    var t1 = -BIG;
    var q = array<vec3<f32>, 3>(t.q0, t.q1, t.q2);
    var edges = array<vec3<f32>, 3>(t.e0, t.e1, t.e2);
    let p = vec2<f32>(pu, pv);

    // Vertex balls.
    for (var k = 0u; k < 3u; k++) {
        let r = q[k].xy - p;
        let r2 = r.x * r.x + r.y * r.y;
        if r2 <= d2 {
            let s = sqrt(d2 - r2);
            t0 = min(t0, q[k].z - s);
            t1 = max(t1, q[k].z + s);
        }
    }

    // Edge cylinders, evaluated at the clamped optimal edge parameter.
    for (var k = 0u; k < 3u; k++) {
        let inv = t.inv_e_uv2[k];
        if inv == 0.0 {
            continue;
        }
        let a = q[k].xy - p;
        let e = edges[k];
        let c = a.x * e.y - a.y * e.x;
        let m2 = c * c * inv;
        if m2 >= d2 {
            continue;
        }
        let shift = sqrt(d2 - m2) * t.shift_scale[k];
        let s_star = -(a.x * e.x + a.y * e.y) * inv;
        for (var side = 0u; side < 2u; side++) {
            var s_opt = s_star - shift;
            var sgn = -1.0;
            if side == 1u {
                s_opt = s_star + shift;
                sgn = 1.0;
            }
            // An unclamped optimum is taken even if rounding pushed rho2 past d2 (offset.rs).
            let unclamped = s_opt >= 0.0 && s_opt <= 1.0;
            let s = clamp(s_opt, 0.0, 1.0);
            let cu = a.x + s * e.x;
            let cv = a.y + s * e.y;
            let rho2 = cu * cu + cv * cv;
            if unclamped || rho2 <= d2 {
                let depth = q[k].z + s * e.z + sgn * sqrt(max(d2 - rho2, 0.0));
                t0 = min(t0, depth);
                t1 = max(t1, depth);
            }
        }
    }

    // Prism caps: the foot of the cap point on the triangle, by barycentrics.
    if t.caps {
        let e1 = t.e0;
        let e2 = -t.e2;
        let a0 = t.q0.xy - p;
        for (var side = 0u; side < 2u; side++) {
            var sd = 1.0;
            var dir = -1.0;
            if side == 1u {
                sd = -1.0;
                dir = 1.0;
            }
            let g = vec2<f32>(sd * t.foot.x - a0.x, sd * t.foot.y - a0.y);
            let b1 = diff_of_products(g.x, e2.y, g.y, e2.x) * t.inv_na;
            let b2 = diff_of_products(e1.x, g.y, e1.y, g.x) * t.inv_na;
            if b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 {
                let y_a = t.q0.z + b1 * e1.z + b2 * e2.z;
                let depth = y_a + dir * t.cap_shift;
                t0 = min(t0, depth);
                t1 = max(t1, depth);
            }
        }
    }
    return vec2<f32>(t0, t1);
}

// cpu.rs `fold_min` / `fold_max`: skip the atomic read-modify-write when a load shows it cannot
// change the slot (slots only move outward, so a stale load errs toward doing it).
fn store(axis: u32, slot: u32, t0: f32, t1: f32) {
    let lo = encode_depth(t0);
    let hi = encode_depth(t1);
    if axis == 0u {
        if lo < atomicLoad(&image_x[slot]) { atomicMin(&image_x[slot], lo); }
        if hi > atomicLoad(&image_x[slot + 1u]) { atomicMax(&image_x[slot + 1u], hi); }
    } else if axis == 1u {
        if lo < atomicLoad(&image_y[slot]) { atomicMin(&image_y[slot], lo); }
        if hi > atomicLoad(&image_y[slot + 1u]) { atomicMax(&image_y[slot + 1u], hi); }
    } else {
        if lo < atomicLoad(&image_z[slot]) { atomicMin(&image_z[slot], lo); }
        if hi > atomicLoad(&image_z[slot + 1u]) { atomicMax(&image_z[slot + 1u], hi); }
    }
}

// cpu.rs `pixel_span`: pixels whose centres k + 1/2 lie in [lo - r, hi + r], clamped.
fn pixel_span(a: f32, b: f32, c: f32, r: f32, count: u32) -> vec2<i32> {
    let lo = max(ceil(min(min(a, b), c) - r - 0.5), 0.0);
    let hi = min(floor(max(max(a, b), c) + r - 0.5), f32(count) - 1.0);
    if lo > hi {
        return vec2<i32>(1, 0);
    }
    return vec2<i32>(i32(lo), i32(hi));
}

fn component(p: vec3<f32>, k: u32) -> f32 {
    if k == 0u {
        return p.x;
    } else if k == 1u {
        return p.y;
    }
    return p.z;
}

// cpu.rs `splat`: ray-cast the posed triangle against every pixel its offset can cover.
fn splat(p0: vec3<f32>, p1: vec3<f32>, p2: vec3<f32>, axis: u32) {
    // COLUMN_AXIS = [2, 0, 0], ROW_AXIS = [1, 2, 1] (depth.rs).
    var cu = 0u;
    var rv = 1u;
    if axis == 0u {
        cu = 2u;
        rv = 1u;
    } else if axis == 1u {
        cu = 0u;
        rv = 2u;
    }
    var dims = array<u32, 3>(params.dim_x, params.dim_y, params.dim_z);
    let width = dims[cu];
    let height = dims[rv];
    let r = params.radius;
    let cs = pixel_span(component(p0, cu), component(p1, cu), component(p2, cu), r, width);
    let rs = pixel_span(component(p0, rv), component(p1, rv), component(p2, rv), r, height);
    if cs.x > cs.y || rs.x > rs.y {
        return;
    }
    let tri = prepare(
        vec3<f32>(component(p0, cu), component(p0, rv), component(p0, axis)),
        vec3<f32>(component(p1, cu), component(p1, rv), component(p1, axis)),
        vec3<f32>(component(p2, cu), component(p2, rv), component(p2, axis)),
        r,
    );
    for (var row = rs.x; row <= rs.y; row++) {
        let pv = f32(row) + 0.5;
        for (var col = cs.x; col <= cs.y; col++) {
            let hit = interval_at(tri, f32(col) + 0.5, pv);
            if hit.x <= hit.y {
                let pixel = (height - 1u - u32(row)) * width + u32(col);
                store(axis, 2u * pixel, hit.x, hit.y);
                if axis == 0u && (params.flags & 1u) != 0u {
                    set_centres(u32(row), u32(col), hit.x, hit.y);
                }
            }
        }
    }
}

// cpu.rs `pose_triangle`: p = M·v, M row-major 3x4.
fn pose_point(m: u32, x: f32, y: f32, z: f32) -> vec3<f32> {
    var out: vec3<f32>;
    for (var r = 0u; r < 3u; r++) {
        let b = m + 4u * r;
        let c = poses[b] * x + poses[b + 1u] * y + poses[b + 2u] * z + poses[b + 3u];
        if r == 0u {
            out.x = c;
        } else if r == 1u {
            out.y = c;
        } else {
            out.z = c;
        }
    }
    return out;
}

@compute @workgroup_size(64, 1, 1)
fn sweep_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= params.tri_count || id.y >= params.pose_count {
        return;
    }
    let t = 9u * (params.tri_start + id.x);
    let m = 12u * (params.pose_start + id.y);
    let p0 = pose_point(m, triangles[t], triangles[t + 1u], triangles[t + 2u]);
    let p1 = pose_point(m, triangles[t + 3u], triangles[t + 4u], triangles[t + 5u]);
    let p2 = pose_point(m, triangles[t + 6u], triangles[t + 7u], triangles[t + 8u]);
    for (var axis = 0u; axis < 3u; axis++) {
        splat(p0, p1, p2, axis);
    }
}
