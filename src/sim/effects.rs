//! Which of the step's optional effects acted on the last step, for engines that log, display or
//! react to them (a teleport to hide, a skipped step to skip the upload of).

use super::Sim;

/// What the last successful [`Sim::step`] did beyond a plain network step. A teleported or
/// sleeping step does nothing else; the other flags may combine.
///
/// Calls that place the garment without stepping report as follows: [`Sim::teleport`] reads as
/// a teleported step (`teleported` alone), since it moves the garment as an automatic teleport
/// does; [`Sim::set_state`] and [`Sim::load_state`] clear every flag, as before the first step
/// (the flags report on a step, and none has run from the new state yet). A refused call of
/// any of these, like a refused step, leaves the flags as they were.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepEffects {
    /// The garment was moved by a rigid motion instead of stepped: the body jumped farther than
    /// [`SimConfig::teleport`](super::SimConfig::teleport) (the body's best-fit motion), or
    /// [`Sim::teleport`] was called.
    pub teleported: bool,
    /// Sleeping: body and garment were at rest, and the step was skipped.
    pub slept: bool,
    /// The start-up (relaxation) pass ran before the regular one.
    pub startup: bool,
    /// The speed limit carried the garment: the body's centroid moved farther than
    /// [`SimConfig::speed_limit`](super::SimConfig::speed_limit).
    pub carried: bool,
    /// A solver refinement ran ([`SimConfig::refine`](super::SimConfig::refine)), or the solve of
    /// a solver step mode.
    pub refined: bool,
    /// The collision projection moved at least one garment vertex.
    pub projected: bool,
    /// A body tether pulled at least one garment vertex back
    /// ([`SimConfig::tether`](super::SimConfig::tether)).
    pub tethered: bool,
    /// The step took longer than the time budget of
    /// [`StepMode::SolverBudget`](super::StepMode::SolverBudget) (see
    /// [`Sim::last_budget`](super::Sim::last_budget)).
    pub over_budget: bool,
}

impl Sim<'_> {
    /// What the last successful step did (all false before the first; a refused step leaves it).
    /// After [`Sim::teleport`]: `teleported` alone; after [`Sim::set_state`] or
    /// [`Sim::load_state`]: all false until the next step (see [`StepEffects`]).
    pub fn last_effects(&self) -> StepEffects {
        self.last_effects
    }
}

#[cfg(test)]
mod tests {
    use super::StepEffects;
    use crate::body::rigid::RigidMotion;
    use crate::body::{shapes, BodyMesh};
    use crate::mesh::{shapes::grid, Garment, GarmentDesc};
    use crate::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
    use crate::sim::{BodyDesc, Sim, SimConfig};
    use alloc::vec;
    use alloc::vec::Vec;

    const NONE: StepEffects = StepEffects {
        teleported: false,
        slept: false,
        startup: false,
        carried: false,
        refined: false,
        projected: false,
        tethered: false,
        over_budget: false,
    };
    const TELEPORTED: StepEffects = StepEffects { teleported: true, ..NONE };
    const STARTUP: StepEffects = StepEffects { startup: true, ..NONE };

    fn moved(body: &[[f32; 3]], dx: f32) -> Vec<[f32; 3]> {
        body.iter().map(|p| [p[0] + dx, p[1], p[2]]).collect()
    }

