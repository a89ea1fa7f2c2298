//! nimbus: the tools' library. The five binaries in `tools/` keep their own wiring (the
//! command line's input and output, the stage run through nimbus-cli's runner, the write);
//! what a tool's stage needs besides lives here, one module a tool: its flags and their
//! conversion into the engine's parameters, the run with its summary and errors, what it
//! writes and records.

pub mod cache;
pub mod march;
pub mod photon;
pub mod particles;
pub mod render;
