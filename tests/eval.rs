//! Rollout evaluation on procedural scenes with small random models: what is recorded, that the
//! per-frame objective agrees with the physics module's independent rollout scoring, and that the
//! objective gap is ordered (optimum ≤ model, optimum ≤ coasting).
#![cfg(feature = "tools")]

mod common;
use common::random_model;
use hood::eval::{rollout, rollout_observed, strip_images, Playback, RolloutOptions, StepKind};
use hood::physics::{score_rollout, Objective};
use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind};
use hood::sim::SimConfig;

#[test]
fn eval_rollout_records_every_frame_and_orders_the_gap() {
    let scene = procedural(&Mannequin::new(), GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
    let bytes = random_model(16, 7, false);
    let model = bytes.model().unwrap();
    let frames = 8;
    let opts = RolloutOptions::default().with_gap_every(3).with_keep(vec![0, 4, 8, 99]);
    let mut seen = Vec::new();
    let r = rollout_observed(&model, &scene, frames, SimConfig::network(), &opts, &mut |rec, pos| {
        assert_eq!(pos.len(), scene.garment.n_vertices());
        seen.push(rec.frame);
        Ok(())
    })
    .unwrap();
    if let Some((f, e)) = &r.failure {
        println!("random model refused at frame {f}: {e}");
    }
    let reached = r.frames.len();
    assert_eq!(seen, (1..=reached).collect::<Vec<_>>());
    assert_eq!(r.summary.frames, reached);
    assert_eq!(r.summary.finite, r.failure.is_none());
    assert_eq!(r.frames[0].kind, StepKind::StartUp);
    assert!(r.frames[1..].iter().all(|f| f.kind == StepKind::Stepped));
    let kept: Vec<usize> = r.kept.iter().map(|k| k.0).collect();
    assert_eq!(kept, [0, 4, 8].into_iter().filter(|&f| f <= reached).collect::<Vec<_>>());
    for f in &r.frames {
        let t = f.terms.expect("stepped frames are scored");
        assert!(t.total().is_finite() && t.stretching >= 0.0 && t.bending >= 0.0 && t.inertia >= 0.0);
        assert!((0.0..=100.0).contains(&f.penetrating_percent));
        assert!(f.max_edge_strain.is_finite() && f.max_speed.is_finite());
        assert_eq!(f.gap.is_some(), f.frame % 3 == 0, "frame {}", f.frame);
        if let Some(g) = f.gap {
            // The model's total is the scored total; the optimum is no worse than either.
            assert!((g.model - t.total()).abs() <= 1e-12 * g.model.abs().max(1.0));
            let tol = 1e-9 * g.coasting.abs().max(1.0);
            assert!(g.optimum <= g.coasting + tol, "{g:?}");
            assert!(g.optimum <= g.model + tol, "{g:?}");
            // The parts by term add up to the relative gap.
            assert!((g.optimum_terms.total() - g.optimum).abs() <= tol, "{g:?}");
            if let (Some(rel), Some(parts)) = (g.relative, g.by_term(&t)) {
                assert!((parts.total() - rel).abs() <= 1e-6 * rel.abs().max(1.0), "{parts:?} against {rel}");
            }
            println!("frame {}: {g:?}", f.frame);
        }
    }
    if reached >= 6 {
        assert_eq!(r.summary.gap_frames, 2);
        let (m, p) = (r.summary.gap_mean.unwrap(), r.summary.gap_p95.unwrap());
        assert!(m >= -1e-6 && p >= m - 1e-12, "mean {m}, p95 {p}");
        let abs: Vec<f64> = r
            .frames
            .iter()
            .filter_map(|f| f.gap.filter(|g| g.relative.is_some()))
            .map(|g| g.model - g.optimum)
            .collect();
        let abs_mean = abs.iter().sum::<f64>() / abs.len() as f64;
        assert!((r.summary.gap_abs_mean.unwrap() - abs_mean).abs() <= 1e-12 * abs_mean.abs().max(1e-9));
        let parts = r.summary.gap_by_term.unwrap();
        assert!((parts.total() - m).abs() <= 1e-6 * m.abs().max(1.0), "{parts:?} against {m}");
    }
    let images = strip_images(&scene, &r.kept, 60, 100);
    assert_eq!(images.len(), r.kept.len());
    // Something other than background was drawn.
    assert!(images.iter().all(|im| im.rgb.chunks(3).any(|c| c != [245, 245, 240])));
}

#[test]
fn eval_frame_objective_matches_the_physics_rollout_score() {
    // Without pins, from frame 3 on the runtime's velocity is the frame difference that
    // `score_rollout` derives: both scorings must agree (to f32 rounding of the velocity).
    let frames = 6;
    let scene = procedural(&Mannequin::new(), GarmentKind::Dress, 300, MotionKind::Walk, 0.5).unwrap();
    let mut scene = Playback::record(&scene, frames + 1).unwrap();
    let n = scene.garment.n_vertices();
    scene.garment.set_pinned(&vec![false; n]).unwrap();
    let bytes = random_model(16, 11, false);
    let model = bytes.model().unwrap();
    let opts = RolloutOptions::default().with_keep((0..=frames).collect());
    let r = rollout(&model, &scene, frames, SimConfig::network(), &opts).unwrap();
    assert!(r.failure.is_none(), "{:?}", r.failure);
    let garment: Vec<Vec<[f32; 3]>> = r.kept.iter().map(|k| k.1.clone()).collect();
    let body: Vec<Vec<[f32; 3]>> = scene.body_frames.clone();
    let s = score_rollout(
        &scene.garment,
        &Objective::evaluation(),
        &garment,
        &body,
        scene.body.as_ref().unwrap().faces(),
        1.0 / 30.0,
    )
    .unwrap();
    for t in 3..=frames {
        let ours = r.frames[t - 1].terms.unwrap();
        let theirs = s.frames[t - 1].terms;
        for ((name, a), (_, b)) in ours.named().iter().zip(theirs.named()) {
            assert!((a - b).abs() <= 1e-4 * b.abs().max(1e-6), "frame {t} {name}: {a} vs {b}");
        }
        let (pa, pb) = (r.frames[t - 1].penetrating_percent, s.frames[t - 1].penetrating_percent);
        assert!((pa - pb).abs() < 1e-9, "frame {t} penetration {pa} vs {pb}");
        assert!((r.frames[t - 1].max_edge_strain - s.frames[t - 1].max_edge_strain).abs() < 1e-9);
    }
}

#[test]
fn eval_cloth_without_body_and_bad_requests() {
    let (rest, faces) = hood::mesh::shapes::grid(6, 6, 0.5, 0.5, 1.0);
    let mut pinned = vec![false; rest.len()];
    pinned[0] = true;
    let g = hood::mesh::Garment::new(hood::mesh::GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let anim = Playback::cloth_only(g, 10);
    let bytes = random_model(16, 3, false);
    let model = bytes.model().unwrap();
    let opts = RolloutOptions::default().with_gap_every(2);
    let r = rollout(&model, &anim, 5, SimConfig::network(), &opts).unwrap();
    assert!(r.frames.iter().all(|f| f.penetrating_percent == 0.0));
    assert!(r.frames.iter().all(|f| f.terms.unwrap().collision == 0.0 && f.terms.unwrap().friction == 0.0));
    assert!(matches!(rollout(&model, &anim, 0, SimConfig::network(), &opts), Err(hood::Error::Empty { .. })));
    assert!(matches!(rollout(&model, &anim, 10, SimConfig::network(), &opts), Err(hood::Error::OutOfRange { .. })));
    // From common states without a body: the reference's contact terms are dropped too, so the
    // converged step of the training objective is the evaluation objective's optimum.
    use hood::eval::{common_state_gaps, converged_solver, Method, Reference};
    let methods = [Method::Network { model: &model, cfg: SimConfig::network() }, Method::Implicit(converged_solver())];
    let out = common_state_gaps(&anim, 5, &methods, Reference::Converged(Objective::training(5e5)), &opts).unwrap();
    assert!(out[0].frames.iter().all(|f| f.terms.unwrap().collision == 0.0 && f.penetrating_percent == 0.0));
    assert!(out[1].summary.gap_mean.unwrap().abs() < 1e-9, "{:?}", out[1].summary);
    let past = common_state_gaps(&anim, 10, &methods, Reference::Converged(Objective::training(5e5)), &opts);
    assert!(matches!(past, Err(hood::Error::OutOfRange { .. })));
}

#[test]
fn eval_implicit_rollout_gap_is_zero_when_converged_and_below_one_when_truncated() {
    use hood::eval::{converged_solver, implicit_rollout};
    let m = Mannequin::with_spacing(0.04).unwrap();
    let scene = procedural(&m, GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
    let opts = RolloutOptions::default().with_gap_every(2);
    let frames = 6;
    // Converged solves from the same states are the optimum itself.
    let r = implicit_rollout(&scene, frames, &converged_solver(), &opts, &mut |_, _| Ok(())).unwrap();
    assert!(r.failure.is_none());
    for g in r.frames.iter().filter_map(|f| f.gap) {
        assert!(g.relative.unwrap().abs() < 1e-9, "{g:?}");
    }
    // Two L-BFGS iterations descend (gap ≤ 1) without reaching the optimum (gap > 0).
    let two = converged_solver().with_max_iterations(2);
    let r = implicit_rollout(&scene, frames, &two, &opts, &mut |_, _| Ok(())).unwrap();
    assert_eq!(r.summary.gap_frames, 3);
    for g in r.frames.iter().filter_map(|f| f.gap) {
        let rel = g.relative.unwrap();
        println!("2 iterations: {g:?}");
        assert!(rel > 1e-6 && rel <= 1.0 + 1e-9, "{g:?}");
    }
    println!("{:?}", r.summary);
    // The penetration and strain of a physical solve stay small.
    assert!(r.summary.max_edge_strain < 1.0);
}

/// The runtime's own solver refinement (f32, in the step) closes the gap the evaluation measures
/// against the converged f64 implicit step of the same (training-form) objective: a few
/// iterations improve on the model alone, enough of them reach the optimum to f32 precision.
#[test]
fn eval_runtime_refinement_closes_the_gap() {
    use hood::sim::REFINE_COLLISION_WEIGHT;
    let m = Mannequin::with_spacing(0.04).unwrap();
    let scene = procedural(&m, GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let frames = 6;
    let run = |refine: Option<u32>| {
        let opts =
            RolloutOptions::default().with_gap_every(2).with_objective(Objective::training(REFINE_COLLISION_WEIGHT));
        let r = rollout(&model, &scene, frames, SimConfig::network().with_refine(refine), &opts).unwrap();
        assert!(r.failure.is_none(), "{:?}", r.failure);
        r.summary.gap_mean.unwrap()
    };
    let (alone, three, many) = (run(None), run(Some(3)), run(Some(200)));
    println!("gap: model alone {alone:.3}, + 3 iterations {three:.3}, + 200 iterations {many:.2e}");
    assert!(three < 0.8 * alone, "three iterations improve on the model alone");
    assert!(many < 1e-3, "enough iterations reach the optimum");
}

/// `hood simulate` end to end on a random model: the OBJ sequence and the preview strip appear.
#[cfg(feature = "cli")]
#[test]
fn eval_cli_simulate_writes_obj_sequence_strip_and_animation() {
    let out = std::env::temp_dir().join(format!("hood-simulate-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["simulate", "--random-model", "16", "--garment", "skirt", "--vertices", "300", "--frames", "3"])
        .args(["--strip", "2", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    for f in ["garment_0000.obj", "garment_0003.obj", "body_0003.obj", "preview.png"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let g = hood::io::obj::Obj::read(out.join("garment_0003.obj")).unwrap();
    assert!(g.positions.len() > 200 && g.positions.iter().all(|p| p.iter().all(|c| c.is_finite())));
    // The animated preview: frames 0 and 2 of 3, at 15 per second, each a picture of the scene
    // (not blank).
    let bytes = std::fs::read(out.join("animation.png")).unwrap();
    let decoder = png::Decoder::new(std::io::Cursor::new(&bytes[..])).read_info().unwrap();
    assert_eq!(decoder.info().animation_control.map(|c| c.num_frames), Some(2));
    let first = hood::io::png::decode(&bytes).unwrap();
    assert!(first.rgb.chunks(3).filter(|px| px != &[245, 245, 240]).count() > first.rgb.len() / 30);
    // An unknown garment is a clear error, not a panic.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["simulate", "--random-model", "16", "--garment", "poncho", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown garment"), "{}", String::from_utf8_lossy(&o.stderr));
    // A lead-in from the rest pose needs the MakeHuman body's rest; the mannequin has none.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["simulate", "--random-model", "16", "--garment", "skirt", "--lead-in", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--lead-in need a MakeHuman garment"), "{err}");
    let _ = std::fs::remove_dir_all(&out);
}

/// `hood simulate` runs the model it is given: a named model steps the garment unless `--solver`
/// says otherwise, and with no model named the default step (the solver) runs. The scene line
/// says which.
#[cfg(feature = "cli")]
#[test]
fn eval_cli_simulate_runs_the_model_it_is_named() {
    let out = std::env::temp_dir().join(format!("hood-simulate-step-test-{}", std::process::id()));
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood");
    let steps = |extra: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
            .args(["simulate", "--garment", "skirt", "--vertices", "300", "--frames", "1", "--no-obj", "--out"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{err}");
        let line = err.lines().find(|l| l.starts_with("scene:")).expect("a scene line").to_string();
        line.split_once("steps: ").expect("the step on the scene line").1.to_string()
    };
    assert!(steps(&[]).starts_with("the solver, 30 iterations"), "{}", steps(&[]));
    assert_eq!(steps(&["--model", model]), format!("the network ({model})"));
    assert_eq!(steps(&["--random-model", "16"]), "the network (a random model, h = 16)");
    assert!(steps(&["--model", model, "--solver", "10"]).starts_with("the solver, 10 iterations"));
    assert_eq!(steps(&["--refine", "3"]), "the network (the shipped compact model), refined by 3 iterations");
    let _ = std::fs::remove_dir_all(&out);
}

/// `hood validate` measures what the model cards' `hood simulate` command measures (the same
/// figures to the printed digit), runs its rollouts in parallel without changing them (two
/// copies of one file give identical rows), writes the table and one strip per rollout (named by
/// folder and stem when two files share a stem), and refuses an unknown scene.
#[cfg(feature = "cli")]
#[test]
fn eval_cli_validate_matches_simulate_and_is_deterministic_in_parallel() {
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood");
    let out = std::env::temp_dir().join(format!("hood-validate-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(out.join("a")).unwrap();
    let copy = out.join("a").join("compact.hood");
    std::fs::copy(model, &copy).unwrap();
    let hood = |args: &[&str]| std::process::Command::new(env!("CARGO_BIN_EXE_hood")).args(args).output().unwrap();
    let text = |o: &std::process::Output| String::from_utf8_lossy(&o.stdout).into_owned();
    let tables = out.join("tables");
    // The skirt, 10 frames, gap every 5th: validate takes files and options, simulate options.
    let validate = |files: &[&str], extra: &[&str]| {
        let mut args = vec!["validate"];
        args.extend(files);
        args.extend(["--scenes", "skirt", "--frames", "10", "--gap-every", "5"]);
        args.extend(extra);
        hood(&args)
    };
    let sim_out = out.join("sim");
    let simulate = |extra: &[&str]| {
        // The network's step (`--solver 0`), which validate scores.
        let mut args = vec!["simulate", "--model", model, "--solver", "0", "--garment", "skirt", "--vertices", "500"];
        args.extend(["--frames", "10", "--gap-every", "5", "--objective", "training", "--no-obj"]);
        args.extend(["--out", sim_out.to_str().unwrap()]);
        args.extend(extra);
        hood(&args)
    };
    let o = validate(&[model, copy.to_str().unwrap()], &["--jobs", "2", "--out", tables.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = text(&o);
    let rows: Vec<Vec<&str>> = table
        .lines()
        .filter(|l| l.starts_with("| models-compact ") || l.starts_with("| a-compact "))
        .map(|l| l.split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.len(), 2, "{table}");
    // Every figure but the name and the wall time (the last column) agrees.
    let n = rows[0].len();
    assert_eq!(rows[0][2..n - 2], rows[1][2..n - 2], "{table}");
    assert_eq!(std::fs::read_to_string(tables.join("validation.md")).unwrap().lines().count(), 12);
    // The off-body verdict leads: the skirt stays on, and the closing line counts it.
    assert_eq!(rows[0][4], "yes", "{table}");
    assert!(table.contains("models-compact 1 of 1, a-compact 1 of 1."), "{table}");
    // The split's means over all scenes and over the kept ones: the same for the two copies; with
    // the one scene kept, the kept means are the means, and they are the row's figures.
    let split = |name: &str| {
        let from = table.find(&format!("{name}: absolute gap ")).expect("the split line names every model");
        table[from + name.len()..].split(['\n', ';']).next().unwrap().trim_end_matches('.').to_owned()
    };
    let one = split("models-compact");
    assert_eq!(one, split("a-compact"), "{table}");
    let numbers: Vec<f64> =
        one.split(|c: char| !(c.is_ascii_digit() || c == '.')).filter_map(|t| t.parse().ok()).collect();
    // absolute gap (kept), penetrating (kept), the strain goal, strained (kept), largest kept.
    assert_eq!(numbers.len(), 8, "{one}");
    assert_eq!((numbers[0], numbers[2]), (numbers[1], numbers[3]), "{one}");
    assert_eq!(numbers[2], rows[0][15].parse::<f64>().unwrap(), "{table}");
    let strain: f64 = rows[0][17].parse().unwrap();
    assert_eq!(numbers[7], strain, "{table}");
    let strained = f64::from(u8::from(strain > 1.5));
    assert_eq!((numbers[5], numbers[6]), (strained, strained), "{one}");
    let met = strain <= 1.5 && numbers[2] < 2.0;
    assert!(one.ends_with(if met { "goals met" } else { "goals not met" }), "{one}");
    for f in ["models-compact-skirt.png", "a-compact-skirt.png"] {
        assert!(tables.join(f).exists(), "{f} missing");
    }
    // The own-rollout gap and the figures from common states, as `hood simulate` prints them.
    let o = simulate(&["--inside-every", "5", "--common-states"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sim = text(&o);
    let after = |s: &str, key: &str| s.split(key).nth(1).and_then(|t| t.split([',', ' ']).next()).map(str::to_owned);
    let own = after(&sim, "; relative gap mean ").unwrap();
    let common = after(&sim, "training objective): relative gap mean ").unwrap();
    assert!(rows[0][9].starts_with(&format!("{own} (")), "simulate {own}, validate {}", rows[0][9]);
    assert!(rows[0][12].starts_with(&format!("{common} (")), "simulate {common}, validate {}", rows[0][12]);
    assert!(sim.contains("garment on the body (worn vertices over 10 cm off: max 0.0 %"), "{sim}");
    let means = format!("over the 1 scene(s): models-compact {own}, a-compact {own}.");
    assert!(table.contains(&means), "{table}");
    // The worn centroid's shift, in cm as simulate's verdict gives it.
    assert_eq!(Some(rows[0][7].to_string()), after(&sim, "shift max "), "{sim}");
    let strain = after(&sim, "largest strain ").unwrap();
    assert_eq!(rows[0][17], strain);
    let long = after(&sim, &format!("largest strain {strain} (")).unwrap();
    assert_eq!(rows[0][18], long);
    assert!(long.parse::<f64>().unwrap() <= strain.parse::<f64>().unwrap());
    let objective = after(&sim, "objective mean ").unwrap();
    assert_eq!(rows[0][13], objective.trim_end_matches(';'));
    // The peak is the largest of the per-frame objectives simulate prints, past frame 1.
    let peak = sim
        .lines()
        .filter(|l| l.starts_with("frame") && !l.contains("(with start-up step)"))
        .filter_map(|l| Some((l.split("objective").nth(1)?.split_whitespace().next()?.parse::<f64>().ok()?, l)))
        .fold(0.0f64, |m, (e, _)| m.max(e));
    let shown: f64 = rows[0][14].split(' ').next().unwrap().parse().unwrap();
    assert!((shown - peak).abs() <= 0.006 + 1e-4 * peak, "validate {shown}, simulate {peak}");
    // The model alone with `extra` options: validate's table and the model's row, and what
    // simulate prints with the same options.
    let validated = |extra: &[&str], dir: &str| {
        let dir = out.join(dir);
        let mut args = extra.to_vec();
        args.extend(["--no-common-states", "--out", dir.to_str().unwrap()]);
        let o = validate(&[model], &args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let table = text(&o);
        let row = table.lines().find(|l| l.starts_with("| compact ")).unwrap();
        let row: Vec<String> = row.split('|').map(|c| c.trim().to_string()).collect();
        (table, row)
    };
    let simulated = |extra: &[&str]| {
        let o = simulate(extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        text(&o)
    };
    // With the refinement effect, validate scores what `simulate --refine` scores, closer to
    // the optimum than the model alone.
    let (table, refined) = validated(&["--refine", "5"], "refined");
    assert!(table.contains(", 5 refinement iterations per step"), "{table}");
    let gap = after(&simulated(&["--refine", "5"]), "; relative gap mean ").unwrap();
    assert!(refined[9].starts_with(&format!("{gap} (")), "simulate --refine 5 {gap}, validate {}", refined[9]);
    // The absolute gap (J, in parentheses) is what a few iterations from the prediction cut; the
    // relative one also moves with the descent available at the (now different) states.
    let absolute = |cell: &str| {
        let inner = cell.split('(').nth(1).unwrap().trim_end_matches(')');
        let (value, unit) = inner.split_once(' ').unwrap();
        value.parse::<f64>().unwrap() * if unit == "mJ" { 1e-3 } else { 1.0 }
    };
    assert!(absolute(&refined[9]) < absolute(rows[0][9]), "refined {}, model alone {}", refined[9], rows[0][9]);
    // `--material` remakes every garment, in validate as in simulate: the same objective, and
    // not the one of the garment's own material.
    let (table, stiff) = validated(&["--material", "stiff-bend"], "stiff");
    assert!(table.contains(", every garment made of stiff-bend ("), "{table}");
    let objective = after(&simulated(&["--material", "stiff-bend"]), "objective mean ").unwrap();
    assert_eq!(stiff[13], objective.trim_end_matches(';'), "{table}");
    assert_ne!(stiff[13], rows[0][13], "stiff bending changes the objective");
    let o = hood(&["validate", model, "--scenes", "skirt", "--material", "rubber"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("rubber"));
    let o = hood(&["validate", model, "--scenes", "poncho"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("unknown scene"));
    let _ = std::fs::remove_dir_all(&out);
}

/// `hood info m.hood | head` must not panic: output into a closed pipe ends the command quietly.
#[cfg(feature = "cli")]
#[test]
fn eval_cli_output_into_a_closed_pipe_ends_quietly() {
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["info", model])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Closed before the command has read the model, so its first line meets a broken pipe.
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && !stderr.contains("panicked"), "{:?}: {stderr}", o.status);
}

#[test]
fn eval_counts_vertices_inside_the_body_on_the_picked_frames() {
    use hood::body::winding_number_exact;
    let frames = 6;
    let scene = procedural(&Mannequin::new(), GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
    let mut scene = Playback::record(&scene, frames + 1).unwrap();
    // Sink a third of the garment 3 cm into the body, so that there is something to count.
    let mesh = scene.body.clone().unwrap();
    let body0 = scene.body_frames[0].clone();
    let mut normals = vec![[0.0f32; 3]; body0.len()];
    mesh.vertex_normals(&body0, &mut normals).unwrap();
    let grid = {
        let mut g = hood::body::PointGrid::new(body0.len(), 8 * body0.len()).unwrap();
        g.rebuild(&body0).unwrap();
        g
    };
    for (i, p) in scene.initial.iter_mut().enumerate().filter(|(i, _)| i % 3 == 0) {
        let b = grid.nearest_one(*p).unwrap().index as usize;
        *p = [0, 1, 2].map(|a| body0[b][a] - 0.03 * normals[b][a]);
        assert!(i < scene.garment.n_vertices());
    }
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let opts = RolloutOptions::default().with_inside_every(2).with_keep((0..=frames).collect());
    let r = rollout(&model, &scene, frames, SimConfig::network(), &opts).unwrap();
    let mut counted = 0;
    for f in &r.frames {
        assert_eq!(f.inside_percent.is_some(), f.frame % 2 == 0, "frame {}", f.frame);
        let Some(pct) = f.inside_percent else { continue };
        let pos = &r.kept.iter().find(|k| k.0 == f.frame).unwrap().1;
        let body = &scene.body_frames[f.frame];
        let w: Vec<f64> = pos.iter().map(|p| winding_number_exact(mesh.faces(), body, p.map(|c| c as f64))).collect();
        let sure = w.iter().filter(|w| w.abs() > 0.55).count();
        let unsure = w.iter().filter(|w| (0.45..=0.55).contains(&w.abs())).count();
        let got = pct / 100.0 * pos.len() as f64;
        assert!(
            got + 0.5 >= sure as f64 && got - 0.5 <= (sure + unsure) as f64,
            "frame {}: {got} vs {sure}+{unsure}",
            f.frame
        );
        println!("frame {}: {pct:.1} % inside (exact: {sure}, {unsure} ambiguous)", f.frame);
        counted += 1;
    }
    assert_eq!(r.summary.inside_frames, counted);
    assert!(counted >= 1 && r.summary.inside_mean.unwrap() > 5.0, "{:?}", r.summary);
    assert!(r.summary.inside_max.unwrap() >= r.summary.inside_mean.unwrap());
}

/// One step from common states: the reference states are those of the converged implicit
/// rollout, every method is scored against the converged step from them (the converged method
/// itself at zero gap, truncated solves and a refined network in between), and methods do not
/// affect each other.
#[test]
fn eval_common_states_score_every_method_from_the_reference_states() {
    use hood::eval::{common_state_gaps, converged_solver, implicit_rollout, Method, Reference};
    use hood::sim::REFINE_COLLISION_WEIGHT;
    let m = Mannequin::with_spacing(0.04).unwrap();
    let scene = procedural(&m, GarmentKind::Skirt, 300, MotionKind::Walk, 0.5).unwrap();
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let frames = 6;
    let training = Objective::training(REFINE_COLLISION_WEIGHT);
    let opts = RolloutOptions::default().with_gap_every(2).with_objective(training);
    let two = converged_solver().with_max_iterations(2);
    let methods = [
        Method::Network { model: &model, cfg: SimConfig::network() },
        Method::Network { model: &model, cfg: SimConfig::network().with_refine(Some(200)) },
        Method::Implicit(converged_solver()),
        Method::Implicit(two),
    ];
    let out = common_state_gaps(&scene, frames, &methods, Reference::Converged(training), &opts).unwrap();
    assert_eq!(out.len(), methods.len());
    for r in &out {
        assert!(r.failure.is_none(), "{:?}", r.failure);
        assert_eq!(r.frames.iter().map(|f| f.frame).collect::<Vec<_>>(), [2, 4, 6]);
        assert!(r.frames.iter().all(|f| f.kind == StepKind::Stepped && f.gap.is_some()));
        assert_eq!(r.summary.gap_frames, 3);
        // Every method is compared with the same optimum.
        for (f, g) in r.frames.iter().zip(&out[2].frames) {
            assert_eq!(f.gap.unwrap().optimum, g.gap.unwrap().optimum);
            assert_eq!(f.gap.unwrap().coasting, g.gap.unwrap().coasting);
        }
    }
    let gap = |i: usize| out[i].summary.gap_mean.unwrap();
    println!(
        "gap from common states: network {:.3}, + refine 200 {:.2e}, converged {:.1e}, 2 it. {:.3}",
        gap(0),
        gap(1),
        gap(2),
        gap(3)
    );
    assert!(gap(2).abs() < 1e-9, "the converged step is the optimum");
    assert!(gap(3) > 1e-6 && gap(3) <= 1.0 + 1e-9);
    assert!(gap(1) < 1e-3 && gap(1) < gap(0));
    // The states are those of the converged implicit rollout: the converged method's scores
    // there are that rollout's.
    let own = implicit_rollout(&scene, frames, &converged_solver(), &opts, &mut |_, _| Ok(())).unwrap();
    for f in &out[2].frames {
        let o = &own.frames[f.frame - 1];
        assert_eq!((o.frame, o.terms, o.max_edge_strain), (f.frame, f.terms, f.max_edge_strain));
    }
    // A method alone scores as it does among others.
    let alone = common_state_gaps(&scene, frames, &methods[..1], Reference::Converged(training), &opts).unwrap();
    for (a, b) in alone[0].frames.iter().zip(&out[0].frames) {
        assert_eq!((a.terms, a.gap, a.max_edge_strain), (b.terms, b.gap, b.max_edge_strain));
    }
    // Scored under another objective than the reference's: the optimum is that objective's.
    let eval_opts = opts.clone().with_objective(Objective::evaluation());
    let other = common_state_gaps(&scene, frames, &methods[2..], Reference::Converged(training), &eval_opts).unwrap();
    let g = other[0].summary.gap_mean.unwrap();
    assert!(g.abs() < 1e-9, "converged under the scoring objective: {g}");
    assert!(other[1].summary.gap_mean.unwrap() > 1e-6);
    // From a runtime reference, the model scores as on its own rollout (past the start-up step).
    let net = &methods[..1];
    let from_own =
        common_state_gaps(&scene, frames, net, Reference::Network { model: &model, cfg: SimConfig::network() }, &opts)
            .unwrap();
    let own = rollout(&model, &scene, frames, SimConfig::network(), &opts).unwrap();
    assert!(own.failure.is_none());
    for f in &from_own[0].frames {
        let o = &own.frames[f.frame - 1];
        assert_eq!((o.frame, o.kind, o.terms, o.gap), (f.frame, f.kind, f.terms, f.gap));
        assert_eq!((o.max_edge_strain, o.penetrating_percent), (f.max_edge_strain, f.penetrating_percent));
    }
    assert!(matches!(
        common_state_gaps(&scene, 0, &methods, Reference::Converged(training), &opts),
        Err(hood::Error::Empty { .. })
    ));
}

/// A scene that starts in mid-motion starts its garment moving with the body: the initial
/// velocity is the skinned garment's displacement into frame 1, a recorded playback keeps it,
/// and the implicit rollout starts from it (the garment's first-frame displacement follows the
/// body's, where a garment at rest would lag behind by a whole frame's travel).
#[test]
fn eval_a_clip_starting_at_speed_starts_its_garment_moving() {
    use hood::eval::{converged_solver, implicit_rollout, Animation};
    let m = Mannequin::with_spacing(0.04).unwrap();
    let scene = procedural(&m, GarmentKind::Skirt, 300, MotionKind::Run, 0.5).unwrap();
    let n = scene.garment.n_vertices();
    let v0 = Animation::initial_velocity(&scene).unwrap();
    let (mut a, mut b) = (vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]);
    scene.skinned_garment(0, &mut a).unwrap();
    scene.skinned_garment(1, &mut b).unwrap();
    for i in 0..n {
        assert_eq!(v0[i], [b[i][0] - a[i][0], b[i][1] - a[i][1], b[i][2] - a[i][2]], "vertex {i}");
    }
    assert_eq!(scene.initial_velocity(3).unwrap()[7], {
        scene.skinned_garment(2, &mut a).unwrap();
        scene.skinned_garment(3, &mut b).unwrap();
        [b[7][0] - a[7][0], b[7][1] - a[7][1], b[7][2] - a[7][2]]
    });
    // Along the body's travel in the first frame (its centroid's displacement).
    let centroid = |v: &[[f32; 3]]| {
        let s = v.iter().fold([0.0f64; 3], |s, p| [s[0] + p[0] as f64, s[1] + p[1] as f64, s[2] + p[2] as f64]);
        s.map(|c| c / v.len() as f64)
    };
    let (c0, c1) = (centroid(scene.body_frame(0)), centroid(scene.body_frame(1)));
    let travel = [c1[0] - c0[0], c1[1] - c0[1], c1[2] - c0[2]];
    let body_dx = (travel[0] * travel[0] + travel[1] * travel[1] + travel[2] * travel[2]).sqrt();
    let dir = travel.map(|c| c / body_dx);
    let mean_x = |v: &[[f32; 3]]| {
        let c = centroid(v);
        c[0] * dir[0] + c[1] * dir[1] + c[2] * dir[2]
    };
    assert!(body_dx.abs() > 0.02, "the run starts at speed: {body_dx} m in the first frame");

    let recorded = Playback::record(&scene, 4).unwrap();
    assert_eq!(recorded.initial_velocity().unwrap(), v0);
    let mut at_rest = recorded.clone();
    at_rest.initial_velocity.clear();
    assert!(at_rest.initial_velocity().unwrap().iter().all(|v| *v == [0.0; 3]));
    let mut bad = recorded.clone();
    bad.initial_velocity.pop();
    assert!(matches!(bad.initial_velocity(), Err(hood::Error::SizeMismatch { .. })));

    let opts = RolloutOptions::default().with_keep(vec![1]);
    let first_dx = |anim: &Playback| {
        let r = implicit_rollout(anim, 1, &converged_solver(), &opts, &mut |_, _| Ok(())).unwrap();
        mean_x(&r.kept[0].1) - mean_x(&anim.initial)
    };
    let (moving, resting) = (first_dx(&recorded), first_dx(&at_rest));
    println!("first frame: body {body_dx:.4} m, garment {moving:.4} m moving, {resting:.4} m from rest");
    assert!((moving - body_dx).abs() < 0.25 * body_dx.abs(), "{moving} vs {body_dx}");
    assert!((resting - body_dx).abs() > 0.5 * body_dx.abs(), "{resting} vs {body_dx}");
}

/// `hood bench` takes one timed step of every row of a workload per round, and one timed forward
/// of the reference per thread count per round (a stand-in script here, which answers with fixed
/// times and records what it was asked): every row and the reference get one time per round, and
/// the report carries the reference's times.
#[cfg(feature = "cli")]
#[test]
fn eval_cli_bench_times_every_row_and_the_reference_in_rounds() {
    let json_rows = |stdout: &[u8]| -> serde_json::Value {
        let text = String::from_utf8_lossy(stdout);
        serde_json::from_str(text.lines().rev().find(|l| l.starts_with('{')).expect("a JSON line")).unwrap()
    };
    // The procedural workload: four network rows and two solver rows, three rounds each.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["bench", "--workload", "grid-1k", "--latent", "16", "--precision", "f32,bf16", "--threads", "1,2"])
        .args(["--solver", "5", "--steps", "3", "--warmup", "1", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bench = json_rows(&o.stdout);
    let rows = bench["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 6, "{bench}");
    for r in rows {
        let times = r["times_ms"].as_array().unwrap();
        assert_eq!(times.len(), 3, "{r}");
        assert!(times.iter().all(|t| t.as_f64().is_some_and(|t| t > 0.0)), "{r}");
    }

    // The reference, served: needs the parity fixtures for the `tee` workload's scene.
    let assets = common::shared_dir().join("assets");
    let weights = common::shared_dir().join("fixtures/hood-parity/fixture_weights.safetensors");
    if !weights.exists() {
        common::skip("eval_cli_bench_times_every_row_and_the_reference_in_rounds (reference)", &weights);
        return;
    }
    if std::process::Command::new("python3").arg("--version").output().is_err() {
        println!("SKIPPED eval_cli_bench_times_every_row_and_the_reference_in_rounds (reference): no python3");
        return;
    }
    let dir = std::env::temp_dir().join(format!("hood-bench-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let asked = dir.join("asked.txt");
    let script = dir.join("fake_reference.py");
    std::fs::write(
        &script,
        format!(
            "import json, sys\nassert '--serve' in sys.argv\nlog = open({:?}, 'w')\n\
             print('loading (not an answer)', flush=True)\n\
             print(json.dumps({{'ready': True, 'vertices': 1311, 'torch': 'stand-in'}}), flush=True)\n\
             for line in sys.stdin:\n    t = int(line)\n    log.write(f'{{t}}\\n'); log.flush()\n    \
             print(json.dumps({{'vertices': 1311, 'threads': t, 'seconds': 0.5 * t, 'torch': 'stand-in'}}), flush=True)\n",
            asked.display().to_string()
        ),
    )
    .unwrap();
    let report = dir.join("report.md");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
        .args(["bench", "--workload", "tee", "--latent", "16", "--precision", "f32", "--threads", "1,2"])
        .args(["--steps", "2", "--warmup", "0", "--reference", "python3", "--reference-script"])
        .arg(&script)
        .arg("--assets")
        .arg(&assets)
        .arg("--markdown")
        .arg(&report)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // In each of the two rounds, at each thread count in turn, an untimed forward (the round's
    // warm-up) and a timed one.
    assert_eq!(std::fs::read_to_string(&asked).unwrap(), "1\n1\n2\n2\n1\n1\n2\n2\n");
    let text = std::fs::read_to_string(&report).unwrap();
    assert!(text.contains("| x 1 thread | x f32 | latency ns | hand-offs | in jobs | busy | x reference |"), "{text}");
    assert!(
        text.contains("| tee | 1311 | 1 | 500.0 | 500.0 |") && text.contains("| tee | 1311 | 2 | 1000.0 | 1000.0 |"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
