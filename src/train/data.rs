//! Training data: a pool of animated scenes (MODEL.md section 7) and the samples drawn from it:
//! a scene, a start frame, a material, a hierarchy centre.

use super::config::{SceneSource, TrainConfig};
use crate::error::{Error, Result};
use crate::mesh::material_ranges as ranges;
use crate::mesh::{Garment, Material};
use crate::rig::procedural::Mannequin;
use crate::rng::Rng;
use crate::scene::{self, MakeHumanGarment, Scene};
use std::path::Path;
use std::string::String;
use std::vec::Vec;

/// The scenes a run samples from.
pub struct Dataset {
    /// The scenes, in config order (absent asset scenes dropped).
    pub scenes: Vec<Scene>,
    /// Their config names.
    pub names: Vec<String>,
    /// Config entries that could not be built, with the reason (e.g. assets absent).
    pub skipped: Vec<(String, String)>,
    /// Per scene, the garment positions (m) of its reference rollout at frames `0..len`, once
    /// [`attach_reference_states`](Self::attach_reference_states) has run (else empty).
    pub reference: Vec<Vec<Positions>>,
}

/// One training sample.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Index into [`Dataset::scenes`].
    pub scene: usize,
    /// Frame the rollout starts at (the start-up step's frame).
    pub start: usize,
    /// The garment with the sample's material.
    pub garment: Garment,
    /// The material.
    pub material: Material,
    /// Seed of the hierarchy's centre choice (`None`: the first candidate).
    pub centre_seed: Option<u64>,
}

/// A material drawn over MODEL.md's ranges: density and lambda uniform, mu and the bending
/// stiffness log-uniform.
pub fn random_material(rng: &mut Rng) -> Material {
    let log_uniform =
        |rng: &mut Rng, (lo, hi): (f32, f32)| libm::exp(rng.uniform(libm::log(lo as f64), libm::log(hi as f64))) as f32;
    let uniform = |rng: &mut Rng, (lo, hi): (f32, f32)| rng.uniform(lo as f64, hi as f64) as f32;
    let density = uniform(rng, ranges::DENSITY);
    let mu = log_uniform(rng, ranges::MU);
    let lambda = uniform(rng, ranges::LAMBDA);
    let bending = log_uniform(rng, ranges::BENDING);
    Material { density, mu, lambda, bending }
}

impl Dataset {
    /// Builds every scene of `cfg` (asset scenes read `assets`; when absent they are skipped
    /// and listed in [`skipped`](Self::skipped)). `progress` is told each scene's name as it is
    /// built.
    ///
    /// # Errors
    /// Errors of the procedural generators; [`Error::Empty`] when no scene could be built.
    pub fn build(cfg: &TrainConfig, assets: &Path, mut progress: impl FnMut(&str)) -> Result<Dataset> {
        let mut mannequin: Option<Mannequin> = None;
        let mut d = Dataset { scenes: Vec::new(), names: Vec::new(), skipped: Vec::new(), reference: Vec::new() };
        for src in &cfg.scenes {
            let name = src.name();
            progress(&name);
            let built = match src {
                SceneSource::Procedural { garment, vertices, motion, seconds } => {
                    let m = mannequin.get_or_insert_with(Mannequin::new);
                    scene::procedural(m, *garment, *vertices, *motion, *seconds)
                }
                SceneSource::MakeHuman { garment, frames, motion } => {
                    let Some(which) = MakeHumanGarment::parse(garment) else {
                        return Err(Error::parse("training config", 0, "unknown MakeHuman garment"));
                    };
                    if !assets.join("body/base.obj").exists() {
                        d.skipped.push((name, std::format!("{} not found", assets.display())));
                        continue;
                    }
                    scene::makehuman_on(assets, which, *motion, *frames)
                }
            };
            let mut s = built?;
            if cfg.material != Material::default() {
                // The reference rollouts play the scene's own garment: give it the run's material.
                s.garment = s.garment_with_material(cfg.material)?;
            }
            if s.n_frames() < cfg.rollout_max + 2 {
                d.skipped.push((name, std::format!("only {} frames", s.n_frames())));
                continue;
            }
            d.scenes.push(s);
            d.names.push(name);
        }
        if d.scenes.is_empty() {
            return Err(Error::Empty { what: "training scenes" });
        }
        Ok(d)
    }

