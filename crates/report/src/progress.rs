//! How a report tells its caller about progress, without depending on a user interface:
//! the caller (the command line's progress bars, Python, a test) implements [`Progress`];
//! [`Silent`] shows nothing.

/// A counter of finished items, shown as the caller likes (a bar on a terminal).
pub trait Bar: Send + Sync {
    /// `done` of `total` items are finished.
    fn update(&self, done: u64, total: u64);
    /// The work is over: remove the bar.
    fn finish(&self);
}

/// What a report needs from its caller's user interface.
pub trait Progress: Sync {
    /// A counter labelled `what`.
    fn bar(&self, what: &str) -> Box<dyn Bar>;
    /// An indicator of work labelled `what` that reports no progress of its own (loading
    /// a scene); it disappears when the returned value is dropped.
    fn spinner(&self, what: &str) -> Box<dyn Send>;
    /// A warning (a missing scene skipped).
    fn warn(&self, msg: &str);
}

/// Shows nothing.
pub struct Silent;

impl Bar for Silent {
    fn update(&self, _: u64, _: u64) {}
    fn finish(&self) {}
}

impl Progress for Silent {
    fn bar(&self, _: &str) -> Box<dyn Bar> {
        Box::new(Silent)
    }
    fn spinner(&self, _: &str) -> Box<dyn Send> {
        Box::new(())
    }
    fn warn(&self, _: &str) {}
}
