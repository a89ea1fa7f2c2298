//! `--device cpu` must work on machines where loading a GPU driver would fail or hang, so it
//! never creates a wgpu instance. A binary of its own: other tests create instances.

use nimbus_gpu::{wgpu_instances_created, ComputeDevice, CpuReason, DeviceChoice};

#[test]
fn cpu_choice_never_touches_wgpu() {
    let device = "cpu".parse::<DeviceChoice>().unwrap().resolve().unwrap();
    assert!(matches!(device, ComputeDevice::Cpu(CpuReason::Requested)));
    assert_eq!(device.to_string(), "cpu (requested)");
    assert_eq!(wgpu_instances_created(), 0);
}