    /// Plays every scene's reference rollout: from the skinned garment at rest at frame 0, every
    /// frame one implicit step of the training objective at the final collision weight (f64
    /// L-BFGS to the tolerances of [`crate::eval::converged_solver`]), in the
    /// [`material`](TrainConfig::material) of the config the dataset was built with, pinned
    /// vertices at their targets. A rollout that turns non-finite keeps its frames up to there,
    /// and one whose garment has fallen off ([`REFERENCE_GONE_PERCENT`] or more of its worn
    /// vertices off the body) keeps its frames before that one, so that no sample starts from a
    /// garment the solver has thrown off (on inversions the implicit step of the objective can
    /// lose a loose top). A top flaring away from the body at a jump's peak, or ridden up to the
    /// chest, stays: those are states the network has to step from. With `cache`, each scene's
    /// states are read from `cache/<scene>.bin` when there (of the scene's size and made with
    /// the converged step's iteration cap), else computed and written there (the cache is per run: its
    /// files do not record the material). Up to `threads` scenes are solved at once, one per
    /// thread; `progress(scene, done, of)` is told about every frame solved, with the frames
    /// solved so far and the frames to solve in all.
    ///
    /// # Errors
    /// Errors of the scoring rollout; [`Error::Io`] when the cache cannot be written.
    pub fn attach_reference_states(
        &mut self,
        cache: Option<&Path>,
        collision_weight: f64,
        threads: usize,
        progress: impl Fn(&str, usize, usize) + Sync,
    ) -> Result<()> {
        use core::sync::atomic::{AtomicUsize, Ordering};
        use std::sync::Mutex;
        let files: Vec<Option<std::path::PathBuf>> = self
            .names
            .iter()
            .map(|name| cache.map(|dir| dir.join(std::format!("{}.bin", name.replace(['/', ' '], "_")))))
            .collect();
        let cap = crate::eval::converged_solver().max_iterations;
        let mut states: Vec<Option<Vec<Positions>>> = self
            .scenes
            .iter()
            .zip(&files)
            .map(|(scene, file)| {
                let n = scene.garment.n_vertices();
                file.as_deref().and_then(|f| read_states(f, n, cap))
            })
            .collect();
        // The rollouts still to solve, one scene per worker at a time (each is serial).
        let todo: Vec<usize> = (0..self.scenes.len()).filter(|&i| states[i].is_none()).collect();
        let of: usize = todo.iter().map(|&i| self.scenes[i].n_frames() - 1).sum();
        let (next, done) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let solved: Mutex<Vec<(usize, Result<Vec<Positions>>)>> = Mutex::new(Vec::new());
        let work = || {
            while let Some(&i) = todo.get(next.fetch_add(1, Ordering::Relaxed)) {
                let name = &self.names[i];
                let r = reference_rollout(&self.scenes[i], collision_weight, &mut || {
                    progress(name, done.fetch_add(1, Ordering::Relaxed) + 1, of);
                })
                .and_then(|computed| {
                    // Written at once: an interrupted run keeps the scenes it finished.
                    if let Some(f) = &files[i] {
                        write_states(f, &computed, cap)?;
                    }
                    Ok(computed)
                });
                if r.is_err() {
                    // No worker starts another scene.
                    next.store(todo.len(), Ordering::Relaxed);
                }
                solved.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push((i, r));
            }
        };
        std::thread::scope(|scope| {
            for _ in 1..threads.clamp(1, todo.len().max(1)) {
                scope.spawn(work);
            }
            work();
        });
        let mut solved = solved.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner);
        // The first error in scene order, whichever worker met it.
        solved.sort_by_key(|(i, _)| *i);
        for (i, r) in solved {
            states[i] = Some(r?);
        }
        self.reference.clear();
        for (scene, s) in self.scenes.iter().zip(states) {
            let mut s = s.unwrap_or_default();
            truncate_at_loss(scene, &mut s)?;
            self.reference.push(s);
        }
        Ok(())
    }

    /// The reference state of `scene` at `frame`: positions and velocity (the displacement since
    /// the frame before, m per frame), if the reference reaches `frame` and `frame >= 1`.
    pub fn reference_state(&self, scene: usize, frame: usize) -> Option<(Positions, Positions)> {
        let states = self.reference.get(scene)?;
        let (prev, pos) = (states.get(frame.checked_sub(1)?)?, states.get(frame)?);
        let vel = pos.iter().zip(prev).map(|(a, b)| crate::math::sub3(*a, *b)).collect();
        Some((pos.clone(), vel))
    }

    /// Draws a sample whose rollout of `steps` optimiser steps stays within its scene.
    ///
    /// # Errors
    /// Errors of [`Scene::garment_with_material`].
    pub fn sample(&self, rng: &mut Rng, steps: usize, cfg: &TrainConfig) -> Result<Sample> {
        let scene = rng.below(self.scenes.len());
        let s = &self.scenes[scene];
        let last_start = s.n_frames().saturating_sub(steps + 1).max(1);
        let start = rng.below(last_start);
        let material = if cfg.random_materials { random_material(rng) } else { cfg.material };
        let centre_seed = if cfg.random_centres { Some(rng.next_u64()) } else { None };
        let garment = s.garment_with_material(material)?;
        Ok(Sample { scene, start, garment, material, centre_seed })
    }
}

