//! VDB input on arbitrary bytes, through the C++ bridge the way the tools read it: parse,
//! list the grids, read every float, vec3 and points grid and the metadata. An error at any
//! step is fine; a panic, an abort or a crash inside OpenVDB is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nimbus_vdb::{GridKind, VdbFile};

fuzz_target!(|data: &[u8]| {
    let Ok(file) = VdbFile::from_bytes(data, "fuzz") else { return };
    let _ = file.metadata();
    let Ok(grids) = file.grids() else { return };
    for info in grids {
        let _ = match info.kind {
            GridKind::Float => file.read_float(&info.name).map(|v| v.active_voxel_count()),
            GridKind::Vec3 => file.read_vec3(&info.name).map(|v| v.active_voxel_count()),
            GridKind::Points => file.read_points(&info.name).map(|p| p.len() as u64),
            _ => Ok(0),
        };
    }
});
