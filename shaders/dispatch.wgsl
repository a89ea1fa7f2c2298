// Shared by every stage shader, including those that read no volume (density.wgsl): plain
// functions, no bindings. Composed first (nimbus_gpu::DISPATCH_WGSL).

// Flat invocation index for a 1D workload dispatched as a 3D grid of workgroups
// (GpuContext::workgroups_1d splits counts above max_compute_workgroups_per_dimension).
// Callers must still test the result against their item count.
fn dispatch_linear_index(workgroup_id: vec3<u32>, num_workgroups: vec3<u32>, local_index: u32,
                         workgroup_size: u32) -> u32 {
    return ((workgroup_id.z * num_workgroups.y + workgroup_id.y) * num_workgroups.x + workgroup_id.x)
        * workgroup_size + local_index;
}