/// Garment positions (m), one per vertex.
pub type Positions = Vec<[f32; 3]>;

/// One scene's reference rollout (the rules of [`Dataset::attach_reference_states`], before
/// the cut where the garment has fallen off), telling `frame_done` about every frame solved.
///
/// Each frame is the converged step ([`crate::eval::converged_solver`]: at most 1,000 L-BFGS
/// iterations, most frames ending sooner on its tolerances). On walks 100 iterations come within
/// about 0.002 of its gap (the accuracy/time report), but on vigorous motion they fall behind
/// it: capped at 100, the implicit step loses the t-shirt on the training jumps at frame 13 and
/// has it entirely off from frame 262; converged, it keeps the t-shirt on the body through the
/// clip (at most 13.7 % of its worn vertices off, at one jump's peak; ridden up to the chest by
/// the end), for about 0.1 s a frame against 0.04 s.
fn reference_rollout(scene: &Scene, collision_weight: f64, frame_done: &mut dyn FnMut()) -> Result<Vec<Positions>> {
    use crate::eval::{converged_solver, implicit_rollout, RolloutOptions};
    use crate::physics::Objective;
    let solver = converged_solver();
    let frames = scene.n_frames() - 1;
    let opts = RolloutOptions { objective: Objective::training(collision_weight), ..RolloutOptions::default() };
    let mut states = std::vec![scene.initial_garment(0)?];
    let r = implicit_rollout(scene, frames, &solver, &opts, &mut |_, pos| {
        states.push(pos.to_vec());
        frame_done();
        Ok(())
    })?;
    if r.failure.is_some() {
        // The failing frame's positions were not recorded: the states end before it.
        states.truncate(r.frames.len() + 1);
    }
    Ok(states)
}

/// Drops the states of `scene`'s reference rollout from the first frame at which
/// [`REFERENCE_GONE_PERCENT`] or more of the garment's worn vertices are off the body
/// ([`OffBody`](crate::eval::OffBody)). The cache keeps the whole rollout: the rule may change,
/// the solve need not be redone.
fn truncate_at_loss(scene: &Scene, states: &mut Vec<Positions>) -> Result<()> {
    use crate::eval::OffBody;
    let Some(mut metric) = OffBody::new(scene)? else { return Ok(()) };
    for (t, x) in states.iter().enumerate() {
        if metric.measure(scene, t, x)?.off_percent >= REFERENCE_GONE_PERCENT {
            states.truncate(t);
            break;
        }
    }
    Ok(())
}

/// The percentage of worn vertices off the body at which a reference rollout's garment has
/// fallen off, and its states end. Far above the acceptance bound of a rollout
/// ([`crate::eval::LOST_PERCENT`]): at that bound the converged step of the objective already
/// "loses" the t-shirt for a few frames at the peak of a jump, as the hem flares away, and then
/// holds it on for the rest of the clip.
pub const REFERENCE_GONE_PERCENT: f64 = 50.0;

/// Magic bytes of a reference-state file. Version 3: the header records the L-BFGS iterations
/// per frame, and files made with other counts are recomputed. Version 2 started the rollouts
/// at the scene's initial velocity ([`Scene::initial_velocity`]), version 1 from rest.
const STATES_MAGIC: &[u8; 8] = b"HOODREF3";

/// Bytes of a reference-state file's header: magic, then frames, vertices and iterations.
const STATES_HEADER: usize = 20;

/// Reads a reference-state file (magic, frames, vertices and L-BFGS iterations per frame as
/// little-endian `u32`, then the positions as little-endian `f32`), `None` when absent,
/// damaged, not of `n` vertices or not made with `iterations`.
fn read_states(path: &Path, n: usize, iterations: usize) -> Option<Vec<Vec<[f32; 3]>>> {
    let bytes = std::fs::read(path).ok()?;
    let (head, body) = bytes.split_at_checked(STATES_HEADER)?;
    let word = |i: usize| u32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]) as usize;
    let (frames, verts, iters) = (word(8), word(12), word(16));
    let fits = body.len() == frames * verts * 12;
    if &head[..8] != STATES_MAGIC || verts != n || iters != iterations || frames == 0 || !fits {
        return None;
    }
    let values: Vec<f32> = body.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    Some(values.chunks_exact(verts * 3).map(|f| f.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect()).collect())
}