    /// Teleports (called or automatic) read as teleported steps; a set or loaded state as no step
    /// yet; refused calls leave the flags; the next step reports itself again.
    #[test]
    fn sim_effects_after_teleport_set_state_and_load_state() {
        let mut p = Params::init(&ModelSpec::hood(8), 3).unwrap();
        p.normalisers = Normalisers::unit_scale(3);
        let bytes = ModelBytes::new(&write_model(&p, false, &[]).unwrap());
        let model = bytes.model().unwrap();
        let (rest, faces) = grid(5, 5, 0.6, 0.6, 0.32);
        let mut pinned = vec![false; rest.len()];
        pinned[0] = true;
        let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
        let (body, body_faces) = shapes::ellipsoid(12, 16, [0.25, 0.3, 0.25], [0.0; 3]);
        let mesh = BodyMesh::new(body.len(), &body_faces).unwrap();
        let desc = Some(BodyDesc { mesh: &mesh, positions: &body });
        let mut sim = Sim::new(&model, &garment, desc, SimConfig::network()).unwrap();
        assert_eq!(sim.last_effects(), NONE);
        sim.step(&body).unwrap();
        assert_eq!(sim.last_effects(), STARTUP);
        let mut saved = vec![0u8; sim.saved_state_len()];
        sim.save_state(&mut saved).unwrap();

        // A called teleport, and a refused one (a body of the wrong size).
        let motion = RigidMotion { rotation: glam::Quat::IDENTITY, translation: glam::Vec3::new(2.0, 0.0, 0.0) };
        let far = moved(&body, 2.0);
        sim.teleport(&motion, &far).unwrap();
        assert_eq!(sim.last_effects(), TELEPORTED);
        sim.step(&far).unwrap();
        assert_eq!(sim.last_effects(), NONE, "a plain step after the teleport");
        assert!(sim.teleport(&motion, &far[1..]).is_err());
        assert_eq!(sim.last_effects(), NONE, "a refused teleport leaves the flags");

        // A loaded state: no step yet, whatever the last one did; a refused load leaves them.
        sim.teleport(&motion, &moved(&body, 4.0)).unwrap();
        let mut bad = saved.clone();
        bad[10] ^= 1;
        assert!(sim.load_state(&bad).is_err());
        assert_eq!(sim.last_effects(), TELEPORTED);
        sim.load_state(&saved).unwrap();
        assert_eq!(sim.last_effects(), NONE);

        // An automatic teleport (a 1 m jump), then a set state, then a refused one.
        sim.step(&moved(&body, 1.0)).unwrap();
        assert_eq!(sim.last_effects(), TELEPORTED);
        let mut state = sim.state().clone();
        state.pos[3][1] = f32::NAN;
        assert!(sim.set_state(&state).is_err());
        assert_eq!(sim.last_effects(), TELEPORTED);
        state.pos[3][1] = 0.4;
        state.started = false;
        sim.set_state(&state).unwrap();
        assert_eq!(sim.last_effects(), NONE);
        sim.step(&moved(&body, 1.0)).unwrap();
        assert_eq!(sim.last_effects(), STARTUP, "the next step reports itself");
    }

    /// The last refinement and projection describe the last step that ran them: a sleep, a
    /// teleport, a set or loaded state forget them. A teleport counts frames at rest anew.
    #[test]
    fn reports_of_the_last_step_are_forgotten_when_no_step_runs() {
        // A decoder that outputs nothing: every network step is the coasting guess.
        let bytes = crate::sim::coasting_model_bytes(5);
        let model = bytes.model().unwrap();
        // A cloth partly inside the top of the body, which rises 4 cm a frame into it: every
        // step has vertices to refine and to project.
        let (rest, faces) = grid(5, 5, 0.3, 0.3, 0.28);
        let garment = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
        let (body, body_faces) = shapes::ellipsoid(32, 48, [0.25, 0.3, 0.25], [0.0; 3]);
        let mesh = BodyMesh::new(body.len(), &body_faces).unwrap();
        let rise = |sim: &mut Sim| {
            let b: Vec<[f32; 3]> = sim.state().body_pos.iter().map(|p| [p[0], p[1] + 0.04, p[2]]).collect();
            sim.step(&b).unwrap();
            b
        };
        // Everything counts as at rest: the third step at rest in a row sleeps.
        let base = SimConfig {
            sleeping: Some(crate::sim::Sleeping { threshold: 1e3, frames: 2 }),
            startup: false,
            ..SimConfig::network()
        };
        let refined = SimConfig { refine: Some(2), ..base };
        let projected = SimConfig { projection: Some(crate::sim::DEFAULT_PROJECTION_MARGIN), ..base };
        // What each config's step reports.
        type Ran = fn(&Sim) -> bool;
        let reports: [(SimConfig, Ran); 2] =
            [(refined, |s| s.last_refinement().is_some()), (projected, |s| s.last_projected() > 0)];
        for (cfg, ran) in reports {
            let desc = Some(BodyDesc { mesh: &mesh, positions: &body });
            let mut sim = Sim::new(&model, &garment, desc, cfg).unwrap();
            assert!(!ran(&sim));
            rise(&mut sim);
            assert!(ran(&sim), "{cfg:?}");
            let mut saved = vec![0u8; sim.saved_state_len()];
            sim.save_state(&mut saved).unwrap();
            let now = rise(&mut sim);
            let motion = RigidMotion { rotation: glam::Quat::IDENTITY, translation: glam::Vec3::ZERO };
            sim.teleport(&motion, &now).unwrap();
            assert!(!ran(&sim), "teleported");
            // Two frames at rest counted before the teleport would make this one the third.
            rise(&mut sim);
            assert!(!sim.last_effects().slept, "frames at rest are counted anew after a teleport");
            assert!(ran(&sim));
            rise(&mut sim);
            rise(&mut sim);
            assert!(sim.last_effects().slept);
            assert!(!ran(&sim), "slept");
            sim.load_state(&saved).unwrap();
            assert!(!ran(&sim), "loaded");
            rise(&mut sim);
            assert!(ran(&sim));
            let state = sim.state().clone();
            sim.set_state(&state).unwrap();
            assert!(!ran(&sim), "set");
        }
    }
}
