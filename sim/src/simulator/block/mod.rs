//! A block of W environments stepped in lockstep: their batched [`State`], what their episodes
//! prescribe ([`LaneSetup`]), the solver that advances them ([`AnySolver`]) and the events they
//! raise. Per substep the block runs the solver, then the seal model ([`seal`]) and, when due,
//! the health checks ([`health`]).
//!
//! Blocks are independent and run in parallel (rayon), each for the whole requested number of
//! substeps, which keeps a block's ~0.5 MB working set hot in cache. Partial blocks are padded
//! with copies of a real environment whose results are discarded.

mod health;
mod seal;
mod snapshot;

use std::sync::Arc;

use crate::constants::StepConstants;
use crate::episode::{EpisodeSpec, HealthEvent, SealEvent};
use crate::math::{get3, set3, Quat, V3};
use crate::model::Model;
use crate::solvers::{AnySolver, Integrator, Simd, Substep};
use crate::state::{LaneSetup, State};
use crate::tool::{ToolDrive, ToolState};
use crate::trajectory::ToolTrajectory;

pub(crate) use snapshot::LaneSnapshot;

/// W environments stepped together.
pub(crate) struct EnvBlock<const W: usize> {
    /// Environment index of each lane (padding lanes repeat a real one).
    pub(crate) envs: [usize; W],
    /// Whether a lane is a real environment (not padding).
    pub(crate) real: [bool; W],
    pub(crate) state: State<W>,
    pub(crate) setup: LaneSetup<W>,
    solver: AnySolver<W>,
    pub(crate) events: Vec<HealthEvent>,
    pub(crate) seal_events: Vec<SealEvent>,
}

impl<const W: usize> EnvBlock<W> {
    /// A block holding `specs[envs[l]]` in lane l.
    pub(crate) fn new(
        model: &Model,
        specs: &[EpisodeSpec],
        envs: [usize; W],
        real: [bool; W],
    ) -> Self {
        let tools = envs
            .iter()
            .map(|&e| ToolDrive::Trajectory(specs[e].trajectory.clone()))
            .collect();
        let mut block = EnvBlock {
            envs,
            real,
            state: State::new(model),
            setup: LaneSetup::new(model, tools),
            solver: AnySolver::new(model),
            events: Vec::new(),
            seal_events: Vec::new(),
        };
        for (l, &e) in envs.iter().enumerate() {
            block.init_lane(l, model, &specs[e]);
        }
        block
    }

