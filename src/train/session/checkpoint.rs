//! Checkpoints of a training run: the whole state in one safetensors file
//! ([`Trainer::save_checkpoint`]), restored exactly ([`Trainer::resume`]), carried tracks
//! included.

use super::{Track, Trainer};
use crate::error::{Error, Result};
use crate::io::safetensors::{self, SafeTensors, TensorData};
use crate::mesh::Material;
use crate::normaliser::Normaliser;
use crate::rng::Rng;
use crate::train::config::TrainConfig;
use crate::train::data::{Dataset, Sample};
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

/// Checkpoint format version (metadata key `format`).
const CHECKPOINT_FORMAT: &str = "hood-train-1";

impl Trainer {
    /// Writes the whole state to `path` (safetensors; atomically, through a temporary file).
    ///
    /// # Errors
    /// [`Error::Io`].
    pub fn save_checkpoint(&self, path: &Path) -> Result<()> {
        let n = &self.params.normalisers;
        let mut acc: Vec<(String, Vec<f64>)> = Vec::new();
        for (name, norm) in [("node", &n.node), ("edge", &n.edge), ("body_edge", &n.body_edge), ("output", &n.output)] {
            let (s, sq, c) = norm.accumulators();
            acc.push((format!("norm.{name}.sum"), s.to_vec()));
            acc.push((format!("norm.{name}.sum_sq"), sq.to_vec()));
            acc.push((format!("norm.{name}.count"), vec![c]));
        }
        let len = [self.theta.len()];
        let mut tensors: Vec<(&str, &[usize], TensorData<'_>)> = vec![
            ("theta", &len, TensorData::F32(&self.theta)),
            ("adam.m", &len, TensorData::F32(&self.adam.m)),
            ("adam.v", &len, TensorData::F32(&self.adam.v)),
        ];
        if !self.ema.is_empty() {
            tensors.push(("ema", &len, TensorData::F32(&self.ema)));
        }
        let shapes: Vec<[usize; 1]> = acc.iter().map(|a| [a.1.len()]).collect();
        for (a, s) in acc.iter().zip(&shapes) {
            tensors.push((&a.0, s, TensorData::F64(&a.1)));
        }
        // Carried tracks: their states as tensors, the rest in the metadata.
        let kept: Vec<(usize, &Track)> =
            self.tracks.iter().enumerate().filter_map(|(i, t)| Some((i, t.as_ref()?))).collect();
        let names: Vec<[String; 2]> =
            kept.iter().map(|(i, _)| [format!("track.{i}.pos"), format!("track.{i}.velocity")]).collect();
        let track_shapes: Vec<[usize; 1]> = kept.iter().map(|(_, t)| [3 * t.pos.len()]).collect();
        for ((name, (_, t)), shape) in names.iter().zip(&kept).zip(&track_shapes) {
            tensors.push((&name[0], shape, TensorData::F32(bytemuck::cast_slice(&t.pos))));
            tensors.push((&name[1], shape, TensorData::F32(bytemuck::cast_slice(&t.velocity))));
        }
        let rng = self.rng.state().map(|w| w.to_string()).join(",");
        let meta = [
            ("format", CHECKPOINT_FORMAT.to_string()),
            ("config", self.cfg.to_json()),
            ("iteration", self.iteration.to_string()),
            ("optimiser_steps", self.optimiser_steps.to_string()),
            ("adam_t", self.adam.t.to_string()),
            ("rng", rng),
            ("seconds", format!("{}", self.seconds)),
        ];
        let track_meta: Vec<(String, String)> =
            kept.iter().map(|(i, t)| (format!("track.{i}"), track_header(t))).collect();
        let meta: Vec<(&str, String)> =
            meta.into_iter().chain(track_meta.iter().map(|(k, v)| (k.as_str(), v.clone()))).collect();
        let meta_ref: Vec<(&str, &str)> = meta.iter().map(|(k, v)| (*k, v.as_str())).collect();
        let bytes = safetensors::to_bytes(&tensors, &meta_ref)?;
        crate::io::write_atomic(path, &bytes)
    }

