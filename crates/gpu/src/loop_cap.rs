//! Software adapters that end long loops silently, and the one guard every stage uses.
//!
//! llvmpipe (Mesa's software rasteriser, behind lavapipe) gives each SIMD group of
//! invocations a budget of 65535 loop iterations and, once it is spent, ends loops early
//! without any error. Measured on lavapipe (Mesa 22.3.6, LLVM 15, 256-bit vectors) with the
//! probe kernels in `crates/gpu/tests/loop_cap.rs`:
//! - one counter per SIMD group of 8 invocations (lanes 0-7 of a workgroup share it; lane 8
//!   and up are another group), set to 65535 at the start of the invocation, never reset;
//! - every loop of the invocation draws on it, nested or one after another, and so do calls'
//!   loops (functions are inlined): each pass around a loop costs one, and each time a loop is
//!   entered its exit test costs one more (1000 x 100 nested loops stopped at 643 x 101 + 643
//!   = 65,586 ~ 65535; loops of 40,000 then 40,000 ran 40,000 then 25,534);
//! - the lanes of a group add up: lane 0 looping 40,000 times and then lane 1 looping 40,000
//!   times in a later loop left lane 1 with 25,534, although neither lane alone came near the
//!   cap. A per-invocation count cannot see that, so a budget counted in the shader per
//!   invocation is either unsafe or eight times too strict;
//! - small loops with a constant trip count are unrolled and cost nothing;
//! - once spent, every later loop runs one pass and exits.
//!
//! Hence two guards, both here:
//! - a priori, where a bound on an invocation's iterations is cheap and tight (density's
//!   gathers, the march's steps): [`GpuContext::check_loop_bound`] before dispatch;
//! - a posteriori everywhere else (random walks: delta tracking, photon paths, shadow rays,
//!   photon searches): [`LoopGuard`]. At its end each invocation calls `loop_guard_check()`,
//!   a loop of two passes: where it gets only one, its group's budget ran out, some loop of
//!   the group may have been cut short, and it sets a flag the host reads back and turns into
//!   [`GpuError::BeyondAdapter`]. This reads the adapter's own counter, so it is exact (a
//!   false alarm only within two iterations of the cap) whatever the group width or the
//!   divergence. Hardware adapters compile the check out (`LOOP_GUARD` is false there).

use std::fmt;

use crate::context::buffer_entries;
use crate::{storage_entry, GpuContext, GpuError};

/// Loop iterations a software adapter (llvmpipe) runs per SIMD group before it silently ends
/// loops; see the module documentation.
pub const SOFTWARE_LOOP_CAP: u64 = 65_535;

/// What an a priori bound may reach: the cap less a margin for the loops it does not count
/// (the cell loops around density's particle loop, the DDA around a march step).
pub(crate) const SOFTWARE_LOOP_BUDGET: u64 = 50_000;

impl GpuContext {
    /// The loop iterations per SIMD group this adapter runs before it silently ends loops:
    /// [`SOFTWARE_LOOP_CAP`] on a software adapter, `None` on hardware.
    pub fn loop_cap(&self) -> Option<u64> {
        self.info.is_software.then_some(SOFTWARE_LOOP_CAP)
    }

    /// Refuses work whose invocations may take more than `iterations` loop iterations, when
    /// that is beyond what this adapter runs whole (with a margin: see [`Self::loop_cap`]).
    /// `work` says what takes them, `remedy` how to ask for fewer (appended after
    /// `--device cpu`, e.g. "or a longer --step"). Free on hardware.
    pub fn check_loop_bound(&self, iterations: u64, work: impl fmt::Display, remedy: &str) -> Result<(), GpuError> {
        match self.loop_cap() {
            Some(_) if iterations > SOFTWARE_LOOP_BUDGET => {
                Err(self.beyond_loop_cap(format_args!("{work} takes up to {iterations} loop iterations"), remedy))
            }
            _ => Ok(()),
        }
    }

    /// The one error for work the adapter would silently cut short: `work` ("a pixel's
    /// march ... takes up to N loop iterations", "... ran out of loop iterations"), then why,
    /// then `--device cpu` and `remedy`.
    pub fn beyond_loop_cap(&self, work: impl fmt::Display, remedy: &str) -> GpuError {
        let remedy = if remedy.is_empty() { String::new() } else { format!(" {remedy}") };
        GpuError::BeyondAdapter(format!(
            "{work}: a software Vulkan adapter runs at most {SOFTWARE_LOOP_CAP} loop iterations whole \
             (llvmpipe ends longer loops, nested ones included, without an error, and the result would be \
             silently wrong); use --device cpu{remedy}"
        ))
    }
}

