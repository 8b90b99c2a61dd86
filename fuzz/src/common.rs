//! What the entry functions share: a byte reader that turns fuzz input into counts, indices and
//! coordinates, and a tiny scene (a random model of width 4, a 5 x 5 cloth, a coarse ellipsoid).

use hood::body::BodyMesh;
use hood::mesh::{Garment, GarmentDesc};
use hood::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
use hood::sim::{BodyDesc, Sim, SimConfig};
use std::sync::OnceLock;

/// Reads fuzz input front to back; past its end every read gives zeros.
pub struct Bytes<'a> {
    data: &'a [u8],
}

impl<'a> Bytes<'a> {
    /// A reader over `data`.
    pub fn new(data: &'a [u8]) -> Self {
        Bytes { data }
    }

    /// The next byte (0 past the end).
    pub fn u8(&mut self) -> u8 {
        match self.data.split_first() {
            Some((&b, rest)) => {
                self.data = rest;
                b
            }
            None => 0,
        }
    }

    /// The next four bytes, little-endian.
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    /// A coordinate: mostly a value within about ±2.5 on a fine grid, sometimes NaN, ±infinity, a
    /// huge value or any bit pattern.
    pub fn coordinate(&mut self) -> f32 {
        match self.u8() {
            255 => f32::NAN,
            254 => f32::INFINITY,
            253 => f32::NEG_INFINITY,
            252 => 1e30,
            251 => f32::from_bits(self.u32()),
            k => (k as f32 - 125.0) / 50.0 + self.u8() as f32 / 12_800.0,
        }
    }

    /// An index into `n` elements: mostly in range, sometimes just past it or any value.
    pub fn index(&mut self, n: usize) -> u32 {
        match self.u8() {
            255 => self.u32(),
            254 => n as u32,
            k => (k as usize % n.max(1)) as u32,
        }
    }
}

/// The tiny scene every entry steps on.
pub struct Tiny {
    /// Bytes of a random model of width 4 with one coarse level (aligned).
    pub model: ModelBytes,
    /// A 5 x 5 cloth.
    pub garment: Garment,
    /// A coarse ellipsoid under it.
    pub body: BodyMesh,
    /// The body's positions.
    pub body_positions: Vec<[f32; 3]>,
}

/// The bytes of the tiny random model (also the seed of the `model` corpus).
pub fn tiny_model_bytes() -> Vec<u8> {
    let spec = ModelSpec::with_schedule(4, 2, 1, "f,c0 | f").expect("a valid schedule");
    let mut p = Params::init(&spec, 5).expect("parameters");
    p.normalisers = Normalisers::unit_scale(5);
    write_model(&p, true, &[("kind", "tiny random fuzz model")]).expect("a model file")
}

/// The tiny scene, built once per process.
pub fn tiny() -> &'static Tiny {
    static TINY: OnceLock<Tiny> = OnceLock::new();
    TINY.get_or_init(|| {
        let (rest, faces) = hood::mesh::shapes::grid(5, 5, 0.4, 0.4, 0.3);
        let garment = Garment::new(GarmentDesc::new(&rest, &faces)).expect("the cloth");
        let (body_positions, body_faces) = hood::body::shapes::ellipsoid(6, 8, [0.2, 0.25, 0.2], [0.0; 3]);
        let body = BodyMesh::new(body_positions.len(), &body_faces).expect("the body");
        Tiny { model: ModelBytes::new(&tiny_model_bytes()), garment, body, body_positions }
    })
}

/// Creates a sim of `garment` on `body` (or none) and steps it once with the body where it is;
/// errors are fine, panics are not.
pub fn step_once(model: &hood::model::Model<'_>, garment: &Garment, body: Option<BodyDesc<'_>>) {
    let positions = body.as_ref().map(|b| b.positions.to_vec()).unwrap_or_default();
    if let Ok(mut sim) = Sim::new(model, garment, body, SimConfig::network()) {
        let _ = sim.step(&positions);
    }
}

/// Runs `entry` on every file of the corpus directory `dir` (sorted), asserting that none panics
/// (the stable-toolchain replay of a target's corpus).
pub fn replay(dir: &std::path::Path, entry: fn(&[u8])) {
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "{}: an empty corpus", dir.display());
    for file in files {
        let bytes = std::fs::read(&file).expect("a corpus file");
        let run = std::panic::catch_unwind(|| entry(&bytes));
        assert!(run.is_ok(), "{} panics", file.display());
    }
}