    /// Restores a run from [`save_checkpoint`](Self::save_checkpoint)'s file; the dataset is
    /// rebuilt by the caller from the checkpoint's config ([`checkpoint_config`]).
    ///
    /// # Errors
    /// [`Error::Io`], [`Error::Parse`] for a file that is not a checkpoint of this format;
    /// [`Error::SizeMismatch`] when its parameter count disagrees with its config.
    pub fn resume(path: &Path, data: Dataset) -> Result<Trainer> {
        let st = SafeTensors::read(path)?;
        let cfg = checkpoint_config(&st)?;
        let mut t = Trainer::new(cfg, data)?;
        let meta = |k: &str| -> Result<String> {
            st.metadata()
                .iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.clone())
                .ok_or_else(|| Error::parse("checkpoint", 0, format!("missing '{k}'")))
        };
        let num = |k: &str| -> Result<u64> {
            meta(k)?.parse::<u64>().map_err(|_| Error::parse("checkpoint", 0, format!("bad '{k}'")))
        };
        let len = t.theta.len();
        let vec32 = |k: &str| -> Result<Vec<f32>> {
            let v = st.f32(k)?.data;
            if v.len() != len {
                return Err(Error::SizeMismatch { what: "checkpoint tensor", expected: len, got: v.len() });
            }
            Ok(v)
        };
        t.theta = vec32("theta")?;
        t.adam.m = vec32("adam.m")?;
        t.adam.v = vec32("adam.v")?;
        // Absent in checkpoints taken with the average off (or before `ema` existed).
        if st.tensors().iter().any(|(name, _)| name == "ema") {
            t.ema = vec32("ema")?;
        }
        t.adam.t = num("adam_t")?;
        t.iteration = num("iteration")?;
        t.optimiser_steps = num("optimiser_steps")?;
        t.seconds = meta("seconds")?.parse().unwrap_or(0.0);
        let words: Vec<u64> = meta("rng")?.split(',').filter_map(|w| w.parse().ok()).collect();
        let words: [u64; 4] = words.try_into().map_err(|_| Error::parse("checkpoint", 0, "bad 'rng'"))?;
        t.rng = Rng::from_state(words);
        let n = &mut t.params.normalisers;
        for (name, norm) in
            [("node", &mut n.node), ("edge", &mut n.edge), ("body_edge", &mut n.body_edge), ("output", &mut n.output)]
        {
            let sum = st.f64(&format!("norm.{name}.sum"))?.data;
            let sq = st.f64(&format!("norm.{name}.sum_sq"))?.data;
            let c = st.f64(&format!("norm.{name}.count"))?.data;
            if sum.len() != norm.width() || sq.len() != norm.width() || c.len() != 1 {
                return Err(Error::SizeMismatch {
                    what: "normaliser accumulators",
                    expected: norm.width(),
                    got: sum.len(),
                });
            }
            *norm = Normaliser::from_accumulators(&sum, &sq, c[0]);
        }
        for slot in 0..t.tracks.len() {
            if let Ok(header) = meta(&format!("track.{slot}")) {
                let pos = st.f32(&format!("track.{slot}.pos"))?.data;
                let velocity = st.f32(&format!("track.{slot}.velocity"))?.data;
                t.tracks[slot] = Some(read_track(&t.data, &header, &pos, &velocity)?);
            }
        }
        Ok(t)
    }
}

/// A track's checkpoint header: `scene start frame centre material…` (the centre seed `-` when
/// none; the material's four values as `f32` bit patterns, so that they come back exactly).
fn track_header(t: &Track) -> String {
    let s = &t.sample;
    let m = &s.material;
    let centre = s.centre_seed.map_or("-".to_string(), |c| c.to_string());
    let bits = [m.density, m.mu, m.lambda, m.bending].map(|x| x.to_bits().to_string()).join(" ");
    format!("{} {} {} {centre} {bits}", s.scene, s.start, t.frame)
}

/// The inverse of [`track_header`] with the state tensors.
fn read_track(data: &Dataset, header: &str, pos: &[f32], velocity: &[f32]) -> Result<Track> {
    let bad = || Error::parse("checkpoint", 0, format!("bad track '{header}'"));
    let w: Vec<&str> = header.split(' ').collect();
    if w.len() != 8 {
        return Err(bad());
    }
    let num = |i: usize| w[i].parse::<u64>().map_err(|_| bad());
    let (scene, start, frame) = (num(0)? as usize, num(1)? as usize, num(2)? as usize);
    let centre_seed = if w[3] == "-" { None } else { Some(num(3)?) };
    let f = |i: usize| -> Result<f32> { Ok(f32::from_bits(w[i].parse::<u32>().map_err(|_| bad())?)) };
    let material = Material { density: f(4)?, mu: f(5)?, lambda: f(6)?, bending: f(7)? };
    let s = data.scenes.get(scene).ok_or_else(bad)?;
    if frame >= s.n_frames() {
        return Err(bad());
    }
    let garment = s.garment_with_material(material)?;
    let n = garment.n_vertices();
    if pos.len() != 3 * n || velocity.len() != 3 * n {
        return Err(Error::SizeMismatch { what: "checkpoint track", expected: 3 * n, got: pos.len() });
    }
    let rows = |x: &[f32]| x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(Track {
        sample: Sample { scene, start, garment, material, centre_seed },
        frame,
        pos: rows(pos),
        velocity: rows(velocity),
    })
}

/// The config stored in a checkpoint.
///
/// # Errors
/// [`Error::Parse`] when the file is not a checkpoint of this format.
pub fn checkpoint_config(st: &SafeTensors) -> Result<TrainConfig> {
    let get = |k: &str| st.metadata().iter().find(|(key, _)| key == k).map(|(_, v)| v.as_str());
    if get("format") != Some(CHECKPOINT_FORMAT) {
        return Err(Error::parse("checkpoint", 0, format!("not a {CHECKPOINT_FORMAT} checkpoint")));
    }
    TrainConfig::from_json(get("config").unwrap_or(""))
}
