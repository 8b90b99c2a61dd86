//! A rollout's aggregates: the [`Summary`] of its frames and its off-body verdict in words.

use super::{FrameRecord, Loss, LossWatch, OffBodyFrame, StepKind};
use crate::physics::Terms;
use alloc::vec::Vec;

/// Aggregates over a rollout's frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Summary {
    /// Frames recorded.
    pub frames: usize,
    /// Whether every step's output was finite (the runtime refuses non-finite output; the
    /// rollout stops at the first refusal).
    pub finite: bool,
    /// Mean of every term over the frames that have them.
    pub mean_terms: Terms<f64>,
    /// Mean of the total objective over the same frames.
    pub mean_total: f64,
    /// Mean % penetrating vertices.
    pub mean_penetrating_percent: f64,
    /// Largest % penetrating vertices.
    pub max_penetrating_percent: f64,
    /// Largest edge strain of any frame.
    pub max_edge_strain: f64,
    /// Largest strain of any frame over the edges at least a quarter of the median edge long
    /// ([`FrameRecord::max_long_edge_strain`](super::FrameRecord::max_long_edge_strain)).
    pub max_long_edge_strain: f64,
    /// Largest vertex speed of any frame but teleports (which are no motion), m/s.
    pub max_speed: f64,
    /// Mean relative gap over the frames where it was computed and defined.
    pub gap_mean: Option<f64>,
    /// 95th percentile (nearest rank) of the same.
    pub gap_p95: Option<f64>,
    /// Mean absolute gap `model - optimum` (J) over the same frames: unlike the relative gap it
    /// does not depend on the descent available at the rollout's own states (a calmer rollout
    /// has less, which raises its relative gap at an equal absolute one).
    pub gap_abs_mean: Option<f64>,
    /// The mean relative gap split by term ([`Gap::by_term`] averaged over the same frames; the
    /// parts sum to `gap_mean`).
    ///
    /// [`Gap::by_term`]: super::Gap::by_term
    pub gap_by_term: Option<Terms<f64>>,
    /// How many frames the gap figures average.
    pub gap_frames: usize,
    /// Mean % of vertices inside the body over the frames where it was counted.
    pub inside_mean: Option<f64>,
    /// Largest of the same.
    pub inside_max: Option<f64>,
    /// How many frames the inside figures cover.
    pub inside_frames: usize,
    /// Mean step time, ms.
    pub mean_step_ms: f64,
    /// Median step time, ms.
    pub median_step_ms: f64,
    /// Steps that took longer than the time budget of their step mode (0 without one).
    pub over_budget_frames: usize,
    /// Largest % of worn vertices off the body over the frames ([`OffBody`]; `None` without a
    /// body).
    ///
    /// [`OffBody`]: super::OffBody
    pub off_body_max: Option<f64>,
    /// Mean of the same.
    pub off_body_mean: Option<f64>,
    /// The first frame at which the garment was lost, and how ([`LossWatch`]: off the body, or
    /// ridden up): a failure whatever the other figures.
    pub lost: Option<(usize, Loss)>,
    /// Largest drift of a vertex from its skinned position over the frames, m (garments with
    /// pins).
    pub max_drift: Option<f64>,
    /// Largest shift of the worn vertices' centroid from its skinned position over the frames,
    /// m ([`OffBodyFrame::shift`]): a top riding up while it stays within 10 cm of the body.
    pub max_shift: Option<f64>,
}

impl Summary {
    /// Whether the garment stayed on the body (and the rollout finite): not lost at any frame
    /// ([`LossWatch`]).
    pub fn garment_kept(&self) -> bool {
        self.finite && self.lost.is_none()
    }

    /// The off-body verdict in words: `garment on the body (worn vertices off: max 0.4 %, mean
    /// 0.1 %; drift max 4.2 cm)` or `garment LOST from frame 140, off the body (...)`; `None` without a body.
    pub fn off_body_text(&self) -> Option<alloc::string::String> {
        let (max, mean) = (self.off_body_max?, self.off_body_mean?);
        let verdict = match self.lost {
            Some((f, why)) => alloc::format!("garment LOST from frame {f}, {}", why.describe()),
            None => "garment on the body".into(),
        };
        let mut drift =
            self.max_drift.map_or(alloc::string::String::new(), |d| alloc::format!("; drift max {:.1} cm", 100.0 * d));
        if let Some(d) = self.max_shift {
            drift.push_str(&alloc::format!("; shift max {:.1} cm", 100.0 * d));
        }
        Some(alloc::format!("{verdict} (worn vertices over 10 cm off: max {max:.1} %, mean {mean:.1} %{drift})"))
    }
}

