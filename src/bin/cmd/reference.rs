//! `hood bench --reference PYTHON`: the reference network's forward timed on the same machine in
//! the same run, beside the runtime's rows. The reference is `tools/reference/forward.py`, a
//! plain-PyTorch forward of HOOD's network that the parity fixtures check and that does the work
//! HOOD's own `model(batch)` does (every body vertex through every block's node MLP); it runs on
//! the scene `hood bench` steps (`hood::workloads::reference_scene`), with the fixture's weights.

use hood::workloads::{reference_scene, Workload};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The script's default location: beside the sources this binary was built from.
pub(crate) const DEFAULT_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/reference/forward.py");

/// One reference timing: the forward of one workload at one thread count.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ReferenceTime {
    /// The workload's name.
    pub workload: String,
    /// Garment vertices.
    pub vertices: usize,
    /// Threads PyTorch was given (`torch.set_num_threads`).
    pub threads: usize,
    /// Median of the timed forwards, ms.
    pub median_ms: f64,
    /// Fastest of them, ms.
    pub min_ms: f64,
    /// PyTorch's version string.
    pub torch: String,
}

/// How to run the reference.
pub(crate) struct Reference<'a> {
    /// The Python interpreter (with torch, numpy and safetensors).
    pub python: &'a Path,
    /// `forward.py`.
    pub script: &'a Path,
    /// The fixture's weights (`fixture_weights.safetensors`).
    pub weights: PathBuf,
    /// Timed forwards per thread count (the median is reported).
    pub runs: usize,
    /// Untimed forwards before them.
    pub warmup: usize,
}

impl Reference<'_> {
    /// Times the reference's forward on `w` at each of `threads`.
    ///
    /// # Errors
    /// [`hood::Error::Io`] when the scene cannot be written or the interpreter not started;
    /// [`hood::Error::Parse`] when the script fails or prints no timing line.
    pub(crate) fn time(&self, w: &Workload, threads: &[usize]) -> hood::Result<Vec<ReferenceTime>> {
        let scene = std::env::temp_dir().join(format!("hood-reference-{}-{}.safetensors", std::process::id(), w.name));
        std::fs::write(&scene, reference_scene(w)?).map_err(|e| hood::Error::io(&scene, e))?;
        let times = threads.iter().map(|&t| self.run(&scene, w, t)).collect();
        let _ = std::fs::remove_file(&scene);
        times
    }

    fn run(&self, scene: &Path, w: &Workload, threads: usize) -> hood::Result<ReferenceTime> {
        let out = Command::new(self.python)
            .arg(self.script)
            .arg("--scene")
            .arg(scene)
            .arg("--weights")
            .arg(&self.weights)
            .args(["--time", "--threads", &threads.to_string()])
            .args(["--runs", &self.runs.to_string(), "--warmup", &self.warmup.to_string()])
            .stderr(Stdio::inherit())
            .output()
            .map_err(|e| hood::Error::io(self.python, e))?;
        let fail = |what: String| hood::Error::parse("reference forward", 0, what);
        if !out.status.success() {
            return Err(fail(format!("{} exited with {}", self.script.display(), out.status)));
        }
        let stdout = String::from_utf8_lossy(&out.stdout);
        let line = stdout.lines().rev().find(|l| l.trim_start().starts_with('{'));
        parse_timing(line.ok_or_else(|| fail("no timing line on stdout".into()))?, &w.name)
    }
}

/// The script's timing line: `{"vertices": V, "threads": N, "median_s": .., "min_s": .., "torch": ..}`.
fn parse_timing(line: &str, workload: &str) -> hood::Result<ReferenceTime> {
    #[derive(serde::Deserialize)]
    struct Line {
        vertices: usize,
        threads: usize,
        median_s: f64,
        min_s: f64,
        torch: String,
    }
    let l: Line =
        serde_json::from_str(line).map_err(|e| hood::Error::parse("reference forward", 0, format!("{e}: {line}")))?;
    Ok(ReferenceTime {
        workload: workload.to_string(),
        vertices: l.vertices,
        threads: l.threads,
        median_ms: l.median_s * 1e3,
        min_ms: l.min_s * 1e3,
        torch: l.torch,
    })
}

#[cfg(test)]
mod tests {
    use super::parse_timing;

    #[test]
    fn the_reference_timing_line_is_read_in_milliseconds() {
        let line = r#"{"vertices": 1311, "threads": 2, "median_s": 0.75, "min_s": 0.7, "runs": [0.7, 0.75, 0.8], "torch": "2.2.2+cu121"}"#;
        let t = parse_timing(line, "tee").unwrap();
        assert_eq!((t.workload.as_str(), t.vertices, t.threads), ("tee", 1311, 2));
        assert_eq!((t.median_ms, t.min_ms, t.torch.as_str()), (750.0, 700.0, "2.2.2+cu121"));
        assert!(parse_timing(r#"{"vertices": 1}"#, "tee").is_err());
    }
}
