//! `hood bench --reference PYTHON`: the reference network's forward timed on the same machine in
//! the same run, beside the runtime's rows. The reference is `tools/reference/forward.py`, a
//! plain-PyTorch forward of HOOD's network that the parity fixtures check and that does the work
//! HOOD's own `model(batch)` does (every body vertex through every block's node MLP); it runs on
//! the scene `hood bench` steps (`hood::workloads::reference_scene`), with the fixture's weights.

use hood::workloads::{reference_scene, Workload};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

/// The script's default location: beside the sources this binary was built from.
pub(crate) const DEFAULT_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/reference/forward.py");

/// One reference timing: the forwards of one workload at one thread count, one per round.
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
    /// Every timed forward, ms, in the order taken (one per round).
    pub times_ms: Vec<f64>,
    /// PyTorch's version string.
    pub torch: String,
}

impl ReferenceTime {
    /// The timing of `forwards` (all of one workload at one thread count), in round order.
    pub(crate) fn of(workload: &str, forwards: &[Forward]) -> Option<ReferenceTime> {
        let first = forwards.first()?;
        let times_ms: Vec<f64> = forwards.iter().map(|f| f.seconds * 1e3).collect();
        Some(ReferenceTime {
            workload: workload.to_string(),
            vertices: first.vertices,
            threads: first.threads,
            median_ms: hood::bench::median(&times_ms),
            min_ms: hood::bench::fastest(&times_ms),
            times_ms,
            torch: first.torch.clone(),
        })
    }
}

/// How to run the reference.
pub(crate) struct Reference<'a> {
    /// The Python interpreter (with torch, numpy and safetensors).
    pub python: &'a Path,
    /// `forward.py`.
    pub script: &'a Path,
    /// The fixture's weights (`fixture_weights.safetensors`).
    pub weights: PathBuf,
    /// Untimed forwards before the first timed one at each thread count.
    pub warmup: usize,
}

impl Reference<'_> {
    /// Starts the script on `w`'s scene (`--serve`), to time its forwards one at a time.
    ///
    /// # Errors
    /// [`hood::Error::Io`] when the scene cannot be written or the interpreter not started.
    pub(crate) fn serve(&self, w: &Workload) -> hood::Result<ReferenceServer> {
        let scene = std::env::temp_dir().join(format!("hood-reference-{}-{}.safetensors", std::process::id(), w.name));
        std::fs::write(&scene, reference_scene(w)?).map_err(|e| hood::Error::io(&scene, e))?;
        let spawned = Command::new(self.python)
            .arg(self.script)
            .arg("--scene")
            .arg(&scene)
            .arg("--weights")
            .arg(&self.weights)
            .args(["--serve", "--warmup", &self.warmup.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn();
        let mut child = match spawned {
            Ok(c) => c,
            Err(e) => {
                let _ = std::fs::remove_file(&scene);
                return Err(hood::Error::io(self.python, e));
            }
        };
        let (stdin, stdout) = (child.stdin.take(), child.stdout.take().map(BufReader::new));
        let mut server = ReferenceServer { child, stdin, stdout, scene, script: self.script.display().to_string() };
        // Wait for the script to load torch, the scene and the weights, so that its start-up
        // does not share the machine with the first round's steps.
        let ready = server.answer()?;
        if ready.get("ready").and_then(serde_json::Value::as_bool) != Some(true) {
            return Err(hood::Error::parse("reference forward", 0, format!("not a ready line: {ready}")));
        }
        Ok(server)
    }
}

/// One timed forward of the reference.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Forward {
    /// Garment vertices of the scene.
    pub vertices: usize,
    /// Threads PyTorch ran on.
    pub threads: usize,
    /// Wall time, s.
    pub seconds: f64,
    /// PyTorch's version string.
    pub torch: String,
}

/// The reference script serving one scene; stopped (and its scene file removed) when dropped.
pub(crate) struct ReferenceServer {
    child: Child,
    stdin: Option<ChildStdin>,
    stdout: Option<BufReader<ChildStdout>>,
    scene: PathBuf,
    script: String,
}

