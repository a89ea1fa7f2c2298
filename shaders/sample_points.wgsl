// requires: volume_sample_index_in, volume_sample_index_filtered_in
//
// Samples the default volume (group 0) at a list of index-space points: the GPU side of
// nimbus_gpu::PointSampler, used to hold the GPU sampler to the CPU one and to benchmark it.
// Composed after volume.wgsl.

const WORKGROUP_SIZE: u32 = 64u;

// Packed xyz triples: vec3 arrays would pad every point to 16 bytes.
@group(1) @binding(0) var<storage, read> points: array<f32>;
@group(1) @binding(1) var<storage, read_write> samples: array<vec4<f32>>;

fn point_at(i: u32) -> vec3<f32> {
    return vec3<f32>(points[3u * i], points[3u * i + 1u], points[3u * i + 2u]);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn sample_exact(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= arrayLength(&samples)) {
        return;
    }
    samples[i] = volume_sample_index_in(volume_atlas, volume_table, volume_info, point_at(i));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn sample_filtered(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= arrayLength(&samples)) {
        return;
    }
    samples[i] = volume_sample_index_filtered_in(volume_atlas, volume_table, volume_sampler,
                                                 volume_info, point_at(i));
}
