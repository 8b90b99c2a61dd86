//! The clock of the solver's time budget ([`StepMode::SolverBudget`](super::StepMode)): the
//! core has no clock of its own (it runs without `std`), so a step that must stop on time reads
//! one the caller provides ([`Sim::set_clock`](super::Sim::set_clock)); with `std`, a sim starts
//! with `StdClock`.

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

/// How the last step of [`StepMode::SolverBudget`](super::StepMode) kept its time budget
/// ([`Sim::last_budget`](super::Sim::last_budget)). A budget too small for the step's set-up and
/// one iteration (a large garment, or a state whose first iteration is slow) cannot be met: at
/// least one iteration runs, and the step says so here and in
/// [`StepEffects::over_budget`](super::StepEffects::over_budget) rather than hiding it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BudgetUse {
    /// The budget of one step, ns.
    pub budget_ns: u64,
    /// Wall time of the step by the sim's clock, from its start to the end of its solve
    /// (the checks of the frame, the body's grids and the iterations), ns.
    pub used_ns: u64,
}

impl BudgetUse {
    /// Whether the step kept within its budget.
    pub fn met(&self) -> bool {
        self.used_ns <= self.budget_ns
    }
}

/// A time budget over the iterations of one solve that stops before an iteration it predicts
/// would end past the budget: an iteration starts only if the longest one so far still fits.
/// (Stopping once the budget has passed overshoots it by up to a whole iteration.)
pub(super) struct Deadline<'c> {
    clock: &'c dyn Clock,
    /// Clock reading at which the budget ends, ns.
    end: u64,
    /// Clock reading at the last check (or at the start), ns.
    last: u64,
    /// Longest iteration so far, ns.
    longest: u64,
    /// Whether no check has run yet.
    first: bool,
}

impl<'c> Deadline<'c> {
    /// A budget of `budget_ns` that began at the clock reading `start_ns` (the step's start:
    /// the work before the solve counts against it; `None`: now).
    pub(super) fn new(clock: &'c dyn Clock, start_ns: Option<u64>, budget_ns: u64) -> Deadline<'c> {
        let now = clock.now_ns();
        let end = start_ns.unwrap_or(now).saturating_add(budget_ns);
        Deadline { clock, end, last: now, longest: 0, first: true }
    }

    /// Whether to stop rather than start another iteration; asked after each one.
    pub(super) fn stop_before_next(&mut self) -> bool {
        let now = self.clock.now_ns();
        let took = now.saturating_sub(self.last);
        // The first interval also holds the work before the first iteration (the starting
        // evaluation, about one more iteration's worth): half of it is the iteration.
        let took = if self.first { took / 2 } else { took };
        self.first = false;
        self.last = now;
        self.longest = self.longest.max(took);
        now.saturating_add(self.longest) > self.end
    }
}

/// The clock a new sim starts with: `StdClock` with `std`, none without.
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
