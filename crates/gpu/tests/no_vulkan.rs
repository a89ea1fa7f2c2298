//! A machine without any Vulkan driver: `gpu` is a clear error, `auto` the CPU backend, and
//! neither hangs. A binary of its own, since it hides the drivers from the Vulkan loader
//! through the environment before any instance exists.

use std::sync::mpsc;
use std::time::Duration;

use nimbus_gpu::{ComputeDevice, DeviceChoice, GpuError};

#[test]
fn without_drivers_gpu_fails_cleanly_and_auto_uses_the_cpu() {
    // Both the current and the deprecated loader variable; WGPU_BACKEND could re-enable GL.
    std::env::set_var("VK_DRIVER_FILES", "/nonexistent/nimbus-no-driver.json");
    std::env::set_var("VK_ICD_FILENAMES", "/nonexistent/nimbus-no-driver.json");
    std::env::remove_var("WGPU_BACKEND");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let gpu = DeviceChoice::Gpu.resolve().map(|d| d.to_string());
        let auto = DeviceChoice::Auto.resolve().map(|d| matches!(d, ComputeDevice::Cpu(_)));
        tx.send((gpu, auto)).unwrap();
    });
    let (gpu, auto) = rx.recv_timeout(Duration::from_secs(120)).expect("device resolution hung without drivers");
    match gpu {
        Err(e @ GpuError::NoAdapter { .. }) => eprintln!("gpu without drivers: {e}"),
        other => panic!("expected NoAdapter, got {other:?}"),
    }
    assert!(auto.unwrap(), "auto without drivers must pick the CPU backend");
}
