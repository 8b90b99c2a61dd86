//! Which of the step's optional effects acted on the last step, for engines that log, display or
//! react to them (a teleport to hide, a skipped step to skip the upload of).

use super::Sim;

/// What the last successful [`Sim::step`] did beyond a plain network step. A teleported or
/// sleeping step does nothing else; the other flags may combine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepEffects {
    /// The body jumped farther than [`SimConfig::teleport`](super::SimConfig::teleport): the
    /// garment was moved by the body's best-fit rigid motion instead of stepped.
    pub teleported: bool,
    /// Sleeping: body and garment were at rest, and the step was skipped.
    pub slept: bool,
    /// The start-up (relaxation) pass ran before the regular one.
    pub startup: bool,
    /// The speed limit carried the garment: the body's centroid moved farther than
    /// [`SimConfig::speed_limit`](super::SimConfig::speed_limit).
    pub carried: bool,
    /// A solver refinement ran ([`SimConfig::refine`](super::SimConfig::refine)), or the solve of
    /// a solver step mode.
    pub refined: bool,
    /// The collision projection moved at least one garment vertex.
    pub projected: bool,
}

impl Sim<'_> {
    /// What the last successful step did (all false before the first; a refused step leaves it).
    pub fn last_effects(&self) -> StepEffects {
        self.last_effects
    }
}
