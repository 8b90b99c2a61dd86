//! Training runs: the config format, the schedules, exact resumption from a checkpoint, and the
//! exported model running in the runtime.
#![cfg(feature = "train")]

use hood::scene::{GarmentKind, MotionKind};
use hood::train::{Dataset, SceneSource, TrainConfig, Trainer};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A run small enough for debug-mode tests: h = 8, a two-level schedule, a 64-vertex cape.
fn tiny_config() -> TrainConfig {
    TrainConfig::default()
        .with_latent(8)
        .with_levels(2)
        .with_schedule("f,c0 | d:c0,c1 | u:f,c0".into())
        .with_warmup_iterations(2)
        .with_rollout_every(2)
        .with_rollout_max(3)
        .with_validation((1, 4))
        .with_scenes(vec![SceneSource::Procedural {
            garment: GarmentKind::Cape,
            vertices: 64,
            motion: MotionKind::ArmSwings,
            seconds: 1.0,
        }])
}

fn data(cfg: &TrainConfig) -> Dataset {
    Dataset::build(cfg, Path::new("/nonexistent"), |_| {}).unwrap()
}

#[test]
fn train_config_json_round_trip() {
    let c = TrainConfig::default();
    let back = TrainConfig::from_json(&c.to_json()).unwrap();
    assert_eq!(back, c);
    let t = tiny_config();
    assert_eq!(TrainConfig::from_json(&t.to_json()).unwrap(), t);
    let e = TrainConfig::from_json("{\"latnet\": 32}").unwrap_err().to_string();
    assert!(e.contains("latnet"), "{e}");
    assert!(TrainConfig::from_json("{\"scenes\": [{\"garment\": \"hat\", \"motion\": \"walk\"}]}").is_err());
    assert!(TrainConfig::from_json("{\"latent\": -3}").is_err());
    // Corpus clips parse by name, on procedural and MakeHuman garments, and round-trip.
    let corpus = r#"{"scenes": [{"garment": "dress", "motion": "dance-4", "seconds": 2},
        {"garment": "tee", "frames": 30, "motion": "cartwheel-2"}]}"#;
    let c = TrainConfig::from_json(corpus).unwrap();
    assert_eq!(TrainConfig::from_json(&c.to_json()).unwrap(), c);
    assert_eq!(c.scenes[1].name(), "makehuman-tee/cartwheel-2");
    // The held-out split cannot be trained on.
    for motion in ["jumps-1000", "backflip-3", "random-1001"] {
        let text = format!(r#"{{"scenes": [{{"garment": "tee", "motion": "{motion}"}}]}}"#);
        let e = TrainConfig::from_json(&text).unwrap_err().to_string();
        assert!(e.contains("held out"), "{motion}: {e}");
    }
    // So can the held-out garments; the other outfit pieces can be trained on.
    for garment in ["male-tee", "male-jeans"] {
        let text = format!(r#"{{"scenes": [{{"garment": "{garment}"}}]}}"#);
        let e = TrainConfig::from_json(&text).unwrap_err().to_string();
        assert!(e.contains("held out"), "{garment}: {e}");
    }
    let c = TrainConfig::from_json(r#"{"scenes": [{"garment": "crop-top", "motion": "dance-6"}]}"#).unwrap();
    assert_eq!(c.scenes[0].name(), "makehuman-crop-top/dance-6");
}

/// The configs committed beside the shipped models and the specialists (the record of how each
/// was trained, and what `--config` / `--scenes-from` read to continue) parse, and a
/// `NAME.*.json` that sets the model's shape describes the shape of `NAME.hood` beside it.
#[test]
fn train_committed_configs_parse_and_match_their_models() {
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut checked = 0;
    let entries = [models.clone(), models.join("specialists")]
        .into_iter()
        .flat_map(|dir| std::fs::read_dir(&dir).unwrap().map(move |e| (dir.clone(), e.unwrap().path())));
    for (dir, path) in entries {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if !name.ends_with(".json") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let cfg = TrainConfig::from_json(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!cfg.scenes.is_empty(), "{name}: no scenes");
        let model = dir.join(format!("{}.hood", name.split('.').next().unwrap()));
        if text.contains("\"latent\"") && model.exists() {
            let bytes = hood::model::ModelBytes::read(&model).unwrap();
            assert_eq!(&cfg.spec().unwrap(), bytes.model().unwrap().spec(), "{name}");
            checked += 1;
        }
    }
    assert!(checked >= 8, "only {checked} configs compared with a model file");
}

#[test]
fn train_schedules_follow_the_recipe() {
    let c = TrainConfig::default();
    assert_eq!(c.rollout_length(0), 1);
    assert_eq!(c.rollout_length(4_999), 1);
    assert_eq!(c.rollout_length(5_000), 2);
    assert_eq!(c.rollout_length(1_000_000), 5);
    assert!((c.collision_weight_at(0) - 5e3).abs() < 1e-6);
    assert!((c.collision_weight_at(c.collision_ramp / 2) - 5e4).abs() < 1e-3 * 5e4);
    assert!((c.collision_weight_at(10 * c.collision_ramp) - 5e5).abs() < 1e-6);
    assert!((c.learning_rate_at(0) - 5e-5 * 1.01).abs() < 1e-15);
    assert!((c.learning_rate_at(50_000) - 5e-5 * 0.51).abs() < 1e-15);
}

#[test]
fn train_resume_is_exact() {
    resume_is_exact(tiny_config());
    // With carried rollouts the checkpoint holds the tracks' states too.
    resume_is_exact(tiny_config().with_carry((2, 0.0)));
    // With a weight average the checkpoint holds the average too.
    resume_is_exact(tiny_config().with_ema(0.9));
}

fn resume_is_exact(cfg: TrainConfig) {
    let total = 7;
    let mut straight = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    let mut expected = Vec::new();
    for _ in 0..total {
        expected.push(straight.iteration().unwrap());
    }
    assert!(expected.iter().any(|r| r.steps.len() >= 2), "the curriculum should reach rollouts of 2+ steps");
    assert!(expected.iter().flat_map(|r| &r.steps).all(|s| !s.skipped && s.total.is_finite()));
    if cfg.carry.0 > 0 {
        assert!(expected[4..].iter().any(|r| r.carried_from.is_some()), "a carried rollout after the checkpoint");
    }

    let dir = std::env::temp_dir().join(format!("hood-resume-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let ckpt = dir.join("checkpoint.safetensors");
    let mut first = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    let mut got = Vec::new();
    for _ in 0..4 {
        got.push(first.iteration().unwrap());
    }
    first.save_checkpoint(&ckpt).unwrap();
    drop(first);
    let mut resumed = Trainer::resume(&ckpt, data(&cfg)).unwrap();
    assert_eq!(resumed.iteration, 4);
    // Resuming on another thread count (`hood train --threads`) must not change a bit either.
    resumed.set_threads(if cfg.threads == 1 { 2 } else { 1 });
    while got.len() < total {
        got.push(resumed.iteration().unwrap());
    }
    for (a, b) in expected.iter().zip(&got) {
        assert_eq!(a, b, "iteration {} differs after resuming", a.iteration);
    }
    assert_eq!(resumed.params(), straight.params(), "final parameters and statistics");
    assert_eq!(resumed.model_params(), straight.model_params(), "the weights exports use");
    std::fs::remove_dir_all(&dir).ok();
}

/// The weights of `p` in one vector (the order of `Params::tensors_mut`).
fn weights(p: &hood::model::Params) -> Vec<f32> {
    let mut p = p.clone();
    p.tensors_mut().iter().flat_map(|t| t.iter().copied()).collect()
}

/// `ema`: exports and validation use the moving average of the weights, updated after every
/// optimiser step; the optimiser's own weights and the losses are those of a run without it.
#[test]
fn train_weight_average_follows_the_weights() {
    let decay = 0.75;
    // Rollouts of one step: one optimiser step per iteration after the warm-up.
    let plain_cfg = tiny_config().with_rollout_every(1_000_000);
    let cfg = plain_cfg.clone().with_ema(decay);
    let mut plain = Trainer::new(plain_cfg.clone(), data(&plain_cfg)).unwrap();
    let mut t = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    let mut expected: Option<Vec<f32>> = None;
    for _ in 0..7 {
        let before = t.optimiser_steps;
        assert_eq!(plain.iteration().unwrap(), t.iteration().unwrap(), "the average must not feed back");
        assert_eq!(plain.params(), t.params());
        let current = weights(&t.params());
        match t.optimiser_steps - before {
            0 => {}
            1 => {
                let w = (1.0 - decay) as f32;
                expected = Some(match expected {
                    None => current.clone(),
                    Some(mut e) => {
                        e.iter_mut().zip(&current).for_each(|(a, &x)| *a += w * (x - *a));
                        e
                    }
                });
            }
            n => panic!("{n} optimiser steps in one iteration"),
        }
        match &expected {
            None => assert_eq!(t.model_params(), t.params(), "before the first step: the weights themselves"),
            Some(e) => assert!(weights(&t.model_params()) == *e, "iteration {}: the average", t.iteration),
        }
    }
    assert!(t.optimiser_steps >= 3);
    let averaged = weights(&t.model_params());
    assert_ne!(averaged, weights(&t.params()), "after several steps the average lags the weights");
    assert_eq!(plain.model_params(), plain.params(), "without `ema` exports use the weights");
    // The export carries the average (its f32 weights), and says so.
    let bytes = t.export(&[]).unwrap();
    let model = hood::model::ModelBytes::new(&bytes);
    let model = model.model().unwrap();
    assert_eq!(weights(&model.to_params()), averaged);
    assert!(model.provenance().any(|(k, v)| k == "weights" && v == "moving average"));
}

/// `bf16_weights`: exports hold the weights outside the encoders rounded to bf16 (the encoders
/// and biases as they are), and the passes use the rounded weights: a run with the option
/// computes the losses of a run without it from the rounded model, not those of the unrounded
/// one.
#[test]
fn train_bf16_weights_are_trained_and_exported_rounded() {
    let cfg = tiny_config();
    let mut t = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    for _ in 0..4 {
        t.iteration().unwrap();
    }
    let plain = t.export(&[]).unwrap();
    let plain = hood::model::ModelBytes::new(&plain);
    let plain = plain.model().unwrap();
    let on = cfg.clone().with_bf16_weights(true);
    assert_eq!(TrainConfig::from_json(&on.to_json()).unwrap(), on);
    assert!(!cfg.to_json().contains("bf16_weights"), "written only when on");

    let mut rounding = Trainer::from_model(on.clone(), data(&on), &plain).unwrap();
    let rounded = rounding.export(&[]).unwrap();
    let rounded = hood::model::ModelBytes::new(&rounded);
    let rounded = rounded.model().unwrap();
    assert!(rounded.bf16_exact() && !plain.bf16_exact());
    let (p, r) = (plain.to_params(), rounded.to_params());
    let encoders = p.mlps.encoders().count();
    for (i, (a, b)) in p.mlps.iter().zip(r.mlps.iter()).enumerate() {
        for (la, lb) in a.layers.iter().zip(&b.layers) {
            assert_eq!(la.bias, lb.bias);
            if i < encoders {
                assert_eq!(la.weight, lb.weight, "MLP {i}: encoders stay f32");
            } else {
                assert_ne!(la.weight, lb.weight, "MLP {i}: rounded");
                for (&x, &y) in la.weight.iter().zip(&lb.weight) {
                    assert_eq!(y, half::bf16::from_f32(x).to_f32(), "MLP {i}");
                }
            }
        }
    }

    // The first step's loss: the rounded model's, not the plain one's.
    let mut from_rounded = Trainer::from_model(cfg.clone(), data(&cfg), &rounded).unwrap();
    let mut from_plain = Trainer::from_model(cfg.clone(), data(&cfg), &plain).unwrap();
    let (a, b, c) = (rounding.iteration().unwrap(), from_rounded.iteration().unwrap(), from_plain.iteration().unwrap());
    assert!(!a.steps.is_empty() && !a.steps[0].skipped);
    assert_eq!(a.steps[0].total, b.steps[0].total);
    assert_eq!(a.steps[0].grad_norm, b.steps[0].grad_norm, "the gradient at the rounded weights");
    assert_ne!(a.steps[0].total, c.steps[0].total);
    // The optimiser's own weights are not rounded (its steps accumulate below bf16's spacing);
    // the export is.
    let own = rounding.params();
    assert!(own.mlps.decoder.layers[0].weight.iter().any(|&x| half::bf16::from_f32(x).to_f32() != x));
    let exported = rounding.model_params();
    assert!(exported.mlps.decoder.layers[0].weight.iter().all(|&x| half::bf16::from_f32(x).to_f32() == x));
}

/// Frame the rollout of `r` ended at.
fn end_frame(r: &hood::train::IterationReport) -> usize {
    let startup = r.carried_from.is_none();
    r.start_frame + r.steps.len() - usize::from(startup)
}

/// `carry`: a drawn track continues from the frame and the state its last rollout ended in
/// (the rollout's first step is no start-up step), and starts afresh at the scene's end or
/// when the draw restarts it.
#[test]
fn train_carried_rollouts_continue_where_they_ended() {
    let cfg = tiny_config().with_carry((1, 0.0)).with_rollout_every(1);
    let mut t = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    let reports: Vec<_> = (0..14).map(|_| t.iteration().unwrap()).collect();
    let n_frames = t.data.scenes[0].n_frames();
    let mut carried = 0;
    for w in reports[cfg.warmup_iterations as usize..].windows(2) {
        let (a, b) = (&w[0], &w[1]);
        assert!(b.steps.iter().all(|s| !s.skipped));
        match b.carried_from {
            Some(f) => {
                carried += 1;
                assert_eq!(f, end_frame(a), "iteration {} continues where {} ended", b.iteration, a.iteration);
                assert_eq!(b.start_frame, f);
                assert!(!b.steps[0].startup);
            }
            None => {
                assert!(end_frame(a) + b.steps.len() >= n_frames, "iteration {} restarted early", b.iteration);
                assert!(b.steps[0].startup);
            }
        }
    }
    assert!(carried >= 5, "{carried} carried rollouts");

    // The state is carried, not just the frame: a track moved by 1 cm changes the next step's
    // loss, unless the draw restarts the track.
    for (reset, carries) in [(0.0, true), (1.0, false)] {
        let cfg = cfg.clone().with_carry((1, reset));
        let (mut a, mut b) =
            (Trainer::new(cfg.clone(), data(&cfg)).unwrap(), Trainer::new(cfg.clone(), data(&cfg)).unwrap());
        for _ in 0..4 {
            assert_eq!(a.iteration().unwrap(), b.iteration().unwrap());
        }
        b.track_mut(0).unwrap().pos.iter_mut().for_each(|p| p[1] += 0.01);
        let (ra, rb) = (a.iteration().unwrap(), b.iteration().unwrap());
        assert_eq!(ra.carried_from.is_some(), carries);
        assert_eq!(ra.steps[0].total != rb.steps[0].total, carries, "reset {reset}");
    }
    assert!(Trainer::new(tiny_config(), data(&tiny_config())).unwrap().track_mut(0).is_none());
    assert!(TrainConfig::from_json("{\"carry\": [2, 1.5]}").is_err());
    assert_eq!(hood::train::config::parse_carry("8,0.1").unwrap(), (8, 0.1));
}

#[test]
fn train_export_runs_in_the_runtime() {
    let cfg = tiny_config();
    let mut t = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    for _ in 0..4 {
        t.iteration().unwrap();
    }
    let v = t.validate().unwrap();
    assert!(v.finite(), "validation rollouts diverged: {v:?}");
    let bytes = hood::model::ModelBytes::new(&t.export(&[("test", "yes")]).unwrap());
    let model = bytes.model().unwrap();
    assert_eq!(model.provenance().find(|(k, _)| *k == "iterations").map(|(_, v)| v), Some("4"));
    assert_eq!(model.to_params().normalisers.node.stats(), t.params().normalisers.node.stats());
    // The exported model steps the training scene in the runtime, finite.
    let scene = &t.data.scenes[0];
    let body = hood::sim::BodyDesc { mesh: &scene.body, positions: scene.body_frame(0) };
    let mut sim = hood::sim::Sim::new(&model, &scene.garment, Some(body), hood::sim::SimConfig::network()).unwrap();
    let mut targets = vec![[0.0; 3]; scene.garment.n_vertices()];
    for f in 1..6 {
        scene.skinned_garment(f, &mut targets).unwrap();
        sim.set_pin_targets(&targets).unwrap();
        let x = sim.step(scene.body_frame(f)).unwrap();
        assert!(x.iter().flatten().all(|c| c.is_finite()), "frame {f}");
    }
    // Continuing from the exported model (no checkpoint) keeps its weights and counters.
    let again = Trainer::from_model(cfg.clone(), data(&cfg), &model).unwrap();
    assert_eq!(again.iteration, 4);
    let (pa, pb) = (again.params(), t.params());
    assert_eq!(pa.mlps, pb.mlps);
}

/// The supervised warm start: the optimum the trainer pulls toward beats coasting on the training
/// objective, the pull's gradient is its value's derivative, and a run with the pull on records it
/// and learns differently from one without.
#[test]
fn train_supervised_pull_toward_the_optimum() {
    use hood::physics::Objective;
    use hood::solve::{ImplicitStep, LbfgsParams, StepState};
    use hood::train::config::PullStart;
    use hood::train::{LossBody, StepLoss};
    let cfg = tiny_config();
    let d = data(&cfg);
    let scene = &d.scenes[0];
    let g = &scene.garment;
    let n = g.n_vertices();
    let pos = scene.initial_garment(1).unwrap();
    let prev = scene.initial_garment(0).unwrap();
    let velocity: Vec<[f32; 3]> = pos.iter().zip(&prev).map(|(a, b)| [0, 1, 2].map(|c| a[c] - b[c])).collect();
    let coast: Vec<[f32; 3]> = pos.iter().zip(&velocity).map(|(a, b)| [0, 1, 2].map(|c| a[c] + b[c])).collect();
    let mut targets = vec![[0.0f32; 3]; n];
    scene.skinned_garment(2, &mut targets).unwrap();
    let dt = 1.0 / 30.0;
    let objective = Objective::training(5e3);
    let body = LossBody { mesh: &scene.body, current: scene.body_frame(1), next: scene.body_frame(2) };
    let mut loss = StepLoss::new(g, &scene.body).unwrap();
    let e_coast = loss.eval(&objective, &body, &pos, &velocity, dt, &coast).unwrap().0.total();
    let state = StepState { pos: &pos, velocity: &velocity, dt, pinned: g.pinned(), targets: &targets };
    let mut x_star = vec![[0.0f32; 3]; n];
    let params = LbfgsParams::default().with_max_iterations(30);
    loss.optimum(&mut ImplicitStep::new(n, 10), &objective, &state, &params, false, &mut x_star).unwrap();
    let e_star = loss.eval(&objective, &body, &pos, &velocity, dt, &x_star).unwrap().0.total();
    assert!(e_star < e_coast, "optimum {e_star} against coasting {e_coast}");
    // Started from a prediction (`supervised_start: prediction`), a few iterations refine that
    // prediction: from the optimum they stay by it, where three from coasting end far from it.
    let few = LbfgsParams::default().with_max_iterations(3);
    let farthest = |x: &[[f32; 3]]| {
        x.iter()
            .zip(&x_star)
            .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0f32, f32::max))
            .fold(0.0, f32::max)
    };
    let mut refined = x_star.clone();
    loss.optimum(&mut ImplicitStep::new(n, 10), &objective, &state, &few, true, &mut refined).unwrap();
    let mut restarted = x_star.clone();
    loss.optimum(&mut ImplicitStep::new(n, 10), &objective, &state, &few, false, &mut restarted).unwrap();
    let e_refined = loss.eval(&objective, &body, &pos, &velocity, dt, &refined).unwrap().0.total();
    assert!(e_refined <= e_star * (1.0 + 1e-5), "refined {e_refined} against {e_star}");
    assert!(
        farthest(&refined) < 0.1 * farthest(&restarted),
        "refined {} m from the optimum, restarted {} m",
        farthest(&refined),
        farthest(&restarted)
    );
    // The pull at the optimum itself is zero; elsewhere its gradient is its derivative.
    assert_eq!(loss.add_pull(&x_star, &x_star, 1.0, dt), 0.0);
    loss.eval(&objective, &body, &pos, &velocity, dt, &coast).unwrap();
    let before: Vec<[f32; 3]> = loss.grad().to_vec();
    let value = |x: &[[f32; 3]]| {
        let mut l = StepLoss::new(g, &scene.body).unwrap();
        l.eval(&objective, &body, &pos, &velocity, dt, x).unwrap();
        f64::from(l.add_pull(x, &x_star, 0.5, dt))
    };
    loss.add_pull(&coast, &x_star, 0.5, dt);
    let i = (0..n).max_by(|&a, &b| {
        let d = |i: usize| (0..3).map(|c| (coast[i][c] - x_star[i][c]).abs()).sum::<f32>();
        d(a).total_cmp(&d(b))
    });
    let i = i.unwrap();
    for c in 0..3 {
        let h = 1e-3f32;
        let (mut xp, mut xm) = (coast.clone(), coast.clone());
        xp[i][c] += h;
        xm[i][c] -= h;
        let fd = (value(&xp) - value(&xm)) / (2.0 * f64::from(h));
        let an = f64::from(loss.grad()[i][c] - before[i][c]);
        assert!((fd - an).abs() <= 1e-2 * an.abs().max(1e-3), "vertex {i} axis {c}: fd {fd} analytic {an}");
    }
    // A run with the pull records it and ends with other weights than one without.
    let on = cfg.clone().with_supervised((1.0, 100, 10));
    let (mut a, mut b) = (Trainer::new(on.clone(), data(&on)).unwrap(), Trainer::new(cfg.clone(), data(&cfg)).unwrap());
    let mut pulled = 0;
    for _ in 0..4 {
        let r = a.iteration().unwrap();
        pulled += r.steps.iter().filter(|s| s.supervised > 0.0 && s.supervised.is_finite()).count();
        b.iteration().unwrap();
    }
    assert!(pulled > 0, "no step recorded a pull");
    assert_ne!(a.params().mlps, b.params().mlps);
    assert_eq!(TrainConfig::from_json(&on.to_json()).unwrap(), on);
    // The pull toward the network's own refined prediction: recorded, and another training.
    let own = on.clone().with_supervised_start(PullStart::Prediction);
    let mut c = Trainer::new(own.clone(), data(&own)).unwrap();
    let mut pulled = 0;
    for _ in 0..4 {
        let r = c.iteration().unwrap();
        pulled += r.steps.iter().filter(|s| s.supervised > 0.0 && s.supervised.is_finite()).count();
    }
    assert!(pulled > 0, "no step recorded a pull toward the refined prediction");
    assert_ne!(c.params().mlps, a.params().mlps);
    assert_eq!(TrainConfig::from_json(&own.to_json()).unwrap(), own);
    assert!(own.to_json().contains("\"supervised_start\": \"prediction\""));
    assert_eq!(PullStart::parse("coasting").unwrap(), PullStart::Coasting);
    assert!(PullStart::parse("optimum").is_err());
    assert_eq!(hood::train::config::parse_supervised("0, 0, 30").unwrap(), (0.0, 0, 30));
    assert!(hood::train::config::parse_supervised("1, 100").is_err());
    assert!(hood::train::config::parse_supervised("-1, 100, 30").is_err());
}

/// `hood train --scenes-from`: a resumed run forks onto other scenes (recorded in `config.json`
/// and in the next checkpoint, so that a later resume keeps them); a new run refuses the flag.
#[cfg(feature = "cli")]
#[test]
fn train_cli_resume_with_other_scenes() {
    let dir = std::env::temp_dir().join(format!("hood-scenes-from-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut cfg = tiny_config();
    cfg.checkpoint_every = 1;
    let first = dir.join("first.json");
    std::fs::write(&first, cfg.to_json()).unwrap();
    let second = dir.join("second.json");
    std::fs::write(
        &second,
        r#"{"scenes": [{"garment": "cape", "vertices": 64, "motion": "arm-swings", "seconds": 1},
                       {"garment": "skirt", "vertices": 100, "motion": "turn", "seconds": 1}]}"#,
    )
    .unwrap();
    let run = dir.join("run");
    let hood = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_hood"))
            .arg("train")
            .arg("--dir")
            .arg(&run)
            .args(args)
            .output()
            .unwrap()
    };
    let o = hood(&["--scenes-from", second.to_str().unwrap(), "--iterations", "1"]);
    assert!(!o.status.success(), "a new run must refuse --scenes-from");
    assert!(String::from_utf8_lossy(&o.stderr).contains("--scenes-from"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = hood(&["--config", first.to_str().unwrap(), "--iterations", "2", "--snapshot-every", "1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // `--snapshot-every`: one exported model per N-th iteration, the last one the run's own.
    let snapshot = |it: u64| run.join("snapshots").join(format!("{it}.hood"));
    let (one, two) = (std::fs::read(snapshot(1)).unwrap(), std::fs::read(snapshot(2)).unwrap());
    assert_eq!(two, std::fs::read(run.join("model.hood")).unwrap());
    assert_ne!(one, two, "the weights moved between iterations 1 and 2");
    for it in [1, 2] {
        let bytes = hood::model::ModelBytes::read(snapshot(it)).unwrap();
        bytes.model().unwrap();
    }
    assert!(!hood(&["--snapshot-every", "0"]).status.success(), "a snapshot period of 0 is refused");
    // The fork also switches the supervised pull on (`--supervised`), recorded like the scenes.
    let o = hood(&[
        "--scenes-from",
        second.to_str().unwrap(),
        "--iterations",
        "3",
        "--supervised",
        "2,5,7",
        "--snapshot-every",
        "2",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!snapshot(3).exists(), "3 is not a multiple of 2");
    let recorded = TrainConfig::from_json(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(recorded.scenes.len(), 2);
    assert_eq!(recorded.supervised, (2.0, 5, 7));
    let st = hood::io::safetensors::SafeTensors::read(run.join("checkpoint.safetensors")).unwrap();
    let in_checkpoint = hood::train::session::checkpoint_config(&st).unwrap();
    assert_eq!(in_checkpoint.scenes, recorded.scenes);
    assert_eq!(in_checkpoint.supervised, (2.0, 5, 7));
    assert!(!hood(&["--supervised", "2,5"]).status.success(), "three values are required");
    assert_eq!(in_checkpoint.latent, cfg.latent, "only the scenes change");
    // A run that passes an iteration again (here afresh) leaves its snapshot as it was.
    std::fs::write(snapshot(1), b"kept").unwrap();
    let o = hood(&["--fresh", "--config", first.to_str().unwrap(), "--iterations", "1", "--snapshot-every", "1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(snapshot(1)).unwrap(), b"kept");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Reference rollouts solved on two threads, a scene per thread, give each scene the states
/// one thread gives it, and the progress counts every frame of every scene once.
#[test]
fn train_reference_states_on_two_threads_match_one() {
    let scene = |garment, motion| SceneSource::Procedural { garment, vertices: 64, motion, seconds: 0.5 };
    let cfg = tiny_config().with_scenes(vec![
        scene(GarmentKind::Cape, MotionKind::ArmSwings),
        scene(GarmentKind::Skirt, MotionKind::Walk),
        scene(GarmentKind::Cape, MotionKind::Walk),
    ]);
    let mut one = data(&cfg);
    one.attach_reference_states(None, 5e5, 1, |_, _, _| {}).unwrap();
    let mut two = data(&cfg);
    let (calls, last) = (AtomicUsize::new(0), AtomicUsize::new(0));
    two.attach_reference_states(None, 5e5, 2, |_, done, of| {
        calls.fetch_add(1, Ordering::Relaxed);
        last.fetch_max(done, Ordering::Relaxed);
        assert!(done <= of, "{done} of {of}");
    })
    .unwrap();
    let frames: usize = two.scenes.iter().map(|s| s.n_frames() - 1).sum();
    assert_eq!((calls.into_inner(), last.into_inner()), (frames, frames));
    assert_eq!(one.reference.len(), 3);
    assert!(one.reference.iter().all(|r| r.len() > 1));
    assert_eq!(two.reference, one.reference);
}

/// `reference_states`: the scenes' reference rollouts (implicit steps of the training objective)
/// are computed once and cached, and fresh samples start from their states (past the start-up
/// step) with the configured probability; without them attached, from the skinned garment.
#[test]
fn train_reference_states_start_fresh_samples_from_the_reference_rollout() {
    let cfg = tiny_config().with_reference_states(1.0);
    let dir = std::env::temp_dir().join(format!("hood-reference-{}", std::process::id()));
    let mut d = data(&cfg);
    let computed = AtomicUsize::new(0);
    d.attach_reference_states(Some(&dir), 5e5, 1, |_, _, _| {
        computed.fetch_add(1, Ordering::Relaxed);
    })
    .unwrap();
    let n_frames = d.scenes[0].n_frames();
    assert_eq!(computed.into_inner(), n_frames - 1);
    let states = &d.reference[0];
    assert_eq!(states.len(), n_frames);
    assert_eq!(states[0], d.scenes[0].initial_garment(0).unwrap());
    assert!(states.iter().flatten().flatten().all(|c| c.is_finite()));
    assert_ne!(states[1], states[0], "the garment moves");
    let (pos, vel) = d.reference_state(0, 3).unwrap();
    assert_eq!(pos, states[3]);
    assert_eq!(vel[5], [0, 1, 2].map(|a| states[3][5][a] - states[2][5][a]));
    assert!(d.reference_state(0, 0).is_none() && d.reference_state(0, n_frames).is_none());
    // The cache gives the same states without computing; a file of another garment is redone.
    let mut again = data(&cfg);
    again.attach_reference_states(Some(&dir), 5e5, 2, |_, _, _| panic!("computed again")).unwrap();
    assert_eq!(again.reference, d.reference);
    let file = std::fs::read_dir(&dir).unwrap().next().unwrap().unwrap().path();
    let mut bytes = std::fs::read(&file).unwrap();
    bytes[12] ^= 1;
    std::fs::write(&file, &bytes).unwrap();
    let redone = AtomicUsize::new(0);
    again
        .attach_reference_states(Some(&dir), 5e5, 2, |_, _, _| {
            redone.fetch_add(1, Ordering::Relaxed);
        })
        .unwrap();
    assert_eq!((redone.into_inner(), &again.reference), (n_frames - 1, &d.reference));
    std::fs::remove_dir_all(&dir).ok();

    let mut t = Trainer::new(cfg.clone(), d).unwrap();
    for _ in 0..8 {
        let r = t.iteration().unwrap();
        assert!(r.steps.iter().all(|s| !s.skipped && s.total.is_finite()));
        assert_eq!(r.from_reference, !r.warmup, "iteration {}", r.iteration);
        if r.from_reference {
            assert!(r.start_frame >= 1 && r.carried_from.is_none() && !r.steps[0].startup);
            assert!(r.start_frame + r.steps.len() < n_frames);
        }
    }
    // Without the states attached, fresh samples start from the skinned garment.
    let mut t = Trainer::new(cfg.clone(), data(&cfg)).unwrap();
    for _ in 0..4 {
        let r = t.iteration().unwrap();
        assert!(!r.from_reference && (r.warmup || r.steps[0].startup));
    }
    assert!(TrainConfig::from_json("{\"reference_states\": 1.5}").is_err());
    assert_eq!(TrainConfig::from_json(&cfg.to_json()).unwrap(), cfg);
}
