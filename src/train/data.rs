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
        let mut d = Dataset { scenes: Vec::new(), names: Vec::new(), skipped: Vec::new() };
        for src in &cfg.scenes {
            let name = src.name();
            progress(&name);
            let built = match src {
                SceneSource::Procedural { garment, vertices, motion, seconds } => {
                    let m = mannequin.get_or_insert_with(Mannequin::new);
                    scene::procedural(m, *garment, *vertices, *motion, *seconds)
                }
                SceneSource::MakeHuman { garment, frames } => {
                    let which = match garment.as_str() {
                        "tee" => MakeHumanGarment::Tee,
                        "jeans" => MakeHumanGarment::Jeans,
                        _ => return Err(Error::parse("training config", 0, "MakeHuman garments: tee or jeans")),
                    };
                    if !assets.join("body/base.obj").exists() {
                        d.skipped.push((name, std::format!("{} not found", assets.display())));
                        continue;
                    }
                    scene::makehuman(assets, which, *frames)
                }
            };
            let s = built?;
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

    /// Draws a sample whose rollout of `steps` optimiser steps stays within its scene.
    ///
    /// # Errors
    /// Errors of [`Scene::garment_with_material`].
    pub fn sample(&self, rng: &mut Rng, steps: usize, cfg: &TrainConfig) -> Result<Sample> {
        let scene = rng.below(self.scenes.len());
        let s = &self.scenes[scene];
        let last_start = s.n_frames().saturating_sub(steps + 1).max(1);
        let start = rng.below(last_start);
        let material = if cfg.random_materials { random_material(rng) } else { Material::default() };
        let centre_seed = if cfg.random_centres { Some(rng.next_u64()) } else { None };
        let garment = s.garment_with_material(material)?;
        Ok(Sample { scene, start, garment, material, centre_seed })
    }
}
