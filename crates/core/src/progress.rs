//! Progress reporting from long stages. Libraries only report; the binary draws bars.

/// Receives progress from a stage.
pub trait Progress: Sync {
    /// A stage with `total` steps begins.
    fn stage(&self, name: &str, total: u64);
    /// `n` more steps are done.
    fn advance(&self, n: u64);
    /// The current stage is done.
    fn finish(&self);
}

/// Progress reporting that does nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
}
