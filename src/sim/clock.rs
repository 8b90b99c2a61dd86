//! The clock of the solver's time budget ([`StepMode::SolverBudget`](super::StepMode)): the
//! core has no clock of its own (it runs without `std`), so a step that must stop on time reads
//! one the caller provides ([`Sim::set_clock`](super::Sim::set_clock)); with `std`, a sim starts
//! with [`StdClock`].

/// A monotonic clock.
pub trait Clock: Send + Sync {
    /// Nanoseconds since an arbitrary origin fixed for the clock's life; never decreases.
    fn now_ns(&self) -> u64;
}

/// [`std::time::Instant`] as a [`Clock`] (feature `std`).
#[cfg(feature = "std")]
#[derive(Clone, Copy, Debug)]
pub struct StdClock {
    origin: std::time::Instant,
}

#[cfg(feature = "std")]
impl StdClock {
    /// A clock whose origin is now.
    pub fn new() -> StdClock {
        StdClock { origin: std::time::Instant::now() }
    }
}

#[cfg(feature = "std")]
impl Default for StdClock {
    fn default() -> Self {
        StdClock::new()
    }
}

#[cfg(feature = "std")]
impl Clock for StdClock {
    fn now_ns(&self) -> u64 {
        // u64 nanoseconds last 584 years.
        self.origin.elapsed().as_nanos() as u64
    }
}

/// The clock a new sim starts with: [`StdClock`] with `std`, none without.
pub(super) fn default_clock<'m>() -> Option<alloc::boxed::Box<dyn Clock + 'm>> {
    #[cfg(feature = "std")]
    {
        Some(alloc::boxed::Box::new(StdClock::new()))
    }
    #[cfg(not(feature = "std"))]
    {
        None
    }
}
