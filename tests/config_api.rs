//! The config structs are `#[non_exhaustive]`: built from outside the crate with their defaults
//! and `with_` methods. Every setter sets its own field and leaves the others alone.

use hood::hierarchy::{CentreChoice, HierarchyConfig};
use hood::kernels::Tier;
use hood::sim::{Precision, SimConfig, Sleeping, StepMode};
use hood::solve::LbfgsParams;

#[test]
fn config_sim_config_builders_set_every_field() {
    let sleeping = Sleeping::new(2e-5, 7);
    assert_eq!((sleeping.threshold, sleeping.frames), (2e-5, 7));
    assert_eq!(Sleeping::default().with_threshold(2e-5).with_frames(7), sleeping);

    let step = StepMode::SolverBudget { micros: 500, max_iterations: 9 };
    let c = SimConfig::default()
        .with_body_collision(false)
        .with_pinning(false)
        .with_normals(true)
        .with_sleeping(Some(sleeping))
        .with_precision(Precision::Bf16)
        .with_startup(false)
        .with_tier(Some(Tier::Scalar))
        .with_teleport(None)
        .with_speed_limit(Some(0.2))
        .with_projection(Some(0.004))
        .with_refine(Some(5))
        .with_step(step)
        .with_threads(3);
    assert!(!c.body_collision && !c.pinning && c.normals && !c.startup);
    assert_eq!(c.sleeping, Some(sleeping));
    assert_eq!(c.precision, Precision::Bf16);
    assert_eq!(c.tier, Some(Tier::Scalar));
    assert_eq!((c.teleport, c.speed_limit, c.projection), (None, Some(0.2), Some(0.004)));
    assert_eq!(c.refine, Some(5));
    assert_eq!(c.step, step);
    assert_eq!(c.threads, 3);

    // A setter is the same as assigning the field.
    let mut n = SimConfig::network();
    n.threads = 2;
    assert_eq!(n, SimConfig::network().with_threads(2));
    assert_eq!(n.step, StepMode::Network);
}

/// Solver options with every field set away from its default.
fn solver() -> LbfgsParams {
    LbfgsParams::default()
        .with_max_iterations(7)
        .with_grad_tol(1e-3)
        .with_rel_decrease_tol(1e-4)
        .with_armijo(1e-2)
        .with_max_line_search(5)
        .with_first_step(2e-3)
}

#[test]
fn config_option_builders_set_every_field() {
    let solver = solver();
    assert_eq!(
        (solver.max_iterations, solver.grad_tol, solver.rel_decrease_tol, solver.armijo, solver.max_line_search),
        (7, 1e-3, 1e-4, 1e-2, 5)
    );
    assert_eq!(solver.first_step, 2e-3);

    let h = HierarchyConfig::default().with_levels(2).with_centre(CentreChoice::Seeded(9));
    assert_eq!((h.levels, h.centre), (2, CentreChoice::Seeded(9)));
}

#[cfg(feature = "tools")]
#[test]
fn config_tool_option_builders_set_every_field() {
    use hood::eval::RolloutOptions;
    use hood::mesh::Material;
    use hood::physics::Objective;
    use hood::rig::motion::{ClipRest, RetargetOptions};
    use hood::scene::own::{GarmentOptions, Pins, UpAxis};

    let (objective, solver) = (Objective::training(5e3), solver());
    let r = RolloutOptions::default()
        .with_objective(objective)
        .with_gap_every(4)
        .with_gap_solver(solver)
        .with_inside_every(2)
        .with_keep(vec![0, 3]);
    assert_eq!(r.objective, objective);
    assert_eq!((r.gap_every, r.inside_every), (4, 2));
    assert_eq!(r.gap_solver, solver);
    assert_eq!(r.keep, [0, 3]);

    let material = Material::preset("stiff-bend").unwrap();
    let g = GarmentOptions::default()
        .with_scale(0.01)
        .with_up(UpAxis::Z)
        .with_offset([0.0, 0.1, 0.0])
        .with_pins(Pins::Vertices(vec![1, 2]))
        .with_material(Some(material));
    assert_eq!((g.scale, g.up, g.offset), (0.01, UpAxis::Z, [0.0, 0.1, 0.0]));
    assert_eq!(g.pins, Pins::Vertices(vec![1, 2]));
    assert_eq!(g.material, Some(material));

    let initial = [glam::Quat::IDENTITY; 2];
    let aliases = [("Hand", "LeftHand")];
    let t = RetargetOptions::default()
        .with_clip_rest(ClipRest::ZeroRotations)
        .with_rig_initial(Some(&initial))
        .with_aliases(&aliases)
        .with_leg(["a", "b", "c"])
        .with_hips(["l", "r"])
        .with_keep_direction(&["pelvis"]);
    assert_eq!(t.clip_rest, ClipRest::ZeroRotations);
    assert_eq!(t.rig_initial, Some(&initial[..]));
    assert_eq!(t.aliases, aliases);
    assert_eq!((t.leg, t.hips, t.keep_direction), (["a", "b", "c"], ["l", "r"], &["pelvis"][..]));
}

