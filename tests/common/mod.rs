//! Helpers shared by the integration tests: locating `../shared`, loading the parity fixture,
//! comparing tensors.
#![allow(dead_code)]

// Not every test that shares these helpers reads the fixture.
#[cfg(feature = "tools")]
#[allow(unused_imports)]
pub use fixture::*;
use std::path::{Path, PathBuf};

/// Says that `test` skips (some or all of its checks) because `missing` is absent: one `SKIPPED`
/// line. With `HOOD_REQUIRE_SHARED` set (CI sets it, having `../shared` beside the clone) it
/// fails instead, so that no test there passes without testing.
pub fn skip(test: &str, missing: &Path) {
    if std::env::var_os("HOOD_REQUIRE_SHARED").is_some() {
        panic!("{test}: {} is absent and HOOD_REQUIRE_SHARED is set", missing.display());
    }
    println!("SKIPPED {test}: {} is absent", missing.display());
}

/// `../shared` beside the checkout.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared"))
}

/// The parity fixture, read with the tools' safetensors reader (feature `tools`).
#[cfg(feature = "tools")]
mod fixture {
    use super::{shared_dir, skip};
    use hood::io::safetensors::SafeTensors;

    /// The parity fixture's four files, or `None` (after printing why) when absent.
    pub struct Fixture {
        pub scene: SafeTensors,
        pub io: SafeTensors,
        pub weights: SafeTensors,
        pub losses: SafeTensors,
    }

    pub fn fixture(test: &str) -> Option<Fixture> {
        let dir = shared_dir().join("fixtures/hood-parity");
        if !dir.join("fixture_scene.safetensors").exists() {
            skip(test, &dir);
            return None;
        }
        let load = |f: &str| SafeTensors::read(dir.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        Some(Fixture {
            scene: load("fixture_scene.safetensors"),
            io: load("fixture_io.safetensors"),
            weights: load("fixture_weights.safetensors"),
            losses: load("fixture_losses.safetensors"),
        })
    }

    /// An `(n, 2)` edge index stored as `(2, n)` (row 0 sources, row 1 targets) as `[source, target]` pairs.
    pub fn edge_pairs(st: &SafeTensors, name: &str) -> Vec<[u32; 2]> {
        let t = st.i64(name).unwrap();
        assert_eq!(t.shape[0], 2, "{name}");
        let n = t.shape[1];
        (0..n).map(|k| [t.data[k] as u32, t.data[n + k] as u32]).collect()
    }

    pub fn rows3(st: &SafeTensors, name: &str) -> Vec<[f32; 3]> {
        st.f32(name).unwrap().rows::<3>().unwrap()
    }

    pub fn faces(st: &SafeTensors, name: &str) -> Vec<[u32; 3]> {
        st.i64(name).unwrap().rows::<3>().unwrap().iter().map(|f| f.map(|v| v as u32)).collect()
    }
}

/// `||a - b|| / ||b||` (Frobenius), with `||b||` floored at 1e-30.
pub fn rel_err(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    let (mut d, mut n) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        d += (*x as f64 - *y as f64).powi(2);
        n += (*y as f64).powi(2);
    }
    d.sqrt() / n.sqrt().max(1e-30)
}

/// Largest absolute difference.
pub fn max_abs(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).abs()).fold(0.0, f64::max)
}

/// A small random model (PyTorch-style initialisation) whose normalisers have seen unit-scale
/// data, so that features and outputs are in a sensible range.
pub fn random_model(h: usize, seed: u64, bf16: bool) -> hood::model::ModelBytes {
    use hood::model::{write_model, ModelBytes, ModelSpec, Params};
    let spec = ModelSpec::hood(h);
    let mut p = Params::init(&spec, seed).unwrap();
    p.normalisers = hood::model::Normalisers::unit_scale(seed);
    ModelBytes::new(&write_model(&p, bf16, &[("kind", "random test model")]).unwrap())
}

/// A procedural scene: a `nx × nz` cloth hanging just above an ellipsoid body, pinned at two
/// corners, and the body's vertices at frame `t` (a slow sway).
pub struct Scene {
    pub garment: hood::mesh::Garment,
    pub body: hood::body::BodyMesh,
    pub body_rest: Vec<[f32; 3]>,
}

impl Scene {
    pub fn new(nx: usize, nz: usize) -> Scene {
        let (rest, faces) = hood::mesh::shapes::grid(nx, nz, 0.6, 0.6, 0.32);
        let mut pinned = vec![false; rest.len()];
        pinned[0] = true;
        pinned[nx - 1] = true;
        let garment = hood::mesh::Garment::new(hood::mesh::GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
        let (bv, bf) = hood::body::shapes::ellipsoid(24, 32, [0.25, 0.3, 0.25], [0.0, 0.0, 0.0]);
        let body = hood::body::BodyMesh::new(bv.len(), &bf).unwrap();
        Scene { garment, body, body_rest: bv }
    }

    pub fn body_at(&self, t: usize) -> Vec<[f32; 3]> {
        let dx = 0.01 * (t as f32 * 0.3).sin();
        self.body_rest.iter().map(|p| [p[0] + dx, p[1], p[2]]).collect()
    }

    /// A simulator of this scene's garment, with the body at frame 0.
    pub fn sim<'m>(
        &self,
        model: &'m hood::model::Model<'m>,
        cfg: hood::sim::SimConfig,
    ) -> hood::Result<hood::sim::Sim<'m>> {
        let b0 = self.body_at(0);
        hood::sim::Sim::new(model, &self.garment, Some(hood::sim::BodyDesc { mesh: &self.body, positions: &b0 }), cfg)
    }
}