/// The in-shader guard (see the module documentation): a flag buffer, the WGSL that declares
/// it with `fn loop_guard_check()`, and the read-back that turns a raised flag into an error.
///
/// Shader side: compose [`LoopGuard::wgsl`] before the stage shader and call
/// `loop_guard_check()` once at the end of every invocation that did any work, after every
/// loop and on every path (wrap a body with early returns in a function). Host side: add
/// [`LoopGuard::layout_entry`] to the layout and bind with [`LoopGuard::buffer_bind_group`]
/// (or [`LoopGuard::bind_group_entry`]), all at the binding the guard was made with, and call
/// [`LoopGuard::check`] after the dispatches (the flag is sticky).
#[derive(Debug)]
pub struct LoopGuard {
    /// Word 0: the flag. Word 1: always 0, read inside the check's loop so that no compiler
    /// can fold the loop away.
    buffer: wgpu::Buffer,
    enabled: bool,
    /// The flag's binding in its group, fixed here so the WGSL, the layout and the bind
    /// group cannot disagree.
    binding: u32,
}

impl LoopGuard {
    /// A guard whose flag sits at `binding` of the stage's bind group.
    pub fn new(ctx: &GpuContext, binding: u32) -> Result<Self, GpuError> {
        Ok(LoopGuard { buffer: ctx.storage_buffer("loop guard", &[0u32; 2])?, enabled: ctx.loop_cap().is_some(), binding })
    }

    /// Whether the shader checks at all (only on adapters with a loop cap).
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// WGSL declaring the flag at `@group(group)`, the guard's binding, and `loop_guard_check()`.
    pub fn wgsl(&self, group: u32) -> String {
        Self::wgsl_for(self.enabled, group, self.binding)
    }

    /// [`LoopGuard::wgsl`] of a guard made at `binding` on an adapter with (`enabled`) or
    /// without a loop cap: what a stage's shader source builds from, with no device needed.
    pub fn wgsl_for(enabled: bool, group: u32, binding: u32) -> String {
        format!(
            "const LOOP_GUARD: bool = {enabled};\n\
             @group({group}) @binding({binding}) var<storage, read_write> loop_guard: array<atomic<u32>, 2>;\n{LOOP_GUARD_WGSL}"
        )
    }

    pub fn layout_entry(&self) -> wgpu::BindGroupLayoutEntry {
        storage_entry(self.binding, false)
    }

    pub fn bind_group_entry(&self) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry { binding: self.binding, resource: self.buffer.as_entire_binding() }
    }

    /// [`GpuContext::buffer_bind_group`] over `buffers` with the flag after them: the guard's
    /// binding must be `buffers.len()`.
    pub fn buffer_bind_group(
        &self,
        ctx: &GpuContext,
        label: &str,
        layout: &wgpu::BindGroupLayout,
        buffers: &[&wgpu::Buffer],
    ) -> Result<wgpu::BindGroup, GpuError> {
        assert_eq!(buffers.len() as u32, self.binding, "the loop guard's binding follows the buffers");
        let mut entries = buffer_entries(buffers);
        entries.push(self.bind_group_entry());
        ctx.bind_group(label, layout, &entries)
    }

    /// Errors with [`GpuContext::beyond_loop_cap`] if any invocation since the guard was made
    /// ran out of loop iterations (`work` says what ran, `remedy` how to ask for less).
    /// Waits for the dispatches submitted so far; nothing to read where the guard is off.
    pub fn check(&self, ctx: &GpuContext, work: impl fmt::Display, remedy: &str) -> Result<(), GpuError> {
        if !self.enabled {
            return Ok(());
        }
        let flag: Vec<u32> = ctx.read_buffer(&self.buffer)?;
        if flag[0] != 0 {
            return Err(ctx.beyond_loop_cap(format_args!("{work} ran out of loop iterations"), remedy));
        }
        Ok(())
    }
}

/// `loop_guard_check()`: composed after the `LOOP_GUARD` constant and the `loop_guard`
/// binding that [`LoopGuard::wgsl`] declares.
const LOOP_GUARD_WGSL: &str = r#"
// A loop of two passes: a software adapter that has spent this SIMD group's loop budget
// (llvmpipe, see crates/gpu/src/loop_cap.rs) runs only one, and some loop of the group may
// have been cut short; raise the flag for the host. Compiled out where LOOP_GUARD is false.
fn loop_guard_check() {
    if (!LOOP_GUARD) {
        return;
    }
    var passes = 0u;
    loop {
        passes = passes + 1u + atomicLoad(&loop_guard[1]);
        if (passes >= 2u) {
            break;
        }
    }
    if (passes < 2u) {
        atomicStore(&loop_guard[0], 1u);
    }
}
"#;
