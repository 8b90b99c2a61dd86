//! Helpers shared by the integration tests: locating `../shared`, loading the parity fixture,
//! comparing tensors.
#![allow(dead_code)]

use hood::io::safetensors::SafeTensors;
use std::path::PathBuf;

/// `../shared` beside the checkout.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared"))
}

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
        println!("{test}: skipped, {} is absent", dir.display());
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