pub(super) fn summarise(frames: &[FrameRecord], finite: bool) -> Summary {
    let mut s = Summary { frames: frames.len(), finite, ..Summary::default() };
    let scored: Vec<Terms<f64>> = frames.iter().filter_map(|f| f.terms).collect();
    s.mean_terms = mean_terms(&scored);
    s.mean_total = scored.iter().map(|t| t.total() / scored.len() as f64).sum();
    let nf = frames.len().max(1) as f64;
    for f in frames {
        s.mean_penetrating_percent += f.penetrating_percent / nf;
        s.max_penetrating_percent = s.max_penetrating_percent.max(f.penetrating_percent);
        s.max_edge_strain = s.max_edge_strain.max(f.max_edge_strain);
        s.max_long_edge_strain = s.max_long_edge_strain.max(f.max_long_edge_strain);
        if f.kind != StepKind::Teleported {
            s.max_speed = s.max_speed.max(f.max_speed);
        }
        s.mean_step_ms += f.step_ms / nf;
        s.over_budget_frames += usize::from(f.over_budget);
    }
    let mut gaps: Vec<f64> = frames.iter().filter_map(|f| f.gap.and_then(|g| g.relative)).collect();
    s.gap_frames = gaps.len();
    if !gaps.is_empty() {
        s.gap_mean = Some(gaps.iter().sum::<f64>() / gaps.len() as f64);
        let absolute = frames.iter().filter_map(|f| f.gap.and_then(|g| g.relative.map(|_| g.model - g.optimum)));
        s.gap_abs_mean = Some(absolute.sum::<f64>() / gaps.len() as f64);
        s.gap_p95 = Some(percentile(&mut gaps, 0.95));
        let parts: Vec<Terms<f64>> = frames
            .iter()
            .filter_map(|f| f.gap.as_ref().zip(f.terms.as_ref()))
            .filter_map(|(g, t)| g.by_term(t))
            .collect();
        s.gap_by_term = Some(mean_terms(&parts));
    }
    let inside: Vec<f64> = frames.iter().filter_map(|f| f.inside_percent).collect();
    s.inside_frames = inside.len();
    if !inside.is_empty() {
        s.inside_mean = Some(inside.iter().sum::<f64>() / inside.len() as f64);
        s.inside_max = Some(inside.iter().copied().fold(0.0, f64::max));
    }
    let mut ms: Vec<f64> = frames.iter().map(|f| f.step_ms).collect();
    if !ms.is_empty() {
        s.median_step_ms = percentile(&mut ms, 0.5);
    }
    let off: Vec<(usize, OffBodyFrame)> = frames.iter().filter_map(|f| Some((f.frame, f.off_body?))).collect();
    if !off.is_empty() {
        s.off_body_max = Some(off.iter().map(|o| o.1.off_percent).fold(0.0, f64::max));
        s.off_body_mean = Some(off.iter().map(|o| o.1.off_percent).sum::<f64>() / off.len() as f64);
        s.lost = LossWatch::first(off.iter().map(|o| &o.1)).map(|(i, why)| (off[i].0, why));
        s.max_drift = off.iter().filter_map(|o| o.1.max_drift).reduce(f64::max);
        s.max_shift = off.iter().filter_map(|o| o.1.shift).reduce(f64::max);
    }
    s
}

/// The mean of every term (zero for none).
fn mean_terms(terms: &[Terms<f64>]) -> Terms<f64> {
    let k = terms.len().max(1) as f64;
    let mut mean = Terms::<f64>::default();
    for t in terms {
        mean.stretching += t.stretching / k;
        mean.bending += t.bending / k;
        mean.inertia += t.inertia / k;
        mean.gravity += t.gravity / k;
        mean.collision += t.collision / k;
        mean.friction += t.friction / k;
    }
    mean
}

/// Nearest-rank percentile `q` (0-1) of `v` (sorted in place; not empty).
pub fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let rank = libm::ceil(q * v.len() as f64) as usize;
    v[rank.clamp(1, v.len()) - 1]
}
