//! How llvmpipe's loop cap counts (what crates/gpu/src/loop_cap.rs states), held as a test so
//! a Mesa that counts otherwise is noticed; and [`LoopGuard`] raising its flag exactly when a
//! SIMD group's budget ran out. On a hardware adapter only the guard's silence is checked.

use nimbus_gpu::{storage_entry, test_context, GpuContext, GpuError, LoopGuard};

const PROBE: &str = r#"
@group(0) @binding(0) var<storage, read> n: array<u32>;
@group(0) @binding(1) var<storage, read_write> out: array<u32>;

// E1: one loop of n[0] iterations.
@compute @workgroup_size(64)
fn single(@builtin(local_invocation_index) lid: u32) {
    var c = 0u;
    for (var i = 0u; i < n[0]; i = i + 1u) { c = c + 1u; }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = c;
    out[lid * 4u + 3u] = s;
}

// E2: nested n[1] x n[2].
@compute @workgroup_size(64)
fn nested(@builtin(local_invocation_index) lid: u32) {
    var c = 0u;
    var o = 0u;
    for (var i = 0u; i < n[1]; i = i + 1u) {
        o = o + 1u;
        for (var j = 0u; j < n[2]; j = j + 1u) { c = c + 1u; }
    }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = c;
    out[lid * 4u + 1u] = o;
    out[lid * 4u + 3u] = s;
}

// E3: sequential loops of n[3] and n[4].
@compute @workgroup_size(64)
fn sequential(@builtin(local_invocation_index) lid: u32) {
    var a = 0u;
    for (var i = 0u; i < n[3]; i = i + 1u) { a = a + 1u; }
    var b = 0u;
    for (var i = 0u; i < n[4]; i = i + 1u) { b = b + 1u; }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = a;
    out[lid * 4u + 1u] = b;
    out[lid * 4u + 3u] = s;
}

// E4: divergence. Lane 0 runs loop 1 for n[5]; lane n[6] runs loop 2 for n[5]; others nothing.
@compute @workgroup_size(64)
fn divergent(@builtin(local_invocation_index) lid: u32) {
    var m1 = 0u;
    var m2 = 0u;
    if (lid == 0u) { m1 = n[5]; }
    if (lid == n[6]) { m2 = n[5]; }
    var a = 0u;
    for (var i = 0u; i < m1; i = i + 1u) { a = a + 1u; }
    var b = 0u;
    for (var i = 0u; i < m2; i = i + 1u) { b = b + 1u; }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = a;
    out[lid * 4u + 1u] = b;
    out[lid * 4u + 3u] = s;
}

// E5: a constant 8-trip loop inside a loop of n[7].
@compute @workgroup_size(64)
fn constant_inner(@builtin(local_invocation_index) lid: u32) {
    var c = 0u;
    var o = 0u;
    for (var i = 0u; i < n[7]; i = i + 1u) {
        o = o + 1u;
        for (var j = 0u; j < 8u; j = j + 1u) { c = c + (j ^ lid) % 3u + 1u; }
    }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = c;
    out[lid * 4u + 1u] = o;
    out[lid * 4u + 3u] = s;
}

// E6: loop in a function called from a loop of n[7], loop { break } form, trip n[8].
fn inner(k: u32) -> u32 {
    var c = 0u;
    var j = 0u;
    loop {
        if (j >= k) { break; }
        c = c + 1u;
        j = j + 1u;
    }
    return c;
}
@compute @workgroup_size(64)
fn calls(@builtin(local_invocation_index) lid: u32) {
    var c = 0u;
    var o = 0u;
    for (var i = 0u; i < n[7]; i = i + 1u) {
        o = o + 1u;
        c = c + inner(n[8]);
    }
    var s = 0u;
    for (var i = 0u; i < n[9]; i = i + 1u) { s = s + 1u; }
    out[lid * 4u] = c;
    out[lid * 4u + 1u] = o;
    out[lid * 4u + 3u] = s;
}


// The guard: lane 0 loops n[0] times, lane n[6] n[4] times in a later loop.
@compute @workgroup_size(64)
fn guarded(@builtin(local_invocation_index) lid: u32) {
    var m1 = 0u;
    var m2 = 0u;
    if (lid == 0u) { m1 = n[0]; }
    if (lid == n[6]) { m2 = n[4]; }
    var a = 0u;
    for (var i = 0u; i < m1; i = i + 1u) { a = a + 1u; }
    var b = 0u;
    for (var i = 0u; i < m2; i = i + 1u) { b = b + 1u; }
    out[lid * 4u] = a;
    out[lid * 4u + 1u] = b;
    loop_guard_check();
}
"#;

