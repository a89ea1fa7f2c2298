//! How much one dispatch of a kernel with long loops (a voxel's paths, a pixel's samples)
//! takes, by the adapter: one rule for every stage (design.md section 1).
//!
//! A hardware adapter has no loop cap, so a dispatch is sized to keep the GPU busy: enough
//! invocations to fill it several times over, and as many repetitions (paths, samples) each
//! as keep one submission to tens of milliseconds. A software adapter (llvmpipe) ends loops
//! silently past [`crate::SOFTWARE_LOOP_CAP`] iterations per SIMD group, so there the
//! repetitions per dispatch are as many as the stage's bound on its longest repetition allows
//! within the loop budget, as the march bounds its steps a priori; the [`crate::LoopGuard`]
//! still reports a dispatch that ran out.
//!
//! `NIMBUS_GPU_DISPATCH=hardware|software` overrides the adapter's class for these sizes
//! alone (the loop guard stays the adapter's): tests run the hardware sizes on lavapipe.

use std::fmt;
use std::str::FromStr;

use crate::GpuError;

/// What one dispatch of a long-loop kernel may hold on an adapter; see the module documentation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DispatchSizing {
    /// Most invocations (voxels, pixels) one dispatch covers.
    pub items: u64,
    /// Most invocation-repetitions (paths, samples summed over the invocations) one
    /// dispatch runs: on hardware, what keeps a submission to tens of milliseconds.
    pub work: u64,
    /// Most repetitions one invocation runs per dispatch, whatever the budget.
    pub max_repeats: u32,
    /// Loop iterations a repetition budget is cut to ([`crate::SOFTWARE_LOOP_CAP`] less a
    /// margin) on an adapter with a loop cap; `None` on hardware.
    pub loop_budget: Option<u64>,
}

impl DispatchSizing {
    /// A hardware GPU: a million invocations is several waves even on the largest GPUs
    /// (an H100 holds about 270k threads at once); 2^24 paths of a few tens of tracking
    /// steps each is of the order of 10-100 ms there (an estimate: no hardware adapter has
    /// run these kernels yet, issue #49).
    pub const HARDWARE: DispatchSizing = DispatchSizing { items: 1 << 20, work: 1 << 24, max_repeats: 256, loop_budget: None };

    /// A software adapter: 32k invocations keep lavapipe's threads busy, and a chunk whose
    /// voxels are all done is skipped (a pass runs to the largest count, which one voxel can set).
    pub const SOFTWARE: DispatchSizing =
        DispatchSizing { items: 1 << 15, work: u64::MAX, max_repeats: 256, loop_budget: Some(crate::loop_cap::SOFTWARE_LOOP_BUDGET) };

    /// The sizes of an adapter of `device_type`.
    pub fn for_device_type(device_type: wgpu::DeviceType) -> Self {
        if crate::is_hardware(device_type) {
            Self::HARDWARE
        } else {
            Self::SOFTWARE
        }
    }

    /// Repetitions per invocation per dispatch over `items` invocations, when one repetition
    /// takes up to `longest` loop iterations (ignored on hardware): at least one.
    pub fn repeats(&self, items: u64, longest: u64) -> u32 {
        let by_work = self.work / items.max(1);
        let by_loop = self.loop_budget.map_or(u64::MAX, |budget| budget / longest.max(1));
        by_work.min(by_loop).clamp(1, u64::from(self.max_repeats)) as u32
    }
}

/// `NIMBUS_GPU_DISPATCH`: which adapter class's [`DispatchSizing`] to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DispatchClass {
    Hardware,
    Software,
}

impl DispatchClass {
    /// The environment variable that overrides the adapter's class for dispatch sizes.
    pub const ENV: &'static str = "NIMBUS_GPU_DISPATCH";

    pub fn sizing(self) -> DispatchSizing {
        match self {
            DispatchClass::Hardware => DispatchSizing::HARDWARE,
            DispatchClass::Software => DispatchSizing::SOFTWARE,
        }
    }

    /// The class [`Self::ENV`] names, if set; an error for any other value.
    pub fn from_env() -> Result<Option<Self>, GpuError> {
        match std::env::var(Self::ENV) {
            Ok(v) if !v.is_empty() => v.parse().map(Some),
            _ => Ok(None),
        }
    }
}

impl FromStr for DispatchClass {
    type Err = GpuError;

    fn from_str(s: &str) -> Result<Self, GpuError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "hardware" => Ok(DispatchClass::Hardware),
            "software" => Ok(DispatchClass::Software),
            _ => Err(GpuError::Validation {
                context: DispatchClass::ENV.into(),
                message: format!("{s:?} is neither hardware nor software"),
            }),
        }
    }
}

impl fmt::Display for DispatchSizing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} invocations", self.items)?;
        match self.loop_budget {
            Some(b) => write!(f, ", repetitions within {b} loop iterations"),
            None => write!(f, ", {} repetitions", self.work),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hardware_fills_the_work_and_software_the_loop_budget() {
        let hw = DispatchSizing::HARDWARE;
        assert_eq!(hw.repeats(1 << 20, 1_000_000), 16, "hardware ignores the loop bound");
        assert_eq!(hw.repeats(1000, 1), 256, "at most max_repeats");
        let sw = DispatchSizing::SOFTWARE;
        assert_eq!(sw.repeats(1 << 15, 1000), 50);
        assert_eq!(sw.repeats(1 << 15, 10_000_000), 1, "at least one");
        assert_eq!(DispatchSizing::for_device_type(wgpu::DeviceType::Cpu), sw);
        assert_eq!(DispatchSizing::for_device_type(wgpu::DeviceType::DiscreteGpu), hw);
        assert_eq!("Hardware".parse::<DispatchClass>().unwrap(), DispatchClass::Hardware);
        assert!("fast".parse::<DispatchClass>().is_err());
    }
}
