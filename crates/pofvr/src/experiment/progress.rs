//! How an experiment tells its caller how far it is: stages of counted steps.

/// Receives an experiment's progress: a stage begins, steps of it are done, it ends.
/// Called from the experiment's thread, and from worker threads while POFs are built.
pub trait Progress: Sync {
    /// A stage of `len` steps begins (`len` 0 when not known yet).
    fn begin(&self, what: &str, len: u64);
    /// `done` of the stage's `len` steps are done (`len` may grow once it is known).
    fn set(&self, done: u64, len: u64);
    /// One more step of the stage is done.
    fn inc(&self);
    /// The stage has ended.
    fn end(&self);
}

/// Progress that nobody watches.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn begin(&self, _: &str, _: u64) {}
    fn set(&self, _: u64, _: u64) {}
    fn inc(&self) {}
    fn end(&self) {}
}