/// Runs `entry` over one workgroup of 64 with `n`; (what each lane wrote, the guard's verdict).
fn run(ctx: &GpuContext, entry: &str, n: [u32; 10]) -> (Vec<[u32; 4]>, Result<(), GpuError>) {
    let guard = LoopGuard::new(ctx, 2).unwrap();
    let layout = ctx.bind_group_layout("probe", &[storage_entry(0, true), storage_entry(1, false), guard.layout_entry()]).unwrap();
    let source = format!("{}\n{PROBE}", guard.wgsl(0));
    let pipeline = ctx.compute_pipeline(entry, &source, entry, &[&layout]).unwrap();
    let nb = ctx.storage_buffer("n", &n).unwrap();
    let out = ctx.storage_buffer_zeroed("out", 64 * 16).unwrap();
    let entries = [
        nimbus_gpu::wgpu::BindGroupEntry { binding: 0, resource: nb.as_entire_binding() },
        nimbus_gpu::wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() },
        guard.bind_group_entry(),
    ];
    let group = ctx.bind_group("probe", &layout, &entries).unwrap();
    ctx.dispatch(entry, &pipeline, &[&group], [1, 1, 1]).unwrap();
    let v: Vec<u32> = ctx.read_buffer(&out).unwrap();
    (v.chunks(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(), guard.check(ctx, "the probe", ""))
}

/// Lane results of `entry`; slot 3 is what a closing loop of n[9] = 2 passes got.
fn lanes(ctx: &GpuContext, entry: &str, set: &[(usize, u32)]) -> Vec<[u32; 4]> {
    let mut n = [0u32; 10];
    n[9] = 2;
    for &(i, v) in set {
        n[i] = v;
    }
    run(ctx, entry, n).0
}

#[test]
fn llvmpipe_counts_loop_iterations_per_simd_group() {
    let Some(ctx) = test_context() else { return };
    if ctx.loop_cap().is_none() {
        return;
    }
    // One loop: cut at 65535 passes; a later loop then gets one pass only.
    assert_eq!(lanes(ctx, "single", &[(0, 100_000)])[0], [65_535, 0, 0, 1]);
    assert_eq!(lanes(ctx, "single", &[(0, 65_532)])[0], [65_532, 0, 0, 2]);
    // Nested: inner and outer passes and each inner loop's exit test share the budget.
    assert_eq!(lanes(ctx, "nested", &[(1, 1000), (2, 100)])[0], [64_251, 643, 0, 1]);
    assert_eq!(lanes(ctx, "nested", &[(1, 600), (2, 100)])[0], [60_000, 600, 0, 2]);
    // One after another: the second loop gets what the first left.
    assert_eq!(lanes(ctx, "sequential", &[(3, 40_000), (4, 40_000)])[0], [40_000, 25_534, 0, 1]);
    // Lanes 0-7 share one budget, lanes 8 on have their own.
    for (other, second) in [(1usize, 25_534), (7, 25_534), (8, 40_000), (63, 40_000)] {
        let r = lanes(ctx, "divergent", &[(5, 40_000), (6, other as u32)]);
        assert_eq!((r[0][0], r[other][1]), (40_000, second), "lane 0 then lane {other}");
    }
    // A constant 8-pass loop is unrolled: 10,000 x 8 passes cost only the outer 10,000.
    assert_eq!(lanes(ctx, "constant_inner", &[(7, 10_000)])[0][1], 10_000);
    // A function's loop counts like any other.
    assert_eq!(lanes(ctx, "calls", &[(7, 10_000), (8, 5)])[0][3], 1);
}

#[test]
fn the_guard_flags_exactly_the_groups_that_ran_out() {
    let Some(ctx) = test_context() else { return };
    let guarded = |first: u32, lane: u32, second: u32| {
        let mut n = [0u32; 10];
        (n[0], n[6], n[4]) = (first, lane, second);
        run(ctx, "guarded", n)
    };
    // Within the budget: whole, no flag.
    let (r, verdict) = guarded(30_000, 1, 30_000);
    assert_eq!((r[0][0], r[1][1]), (30_000, 30_000));
    verdict.unwrap();
    // Two lanes of different groups, 40,000 each: whole, no flag.
    let (r, verdict) = guarded(40_000, 8, 40_000);
    assert_eq!((r[0][0], r[8][1]), (40_000, 40_000));
    verdict.unwrap();
    // Two lanes of one group, 40,000 each: neither alone nears the cap, together they pass
    // it; a software adapter cuts lane 1 short and must say so.
    let (r, verdict) = guarded(40_000, 1, 40_000);
    match ctx.loop_cap() {
        Some(_) => {
            assert!(r[1][1] < 40_000, "lane 1 ran whole: {:?}", r[1]);
            let e = verdict.expect_err("flagged").to_string();
            assert!(e.contains("65535") && e.contains("--device cpu"), "{e}");
        }
        None => {
            assert_eq!(r[1][1], 40_000);
            verdict.unwrap();
        }
    }
    // One lane alone past the cap.
    let (_, verdict) = guarded(100_000, 1, 0);
    assert_eq!(verdict.is_err(), ctx.loop_cap().is_some());
}
