//! The FIFO record of MergeTree's reports: a FIFO's name, capacity and statistics at the
//! end of a run (and in deadlock messages). The FIFOs themselves are the simulation
//! kernel's [`crate::kernel::LatencyFifo`]s; this is the flat, serializable row the
//! `arbor.sim.mergetree.v1` document has always carried.

/// A snapshot of a FIFO's state and statistics (for reports and deadlock messages).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct FifoStats {
    /// The FIFO's name.
    pub name: &'static str,
    /// Its capacity.
    pub capacity: usize,
    /// Items held now.
    pub len: usize,
    /// Accepted pushes so far.
    pub pushes: u64,
    /// Pushes refused because the FIFO was full.
    pub refused_pushes: u64,
    /// Highest occupancy seen.
    pub peak: usize,
}

impl std::fmt::Display for FifoStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {}/{} (peak {}, {} pushes, {} refused)",
            self.name, self.len, self.capacity, self.peak, self.pushes, self.refused_pushes
        )
    }
}