#[cfg(feature = "train")]
#[test]
fn config_train_config_builders_set_every_field() {
    use hood::mesh::Material;
    use hood::scene::{GarmentKind, MotionKind};
    use hood::train::config::PullStart;
    use hood::train::{SceneSource, TrainConfig};

    let scenes = vec![SceneSource::Procedural {
        garment: GarmentKind::Cape,
        vertices: 64,
        motion: MotionKind::ArmSwings,
        seconds: 1.0,
    }];
    let c = TrainConfig::default()
        .with_latent(8)
        .with_hidden_layers(3)
        .with_levels(2)
        .with_schedule("f,c0 | u:f,c0".into())
        .with_iterations(10)
        .with_warmup_iterations(1)
        .with_learning_rate(1e-3)
        .with_lr_halving_steps(100)
        .with_clip(0.5)
        .with_rollout_max(4)
        .with_rollout_every(3)
        .with_noise(1e-3)
        .with_collision_weight((1.0, 2.0))
        .with_collision_ramp(50)
        .with_decoder_init_scale(0.1)
        .with_random_materials(false)
        .with_material(Material::preset("stiff-bend").unwrap())
        .with_random_centres(false)
        .with_scenes(scenes.clone())
        .with_checkpoint_every(6)
        .with_validate_every(7)
        .with_validation((1, 4))
        .with_supervised((0.5, 20, 10))
        .with_supervised_start(PullStart::Prediction)
        .with_carry((2, 0.25))
        .with_reference_states(0.5)
        .with_ema(0.99)
        .with_threads(1)
        .with_seed(42);
    assert_eq!((c.latent, c.hidden_layers, c.levels), (8, 3, 2));
    assert_eq!(c.schedule, "f,c0 | u:f,c0");
    assert_eq!((c.iterations, c.warmup_iterations, c.lr_halving_steps), (10, 1, 100));
    assert_eq!((c.learning_rate, c.clip), (1e-3, 0.5));
    assert_eq!((c.rollout_max, c.rollout_every), (4, 3));
    assert_eq!((c.noise, c.decoder_init_scale), (1e-3, 0.1));
    assert_eq!((c.collision_weight, c.collision_ramp), ((1.0, 2.0), 50));
    assert!(!c.random_materials && !c.random_centres);
    assert_eq!(c.material, Material::preset("stiff-bend").unwrap());
    assert_eq!(c.scenes, scenes);
    assert_eq!((c.checkpoint_every, c.validate_every, c.validation), (6, 7, (1, 4)));
    assert_eq!((c.supervised, c.supervised_start), ((0.5, 20, 10), PullStart::Prediction));
    assert_eq!((c.carry, c.reference_states, c.ema), ((2, 0.25), 0.5, 0.99));
    assert_eq!((c.threads, c.seed), (1, 42));
    // A built config survives its JSON form, as one read from a file.
    assert_eq!(TrainConfig::from_json(&c.to_json()).unwrap(), c);
}