/// Writes `states` in [`read_states`]' format (atomically).
fn write_states(path: &Path, states: &[Vec<[f32; 3]>], iterations: usize) -> Result<()> {
    let io = |e: std::io::Error| Error::io(path, e);
    let verts = states.first().map_or(0, Vec::len);
    let mut bytes = Vec::with_capacity(STATES_HEADER + states.len() * verts * 12);
    bytes.extend_from_slice(STATES_MAGIC);
    for word in [states.len(), verts, iterations] {
        bytes.extend_from_slice(&(word as u32).to_le_bytes());
    }
    for p in states.iter().flatten().flatten() {
        bytes.extend_from_slice(&p.to_le_bytes());
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    crate::io::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{GarmentKind, MotionKind};

    /// A reference rollout keeps its frames up to the one whose garment has fallen off, and all
    /// of them while the garment stays on, even where part of it flares away for a while.
    #[test]
    fn reference_states_end_where_the_garment_has_fallen_off() {
        let m = Mannequin::new();
        let s = scene::procedural(&m, GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
        let worn: Vec<Positions> = (0..s.n_frames()).map(|f| s.initial_garment(f).unwrap()).collect();
        let mut kept = worn.clone();
        truncate_at_loss(&s, &mut kept).unwrap();
        assert_eq!(kept.len(), worn.len());
        // Every fifth vertex 30 cm out on frames 3-6: off the body by the acceptance rule, not
        // fallen off.
        let mut flared = worn.clone();
        for frame in &mut flared[3..7] {
            for p in frame.iter_mut().step_by(5) {
                p[0] += 0.3;
            }
        }
        let mut metric = crate::eval::OffBody::new(&s).unwrap().unwrap();
        let off = metric.measure(&s, 3, &flared[3]).unwrap().off_percent;
        assert!((crate::eval::LOST_PERCENT..REFERENCE_GONE_PERCENT).contains(&off), "{off}");
        truncate_at_loss(&s, &mut flared).unwrap();
        assert_eq!(flared.len(), worn.len());
        let mut lost = worn.clone();
        for p in lost[7].iter_mut() {
            p[1] -= 1.0; // a metre down: fallen to the floor
        }
        truncate_at_loss(&s, &mut lost).unwrap();
        assert_eq!(lost.len(), 7);
    }

    /// The state cache reads back what it wrote, and refuses files of another vertex count or
    /// made with another number of solver iterations.
    #[test]
    fn reference_state_files_record_their_solver_iterations() {
        let dir = std::env::temp_dir().join(std::format!("hood-reference-{}", std::process::id()));
        let file = dir.join("scene.bin");
        let states: Vec<Positions> = (0..3).map(|f| (0..4).map(|v| [f as f32, v as f32, 0.5]).collect()).collect();
        write_states(&file, &states, 300).unwrap();
        assert_eq!(read_states(&file, 4, 300), Some(states));
        assert_eq!(read_states(&file, 5, 300), None);
        assert_eq!(read_states(&file, 4, 100), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A run's fixed material reaches its samples and the garments its reference rollouts play;
    /// without one, both keep the default.
    #[test]
    fn a_fixed_material_reaches_samples_and_reference_scenes() {
        let stiff = Material::preset("stiff-bend").unwrap();
        let scenes = r#""scenes": [{"garment": "skirt", "vertices": 200, "motion": "walk", "seconds": 0.5}]"#;
        for (material, want) in [(r#""material": "stiff-bend","#, stiff), ("", Material::default())] {
            let json = std::format!(r#"{{"random_materials": false, {material} {scenes}}}"#);
            let cfg = TrainConfig::from_json(&json).unwrap();
            assert_eq!(cfg.material, want);
            let d = Dataset::build(&cfg, Path::new("no-assets"), |_| {}).unwrap();
            assert!(d.scenes[0].garment.materials().iter().all(|m| *m == want));
            let s = d.sample(&mut Rng::new(1), 2, &cfg).unwrap();
            assert_eq!(s.material, want);
            assert!(s.garment.materials().iter().all(|m| *m == want));
        }
        // A fixed material that random materials would ignore is refused.
        let both = std::format!(r#"{{"material": "stiff-bend", {scenes}}}"#);
        assert!(TrainConfig::from_json(&both).is_err());
    }
}