    /// Lanes holding environment `env` (one, or several in a padded block).
    fn lanes_of(&self, env: usize) -> impl Iterator<Item = usize> + '_ {
        (0..W).filter(move |&l| self.envs[l] == env)
    }

    /// Restarts every lane holding `env` from `spec`: time 0, active, cups sealed anew.
    pub(crate) fn reset_env(&mut self, env: usize, model: &Model, spec: &EpisodeSpec) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            self.setup.tools[l] = ToolDrive::Trajectory(spec.trajectory.clone());
            self.state.clock[l] = 0;
            self.state.active.0[l] = 1.0;
            self.init_lane(l, model, spec);
        }
    }

    /// The tool of lane `l` now (environment time plus `ahead` seconds).
    pub(crate) fn tool_state(&self, l: usize, k: &StepConstants, ahead: f64) -> ToolState {
        self.setup.tools[l].state_at(self.state.clock[l] as f64 * k.dt64 + ahead, k.rest_time)
    }

    /// Replaces what drives the tool of every lane holding `env`.
    pub(crate) fn set_drive(&mut self, env: usize, drive: &ToolDrive) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            self.setup.tools[l] = drive.clone();
        }
    }

    /// Overwrites the positions of every particle of `env` (velocities unchanged).
    pub(crate) fn set_positions(&mut self, env: usize, positions: &[[f32; 3]]) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            for (x, p) in self.state.x.iter_mut().zip(positions) {
                set3(x, l, *p);
            }
        }
    }

    /// Places environment `spec` in lane `l`: positions, springs, cup offsets, disc, parameters.
    fn init_lane(&mut self, l: usize, model: &Model, spec: &EpisodeSpec) {
        let pl = &spec.placement;
        let cup_start = model.cup_start();
        // The package (and the disc in it) turned by its yaw about the vertical through the cup point.
        let (sin, cos) = pl.package_yaw_rad.sin_cos();
        let yaw = |p: [f32; 3]| {
            if pl.package_yaw_rad == 0.0 {
                return p;
            }
            let (dx, dz) = (p[0] - pl.cup_point[0], p[2] - pl.cup_point[2]);
            [
                pl.cup_point[0] + cos * dx + sin * dz,
                p[1],
                pl.cup_point[2] - sin * dx + cos * dz,
            ]
        };
        for (i, off) in model.rest_offsets.iter().enumerate() {
            let anchor = if i < cup_start {
                pl.package_origin
            } else {
                pl.cup_point
            };
            let p = [anchor[0] + off[0], anchor[1] + off[1], anchor[2] + off[2]];
            let p = if i < cup_start { yaw(p) } else { p };
            set3(&mut self.state.x[i], l, p);
            set3(&mut self.setup.x0[i], l, p);
            set3(&mut self.state.v[i], l, [0.0; 3]);
        }
        // Cup offsets from the tool's first pose.
        let tool0 = spec.trajectory.pose_at(f64::NEG_INFINITY);
        let q0 = Quat {
            v: V3::new(
                tool0.orientation[0],
                tool0.orientation[1],
                tool0.orientation[2],
            ),
            w: tool0.orientation[3],
        };
        for k in 0..model.num_cup {
            let c = get3(&self.state.x[cup_start + k], l);
            let d = V3::new(
                c[0] - tool0.position[0],
                c[1] - tool0.position[1],
                c[2] - tool0.position[2],
            );
            let d = if model.config.cups.offsets_in_tool_frame {
                q0.rotate_inv(d)
            } else {
                d
            };
            set3(&mut self.setup.cup_offsets[k], l, [d.x, d.y, d.z]);
        }
        // The cups are built face down (world −y); their axis turns with the tool from here on.
        let down = V3::new(0.0, -1.0, 0.0);
        let axis = if model.config.cups.offsets_in_tool_frame {
            q0.rotate_inv(down)
        } else {
            down
        };
        set3(&mut self.setup.cup_axis_local, l, [axis.x, axis.y, axis.z]);
        let disc_position = yaw(pl.disc_position);
        set3(&mut self.state.disc.com, l, disc_position);
        set3(&mut self.setup.disc_x0, l, disc_position);
        self.setup.disc_hold[l] = pl.disc_hold.map(yaw);
        let q = pl.disc_orientation;
        let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
        let q = q.map(|c| c / norm);
        // A held disc starts level and is turned to its orientation during the rest (see
        // `DiscConfig::hold_orientation`).
        self.setup.disc_turn[l] = self.setup.disc_hold[l]
            .filter(|_| model.config.disc.hold_orientation)
            .map(|_| q);
        let q = if self.setup.disc_turn[l].is_some() {
            [0.0, 0.0, 0.0, 1.0]
        } else {
            q
        };
        let disc = &mut self.state.disc;
        set3(&mut disc.q.v, l, [q[0], q[1], q[2]]);
        disc.q.w.0[l] = q[3];
        set3(&mut disc.v, l, [0.0; 3]);
        set3(&mut disc.w, l, [0.0; 3]);
        for i in 0..model.num_particles() {
            set3(&mut self.state.contact_point[i], l, [0.0; 3]);
            set3(&mut self.state.contact_normal[i], l, [0.0; 3]);
        }
        self.setup.params.set_lane(l, model, spec);
        // Springs: each cup particle to its nearest upper-sheet particle (first minimum wins).
        self.attach_cups_lane(l, model, 0.0, tool0.orientation.map(f64::from));
    }

    /// Bytes held by this block's arrays.
    pub(crate) fn bytes(&self) -> usize {
        self.state.bytes() + self.setup.bytes() + self.solver.bytes() + std::mem::size_of::<Self>()
    }

    /// Stops stepping every lane holding `env`; its state stays as it is.
    pub(crate) fn retire(&mut self, env: usize) {
        for l in 0..W {
            if self.envs[l] == env {
                self.state.active.0[l] = 0.0;
            }
        }
    }

    /// Replaces the material parameters (and object mass) of every lane holding `env`.
    pub(crate) fn set_params(&mut self, env: usize, model: &Model, spec: &EpisodeSpec) {
        for l in 0..W {
            if self.envs[l] == env {
                self.setup.params.set_lane(l, model, spec);
            }
        }
    }

    /// Replaces the tool trajectory of every lane holding `env`.
    pub(crate) fn set_trajectory(&mut self, env: usize, trajectory: &Arc<ToolTrajectory>) {
        self.set_drive(env, &ToolDrive::Trajectory(trajectory.clone()));
    }

    /// Advances every active lane by `substeps` substeps of its own clock.
    pub(crate) fn advance(
        &mut self,
        model: &Model,
        k: &StepConstants,
        substeps: u64,
        parallel: bool,
        simd: Simd,
    ) {
        for _ in 0..substeps {
            // A block whose environments are all frozen or retired would only copy its state over.
            if (0..W).all(|l| !self.real[l] || self.state.active.0[l] < 0.5) {
                return;
            }
            let t = self.state.lane_times(k.dt64, 0.0);
            let step = Substep {
                model,
                k,
                setup: &self.setup,
                t1: self.state.lane_times(k.dt64, k.dt64),
                tool: self.setup.tool_lanes(&t, k.rest_time),
                parallel,
                simd,
            };
            self.solver.substep(&step, &mut self.state);
            // Seal loads and failures (take effect from the next substep).
            let tool_orientation = step.tool.orientation;
            self.update_seals(model, k, tool_orientation, &t);
            let mut due = [false; W];
            for l in 0..W {
                if self.state.active.0[l] > 0.5 {
                    self.state.clock[l] += 1;
                    due[l] = self.state.clock[l].is_multiple_of(k.check_every);
                }
            }
            if due.iter().any(|&d| d) {
                self.check_health(model, k, &due);
            }
        }
    }
}
