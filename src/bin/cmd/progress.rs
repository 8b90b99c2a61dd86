//! Progress on stderr for the long commands (train, validate, report, simulate): an
//! `indicatif` bar when stderr is a terminal, otherwise a plain line at most every few seconds
//! (a log file gets whole lines, no carriage returns).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Progress of one long task, shareable between threads.
pub struct Progress {
    bar: Option<ProgressBar>,
    plain: Mutex<Plain>,
}

/// The state behind the plain lines.
struct Plain {
    label: &'static str,
    unit: &'static str,
    every: Duration,
    done: u64,
    /// Units already done when the task (re)started: not counted in the rate.
    base: u64,
    total: u64,
    message: String,
    started: Instant,
    /// When the last line was written (`None`: none yet).
    last: Option<Instant>,
}

impl Progress {
    /// A task of `total` `unit`s (0 when unknown yet: see [`inc_length`](Self::inc_length));
    /// plain lines at most every `every`.
    pub fn new(label: &'static str, unit: &'static str, total: u64, every: Duration) -> Progress {
        Progress::with_bar(std::io::stderr().is_terminal(), label, unit, total, every)
    }

    fn with_bar(bar: bool, label: &'static str, unit: &'static str, total: u64, every: Duration) -> Progress {
        let bar = bar.then(|| {
            let template = format!("{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {unit}  {{per_sec}}  eta {{eta}}  {{msg}}");
            let style = ProgressStyle::with_template(&template).unwrap_or_else(|_| ProgressStyle::default_bar());
            let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr())
                .with_style(style.progress_chars("#>."));
            bar.set_prefix(label);
            bar
        });
        let plain = Plain {
            label,
            unit,
            every,
            done: 0,
            base: 0,
            total,
            message: String::new(),
            started: Instant::now(),
            last: None,
        };
        Progress { bar, plain: Mutex::new(plain) }
    }

    fn update(&self, f: impl FnOnce(&mut Plain)) {
        let Ok(mut p) = self.plain.lock() else { return };
        f(&mut p);
        if let Some(bar) = &self.bar {
            bar.set_length(p.total);
            bar.set_position(p.done);
            bar.set_message(p.message.clone());
        } else if let Some(line) = p.due(Instant::now()) {
            eprintln!("{line}");
        }
    }

    /// Starts the count at `done` units (a resumed task): the rate counts only those after.
    #[cfg(feature = "train")]
    pub fn start_at(&self, done: u64) {
        if let Ok(mut p) = self.plain.lock() {
            (p.done, p.base) = (done, done);
        }
        if let Some(bar) = &self.bar {
            bar.set_position(done);
            bar.reset_eta();
        }
    }

    /// Sets the units done.
    pub fn set_position(&self, done: u64) {
        self.update(|p| p.done = done);
    }

    /// Adds `n` units done.
    pub fn inc(&self, n: u64) {
        self.update(|p| p.done += n);
    }

    /// Sets the total.
    #[cfg(feature = "train")]
    pub fn set_length(&self, total: u64) {
        self.update(|p| p.total = total);
    }

    /// Adds `n` units to the total.
    pub fn inc_length(&self, n: u64) {
        self.update(|p| p.total += n);
    }

    /// Sets the text after the counts (a loss, a scene name).
    pub fn set_message(&self, message: impl Into<String>) {
        let message = message.into();
        self.update(|p| p.message = message);
    }

    /// Writes a line on stderr (above the bar, if there is one).
    pub fn println(&self, line: impl AsRef<str>) {
        match &self.bar {
            Some(bar) => bar.println(line),
            None => eprintln!("{}", line.as_ref()),
        }
    }

    /// Runs `f` (which may write to stdout or stderr) with the bar out of the way.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        match &self.bar {
            Some(bar) => bar.suspend(f),
            None => f(),
        }
    }

    /// Ends the task: clears the bar, or writes the last plain line.
    pub fn finish(&self) {
        match &self.bar {
            Some(bar) => bar.finish_and_clear(),
            None => {
                if let Ok(mut p) = self.plain.lock() {
                    p.last = None;
                    if let Some(line) = p.due(Instant::now()) {
                        eprintln!("{line}");
                    }
                }
            }
        }
    }
}

impl Plain {
    /// The line to write at `now`, if one is due (the first update writes one).
    fn due(&mut self, now: Instant) -> Option<String> {
        if self.last.is_some_and(|t| now.duration_since(t) < self.every) {
            return None;
        }
        self.last = Some(now);
        let elapsed = now.duration_since(self.started).as_secs_f64();
        let rate = self.done.saturating_sub(self.base) as f64 / elapsed.max(1e-9);
        let mut line = format!("{}: {}/{} {}", self.label, self.done, self.total, self.unit);
        if self.total > 0 {
            line += &format!(" ({:.0}%)", 100.0 * self.done.min(self.total) as f64 / self.total as f64);
        }
        line += &format!(", {} elapsed", clock(elapsed));
        if rate > 0.0 && self.total > self.done {
            line += &format!(", {:.2} {}/s, eta {}", rate, self.unit, clock((self.total - self.done) as f64 / rate));
        }
        if !self.message.is_empty() {
            line += &format!(", {}", self.message);
        }
        Some(line)
    }
}

/// `1h02m`, `3m05s` or `12s`.
fn clock(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match (s / 3600, s % 3600 / 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, _) => format!("{h}h{m:02}m"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_lines_are_whole_lines_at_most_every_period() {
        let p = Progress::with_bar(false, "train", "it", 200, Duration::from_secs(60));
        assert!(p.bar.is_none());
        let mut plain = p.plain.lock().unwrap();
        (plain.base, plain.done) = (10, 60);
        plain.total = 210;
        plain.message = "loss 1.0e-3".into();
        let t0 = plain.started + Duration::from_secs(10);
        let line = plain.due(t0).expect("the first update writes a line");
        assert!(line.starts_with("train: 60/210 it (29%), 10s elapsed, 5.00 it/s, eta 30s"), "{line}");
        assert!(line.ends_with(", loss 1.0e-3"), "{line}");
        assert!(!line.contains('\r') && !line.contains('\n'));
        assert!(plain.due(t0 + Duration::from_secs(59)).is_none());
        assert!(plain.due(t0 + Duration::from_secs(60)).is_some());
    }

    #[test]
    fn clock_reads_hours_minutes_seconds() {
        assert_eq!(clock(12.4), "12s");
        assert_eq!(clock(185.0), "3m05s");
        assert_eq!(clock(3720.0), "1h02m");
    }
}
