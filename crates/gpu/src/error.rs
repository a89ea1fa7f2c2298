use std::fmt;

/// Everything that can go wrong on the GPU side. wgpu reports most failures asynchronously
/// (and panics on the ones nobody catches); the helpers in this crate catch them in error
/// scopes and return them as values of this type instead.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("invalid device '{0}' (expected auto, cpu or gpu)")]
    ParseDevice(String),

    #[error(
        "no GPU adapter found (backends {backends}); install a Vulkan driver \
         (for a software one, Mesa lavapipe: apt-get install mesa-vulkan-drivers) or use --device cpu"
    )]
    NoAdapter { backends: String },

    #[error("cannot open a device on adapter '{adapter}': {source}")]
    RequestDevice {
        adapter: String,
        #[source]
        source: wgpu::RequestDeviceError,
    },

    #[error("GPU validation error in {context}: {message}")]
    Validation { context: String, message: String },

    #[error("GPU out of memory in {context}")]
    OutOfMemory { context: String },

    #[error("GPU internal error in {context}: {message}")]
    Internal { context: String, message: String },

    #[error("{what} needs {size} bytes, above the device limit {limit} ({limit_name})")]
    TooLarge { what: String, size: u64, limit: u64, limit_name: &'static str },

    /// Work the adapter would get wrong rather than fail at, refused before it runs.
    #[error("{0}")]
    BeyondAdapter(String),

    #[error("volume does not fit the GPU layout: {0}")]
    VolumeLayout(String),

    #[error("reading back {context} failed: {message}")]
    Readback { context: String, message: String },
}

impl GpuError {
    pub(crate) fn from_wgpu(context: &str, error: wgpu::Error) -> Self {
        let context = context.to_owned();
        match error {
            wgpu::Error::OutOfMemory { .. } => GpuError::OutOfMemory { context },
            wgpu::Error::Validation { description, .. } => GpuError::Validation { context, message: description },
            wgpu::Error::Internal { description, .. } => GpuError::Internal { context, message: description },
        }
    }

    pub(crate) fn readback(context: &str, message: impl fmt::Display) -> Self {
        GpuError::Readback { context: context.to_owned(), message: message.to_string() }
    }
}