impl ReferenceServer {
    /// Times one forward at `threads` threads (the first at a count follows the warm-up).
    ///
    /// # Errors
    /// [`hood::Error::Parse`] when the script has stopped or answers with no timing line.
    pub(crate) fn forward(&mut self, threads: usize) -> hood::Result<Forward> {
        let fail = |what: String| hood::Error::parse("reference forward", 0, what);
        let Some(stdin) = self.stdin.as_mut() else {
            return Err(fail(format!("{} has no stdin", self.script)));
        };
        writeln!(stdin, "{threads}")
            .and_then(|_| stdin.flush())
            .map_err(|e| fail(format!("{} stopped: {e}", self.script)))?;
        let f = parse_forward(&self.answer()?)?;
        if f.threads != threads {
            return Err(fail(format!("asked for {threads} thread(s), the forward ran on {}", f.threads)));
        }
        Ok(f)
    }

    /// The script's next line of JSON (other lines on its stdout are passed over).
    fn answer(&mut self) -> hood::Result<serde_json::Value> {
        let fail = |what: String| hood::Error::parse("reference forward", 0, what);
        let Some(stdout) = self.stdout.as_mut() else {
            return Err(fail(format!("{} has no stdout", self.script)));
        };
        let mut line = String::new();
        loop {
            line.clear();
            match stdout.read_line(&mut line) {
                Ok(0) => return Err(fail(format!("{} exited before answering", self.script))),
                Ok(_) if line.trim_start().starts_with('{') => {
                    return serde_json::from_str(line.trim()).map_err(|e| fail(format!("{e}: {}", line.trim())));
                }
                Ok(_) => continue,
                Err(e) => return Err(fail(format!("{}: {e}", self.script))),
            }
        }
    }
}

impl Drop for ReferenceServer {
    fn drop(&mut self) {
        // Closing stdin ends the script's loop once its forward in progress (seconds at most)
        // is done; one that is still running a minute on is stopped.
        self.stdin = None;
        self.stdout = None;
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        while matches!(self.child.try_wait(), Ok(None)) && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.scene);
    }
}

/// A forward's answer: `{"vertices": V, "threads": N, "seconds": .., "torch": ..}`.
fn parse_forward(answer: &serde_json::Value) -> hood::Result<Forward> {
    #[derive(serde::Deserialize)]
    struct Line {
        vertices: usize,
        threads: usize,
        seconds: f64,
        torch: String,
    }
    let l: Line = serde_json::from_value(answer.clone())
        .map_err(|e| hood::Error::parse("reference forward", 0, format!("{e}: {answer}")))?;
    Ok(Forward { vertices: l.vertices, threads: l.threads, seconds: l.seconds, torch: l.torch })
}

#[cfg(test)]
mod tests {
    use super::{parse_forward, Forward, ReferenceTime};

    #[test]
    fn the_reference_forwards_are_read_in_milliseconds_in_round_order() {
        let line = r#"{"vertices": 1311, "threads": 2, "seconds": 0.75, "torch": "2.2.2+cu121"}"#;
        let f = parse_forward(&serde_json::from_str(line).unwrap()).unwrap();
        assert_eq!(f, Forward { vertices: 1311, threads: 2, seconds: 0.75, torch: "2.2.2+cu121".into() });
        assert!(parse_forward(&serde_json::json!({"vertices": 1})).is_err());
        let forwards: Vec<Forward> = [0.8, 0.7, 0.75].iter().map(|&seconds| Forward { seconds, ..f.clone() }).collect();
        let t = ReferenceTime::of("tee", &forwards).unwrap();
        assert_eq!((t.workload.as_str(), t.vertices, t.threads, t.torch.as_str()), ("tee", 1311, 2, "2.2.2+cu121"));
        assert_eq!((t.median_ms, t.min_ms), (750.0, 700.0));
        assert_eq!(t.times_ms, [800.0, 700.0, 750.0]);
        assert!(ReferenceTime::of("tee", &[]).is_none());
    }
}
