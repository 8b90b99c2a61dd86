//! Figures over a validation split: many rollouts' [`Summary`]s reduced to the lines a model
//! card quotes, each over every rollout and over those that kept the garment on.
//!
//! A lost garment makes a rollout's penetration and gap look good (the cloth is nowhere near the
//! body), so the means are given over the kept rollouts too, and the count of kept rollouts leads.

use super::Summary;

/// The motion corpus's goal for a model alone: the largest edge strain `|l / L - 1|` of every
/// held-out rollout below this.
pub const STRAIN_GOAL: f64 = 1.5;

/// The motion corpus's goal for a model alone: the mean % of penetrating vertices over the
/// held-out rollouts below this.
pub const PENETRATING_GOAL_PERCENT: f64 = 2.0;

/// A mean over every rollout of a split and over those that kept the garment on.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AllAndKept {
    /// Over every rollout (`None` when no rollout has the figure).
    pub all: Option<f64>,
    /// Over the rollouts that kept the garment on (`None` when none did, or none has it).
    pub kept: Option<f64>,
}

/// Figures over a set of rollouts of one model (a validation split).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplitSummary {
    /// Rollouts.
    pub rollouts: usize,
    /// Rollouts that kept the garment on the body and stayed finite ([`Summary::garment_kept`]).
    pub kept: usize,
    /// Mean own-rollout relative gap (over the rollouts scored with one).
    pub gap: AllAndKept,
    /// Mean own-rollout absolute gap, J.
    pub gap_abs: AllAndKept,
    /// Mean of the rollouts' mean % of penetrating vertices.
    pub penetrating_percent: AllAndKept,
    /// Rollouts whose largest edge strain is above [`STRAIN_GOAL`].
    pub strained: usize,
    /// Kept rollouts whose largest edge strain is above [`STRAIN_GOAL`].
    pub strained_kept: usize,
    /// The largest edge strain of any kept rollout.
    pub max_kept_strain: Option<f64>,
}

impl SplitSummary {
    /// Reduces the rollouts' summaries.
    pub fn of<'a>(rollouts: impl IntoIterator<Item = &'a Summary>) -> Self {
        let mut s = Self::default();
        let (mut gap, mut gap_abs, mut penetrating) = (MeanPair::default(), MeanPair::default(), MeanPair::default());
        for r in rollouts {
            let kept = r.garment_kept();
            s.rollouts += 1;
            s.kept += usize::from(kept);
            let strained = r.max_edge_strain > STRAIN_GOAL;
            s.strained += usize::from(strained);
            gap.add(r.gap_mean, kept);
            gap_abs.add(r.gap_abs_mean, kept);
            penetrating.add(Some(r.mean_penetrating_percent), kept);
            if kept {
                s.strained_kept += usize::from(strained);
                s.max_kept_strain = Some(s.max_kept_strain.map_or(r.max_edge_strain, |m| m.max(r.max_edge_strain)));
            }
        }
        s.gap = gap.means();
        s.gap_abs = gap_abs.means();
        s.penetrating_percent = penetrating.means();
        s
    }

    /// Whether the split meets the motion corpus's goals for a model alone: every rollout kept,
    /// every largest strain at most [`STRAIN_GOAL`], mean penetration below
    /// [`PENETRATING_GOAL_PERCENT`].
    pub fn meets_goals(&self) -> bool {
        self.rollouts > 0
            && self.kept == self.rollouts
            && self.strained == 0
            && self.penetrating_percent.all.is_some_and(|p| p < PENETRATING_GOAL_PERCENT)
    }
}

/// Running means of the figures that are present, over every rollout and over the kept ones.
#[derive(Clone, Copy, Debug, Default)]
struct MeanPair {
    all: (f64, usize),
    kept: (f64, usize),
}

impl MeanPair {
    fn add(&mut self, x: Option<f64>, kept: bool) {
        if let Some(x) = x {
            self.all = (self.all.0 + x, self.all.1 + 1);
            if kept {
                self.kept = (self.kept.0 + x, self.kept.1 + 1);
            }
        }
    }

    fn means(&self) -> AllAndKept {
        let mean = |(sum, n): (f64, usize)| (n > 0).then(|| sum / n as f64);
        AllAndKept { all: mean(self.all), kept: mean(self.kept) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::Loss;

    fn rollout(kept: bool, gap: f64, abs: f64, pen: f64, strain: f64) -> Summary {
        Summary {
            finite: true,
            lost: (!kept).then_some((10, Loss::OffBody)),
            gap_mean: Some(gap),
            gap_abs_mean: Some(abs),
            mean_penetrating_percent: pen,
            max_edge_strain: strain,
            ..Summary::default()
        }
    }

    #[test]
    fn means_are_over_all_and_over_kept_rollouts() {
        let r =
            [rollout(true, 0.2, 1.0, 0.5, 1.2), rollout(false, 0.8, 40.0, 0.1, 9.0), rollout(true, 0.4, 3.0, 1.5, 2.0)];
        let s = SplitSummary::of(&r);
        assert_eq!((s.rollouts, s.kept), (3, 2));
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-12;
        assert!(close(s.gap.all, 1.4 / 3.0) && close(s.gap.kept, 0.3));
        assert!(close(s.gap_abs.all, 44.0 / 3.0) && close(s.gap_abs.kept, 2.0));
        // The lost rollout penetrates least: over the kept ones the mean is higher.
        assert!(close(s.penetrating_percent.all, 0.7) && close(s.penetrating_percent.kept, 1.0));
        assert_eq!((s.strained, s.strained_kept, s.max_kept_strain), (2, 1, Some(2.0)));
        assert!(!s.meets_goals());
    }

    #[test]
    fn goals_need_every_rollout_kept_unstrained_and_little_penetration() {
        let good = rollout(true, 0.3, 1.0, 0.5, 1.4);
        assert!(SplitSummary::of(&[good, good]).meets_goals());
        assert!(!SplitSummary::of(&[good, rollout(false, 0.3, 1.0, 0.5, 1.4)]).meets_goals());
        assert!(!SplitSummary::of(&[good, rollout(true, 0.3, 1.0, 0.5, 1.6)]).meets_goals());
        assert!(!SplitSummary::of(&[good, rollout(true, 0.3, 1.0, 4.0, 1.4)]).meets_goals());
        assert!(!SplitSummary::of(&[]).meets_goals());
        // A rollout scored without a gap leaves the gap means to the others.
        let ungapped = Summary { gap_mean: None, gap_abs_mean: None, ..good };
        assert_eq!(SplitSummary::of(&[good, ungapped]).gap.all, Some(0.3));
    }
}
