//! PNG strips of bodies in motion.
//!
//! ```text
//! cargo run --release --features tools --example strip -- [OUT_DIR] [ASSETS_DIR]
//! ```
//!
//! Writes `OUT_DIR/procedural_walk_skirt.png` (the procedural mannequin walking, with a skirt
//! posed by skinning with diffused weights) and, when `ASSETS_DIR` (default: `$HOOD_ASSETS`,
//! else `shared/assets` in the working directory or a parent) holds the MakeHuman body and the
//! CMU walk, `OUT_DIR/cmu_walk.png` (the walk retargeted onto the MakeHuman body), and `OUT_DIR/motions/<family>.png` for every family of the motion corpus
//! (seed 1, eight frames over four seconds; `docs/motions/` holds them). Six frames each
//! otherwise, side view (from the character's left), metres.

use hood::render::{Camera, Image, Style};
use hood::rig::fit::{diffused_weights, pose_garment, DIFFUSION_SAMPLES};
use hood::rig::motion::{animate, BodyMotion, Retarget, MODEL_FPS};
use hood::rig::procedural::{family_motion, skirt, walk, Family, Mannequin};
use hood::rig::Pose;
use std::path::PathBuf;

const BODY: [u8; 3] = [200, 160, 130];
const CLOTH: [u8; 3] = [60, 110, 190];

/// A second mesh drawn in the garment colour: positions and triangles.
type Overlay<'a> = (&'a [[f32; 3]], &'a [[u32; 3]]);

fn frame_image(pos: &[[f32; 3]], faces: &[[u32; 3]], extra: Option<Overlay<'_>>) -> Image {
    let n = pos.len() as f32;
    let c = pos.iter().fold([0.0f32; 3], |a, p| [a[0] + p[0] / n, a[1] + p[1] / n, a[2] + p[2] / n]);
    let cam = Camera::orthographic([c[0], 0.95, c[2]], [1.0, 0.15, 0.35], 2.1);
    let mut im = Image::new(240, 420, [245, 245, 240]);
    im.draw_floor(&cam, [c[0], 0.0, c[2]], 3.0, 0.0);
    im.draw_mesh(&cam, pos, faces, Style { colour: BODY });
    if let Some((p, f)) = extra {
        im.draw_mesh(&cam, p, f, Style { colour: CLOTH });
    }
    im
}

fn pick(motion: &BodyMotion, k: usize) -> Vec<usize> {
    (0..k).map(|i| i * (motion.n_frames() - 1) / (k - 1)).collect()
}

fn main() -> hood::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let out = PathBuf::from(args.get(1).map_or("target/strips", String::as_str));
    let assets = match args.get(2) {
        Some(dir) => hood::assets::locate(Some(std::path::Path::new(dir)))?,
        None => hood::assets::locate(None).unwrap_or_default(),
    };
    std::fs::create_dir_all(&out)
        .map_err(|e| hood::Error::Io { path: out.display().to_string(), message: e.to_string() })?;

    // Procedural: mannequin walking, skirt skinned with diffused weights.
    let m = Mannequin::new();
    let g = skirt(&m, 2000)?;
    let w = diffused_weights(&g.rest, m.rest(), m.weights(), DIFFUSION_SAMPLES, 0.01, 1)?;
    let mo = walk(m.skeleton(), 2.0)?;
    let body = mo.animate(m.skeleton(), m.weights(), m.rest())?;
    let mut pose = Pose::rest(m.skeleton());
    let mut cloth = vec![[0.0; 3]; g.rest.len()];
    let mut frames = Vec::new();
    for f in pick(&body, 6) {
        mo.pose(m.skeleton(), f, &mut pose)?;
        pose_garment(m.skeleton(), &pose, &w, &g.rest, &mut cloth)?;
        frames.push(frame_image(body.frame(f), m.faces(), Some((&cloth, &g.faces))));
    }
    let p = out.join("procedural_walk_skirt.png");
    hood::io::png::write_strip(&p, &frames)?;
    println!("wrote {} ({} body vertices, skirt {} vertices)", p.display(), m.rest().len(), g.rest.len());

    // The motion corpus: every family, seed 1, on the mannequin.
    let dir = out.join("motions");
    std::fs::create_dir_all(&dir)
        .map_err(|e| hood::Error::Io { path: dir.display().to_string(), message: e.to_string() })?;
    for family in Family::ALL {
        let mo = family_motion(m.skeleton(), family, 4.0, 1)?;
        let body = mo.animate(m.skeleton(), m.weights(), m.rest())?;
        let frames: Vec<Image> =
            pick(&body, 8).into_iter().map(|f| frame_image(body.frame(f), m.faces(), None)).collect();
        let p = dir.join(format!("{}.png", family.name()));
        hood::io::png::write_strip(&p, &frames)?;
        println!("wrote {}", p.display());
    }

    // CMU walk on the MakeHuman body.
    if !assets.join("body/base.obj").exists() || !assets.join("motions/cmu_12_03_walk.bvh").exists() {
        println!("skipped the CMU strip: {} not found", assets.display());
        return Ok(());
    }
    let mh = hood::io::makehuman::MakeHuman::load(assets.join("body"))?;
    let clip = hood::io::bvh::read(assets.join("motions/cmu_12_03_walk.bvh"))?.resample(MODEL_FPS)?;
    let mut rt = Retarget::new(&mh.skeleton, &clip, &hood::scene::cmu_retarget(&mh))?;
    let motion = animate(&mh.skeleton, &mh.body_weights, &mh.body.rest, &clip, &mut rt)?;
    let frames: Vec<Image> =
        pick(&motion, 6).into_iter().map(|f| frame_image(motion.frame(f), &mh.body.faces, None)).collect();
    let p = out.join("cmu_walk.png");
    hood::io::png::write_strip(&p, &frames)?;
    println!("wrote {} ({} frames at 30 Hz)", p.display(), motion.n_frames());
    Ok(())
}
