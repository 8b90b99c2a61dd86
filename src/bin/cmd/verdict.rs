//! The "on the body" cell shared by the tables of `hood validate` and `hood report`.

use hood::eval::Summary;

/// `**lost at F**` (off the body) or `**lost at F** (ridden up)`; `kept` when the rollout kept
/// its garment; `-` without a body to measure against.
pub fn on_body_cell(s: &Summary, kept: &str) -> String {
    match (s.lost, s.off_body_max) {
        (Some((f, hood::eval::Loss::OffBody)), _) => format!("**lost at {f}**"),
        (Some((f, why)), _) => format!("**lost at {f}** ({})", why.describe()),
        (None, Some(_)) => kept.into(),
        (None, None) => "-".into(),
    }
}
