//! The main job in a few lines: a model steps a dress on the walking mannequin; the garment is
//! written as an OBJ sequence and a PNG preview strip, with per-step timing and the objective.
//!
//! ```text
//! cargo run --release --features tools --example simulate -- [MODEL.hood] [OUT_DIR]
//! ```
//!
//! MODEL defaults to the shipped `models/compact.hood`; OUT_DIR to `target/simulate`.

use hood::eval::{rollout_observed, strip_images, RolloutOptions};
use hood::model::ModelBytes;
use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind};
use hood::sim::SimConfig;

fn main() -> hood::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let model_path = args.get(1).map_or(concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood"), String::as_str);
    let out = std::path::PathBuf::from(args.get(2).map_or("target/simulate", String::as_str));
    std::fs::create_dir_all(&out)
        .map_err(|e| hood::Error::Io { path: out.display().to_string(), message: e.to_string() })?;

    let bytes = ModelBytes::read(model_path)?;
    let model = bytes.model()?;
    let frames = 60;
    let scene = procedural(&Mannequin::new(), GarmentKind::Dress, 2000, MotionKind::Walk, 2.1)?;
    let options = RolloutOptions::default().with_keep(vec![0, 12, 24, 36, 48, 60]);
    let faces = scene.garment.faces();
    let rollout = rollout_observed(&model, &scene, frames, SimConfig::default(), &options, &mut |rec, pos| {
        let total = rec.terms.map_or(f64::NAN, |t| t.total());
        println!(
            "frame {:>3}: {:>7.2} ms, objective {total:.4} J, {:.2}% penetrating",
            rec.frame, rec.step_ms, rec.penetrating_percent
        );
        hood::io::obj::write(out.join(format!("garment_{:04}.obj", rec.frame)), pos, faces, None)
    })?;
    hood::io::png::write_strip(out.join("preview.png"), &strip_images(&scene, &rollout.kept, 240, 420))?;
    println!("{:?}", rollout.summary);
    Ok(())
}
