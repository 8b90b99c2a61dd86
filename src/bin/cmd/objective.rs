//! The `--objective` choice shared by `hood simulate` and `hood report`.

use clap::ValueEnum;
use hood::physics::Objective;

/// Which form of the physics objective scores the frames and the gap.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ObjectiveArg {
    /// EVALUATION.md: collision eps 1 mm at weight 1, which the converged optimum barely feels
    /// (it lets the garment sink into the body).
    Evaluation,
    /// The training form: collision eps 2 mm at the final training weight 5e5.
    Training,
}

impl ObjectiveArg {
    /// The objective itself.
    pub fn objective(self) -> Objective {
        match self {
            ObjectiveArg::Evaluation => Objective::evaluation(),
            ObjectiveArg::Training => Objective::training(5e5),
        }
    }

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ObjectiveArg::Evaluation => "evaluation",
            ObjectiveArg::Training => "training",
        }
    }
}
