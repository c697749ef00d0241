//! wgpu's error scopes around a group of calls, so that a failure is an error, not a panic.

use crate::{Error, Result};

/// Validation and out-of-memory error scopes around a group of wgpu calls, so that a failure
/// becomes an [`Error::Gpu`] instead of wgpu's default panic.
pub(crate) struct ErrorScopes {
    // Declared innermost first: dropped without `pop` (an early return), fields drop in this
    // order, which pops the scopes in reverse order of pushing, as wgpu requires.
    validation: wgpu::ErrorScopeGuard,
    oom: wgpu::ErrorScopeGuard,
}

impl ErrorScopes {
    pub(crate) fn push(device: &wgpu::Device) -> Self {
        let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        ErrorScopes { oom, validation }
    }

    /// Pops both scopes; `doing` names the work in the error message.
    pub(crate) fn pop(self, doing: &str) -> Result<()> {
        let validation = pollster::block_on(self.validation.pop());
        let oom = pollster::block_on(self.oom.pop());
        if let Some(e) = validation.or(oom) {
            return Err(Error::Gpu(format!("{doing}: {e}")));
        }
        Ok(())
    }
}
