//! Batched simulator of a two-layer deformable package lifted by suction cups, with a rigid disc
//! inside, using NVIDIA Warp 1.6 `warp.sim`'s force model, integrated by Warp's semi-implicit
//! Euler or by implicit Euler solved with Vertex Block Descent.
//!
//! # Structure (Warp's split)
//! * [`Model`]: topology and rest data shared by every environment: package particles (two
//!   M x N layers joined by a perimeter seam band), membrane triangles with rest `Dm`, interior
//!   bending edges with rest angles, cup rings, the disc's shape. Built from a [`SceneConfig`]
//!   (`configs/scenes/study.toml` or `configs/scenes/physical-explicit.toml`, or [`SceneConfig::preset`]).
//! * [`EpisodeSpec`] ([`episode`]): what differs per environment: [`Placement`] (package origin,
//!   tool cup point, disc position), material [`Params`], object mass, tool trajectory; and what
//!   an environment reports ([`DiscState`], [`EnvObservation`], [`CupLoad`], events).
//! * The state (`state`): positions/velocities of every particle, the disc's pose and twist, the
//!   cups' seals and each environment's clock, struct-of-arrays in blocks of [`LANES`]
//!   environments (16 where the CPU has AVX-512 and the batch fills two such blocks), plus what
//!   each lane's episode prescribes (parameters, tool drive).
//! * The force laws ([`forces`]): one function per force term, one element at a time, shared by
//!   the solvers.
//! * The solvers (`solvers`, one folder each, behind one interface; the scene's
//!   `integrator.solver` picks one, see [`Solver`]): each maps a block's state to the next
//!   substep.
//! * [`Simulator`]: the batch (model, specs, state blocks, the chosen solver) and the calls to
//!   step, control and read it; rayon across blocks.

//! # Typical use
//! ```
//! use std::sync::Arc;
//! use rlpkg_sim::{EpisodeSpec, Model, Placement, SceneConfig, Simulator, ToolTrajectory};
//!
//! let mut config = SceneConfig::preset("reference")?;
//! config.package.grid = [11, 13]; // coarse grid for the example
//! let model = Arc::new(Model::new(&config)?);
//! let markers = [[0.10, 0.25, -0.55], [0.40, 0.25, -0.30]]; // initial marker positions
//! let placement = Placement::from_markers(&markers, [0.25, 0.26, -0.42], [0.25, 0.2, -0.42])?;
//! let tool = ToolTrajectory::hold([0.25, 0.40, -0.42], [0.0, 0.0, 0.0, 1.0]);
//! let spec = EpisodeSpec {
//!     placement,
//!     params: config.params,
//!     object_mass_kg: 0.57,
//!     disc_mass_scale: None,
//!     vacuum_kpa: None,
//!     trajectory: Arc::new(tool),
//! };
//! let mut sim = Simulator::new(model, vec![spec.clone(), spec])?;
//! sim.step(64);
//! let disc = sim.disc(1);
//! let sheet = sim.particle_positions(0);
//! let markers_now = sim.surface_points(0, &sim.embed(0, &markers));
//! assert!(sim.health_events().is_empty() && disc.position[1].is_finite());
//! assert_eq!(sheet.len(), 286 + 96);
//! assert_eq!(markers_now.len(), 2);
//! # Ok::<(), rlpkg_sim::SimError>(())
//! ```
//!
//! # Conventions
//! World frame = motion-capture frame, **y up**, SI units, f32 like Warp. Quaternions (x, y, z, w).
//! Particle order: lower sheet ("top" layer of the reference code) `0..L`, upper sheet (attached
//! to the cups, "bottom") `L..2L`, then the cups, cup-major; within a layer row-major with rows
//! along the short side (z) and columns along the long side (x). Time 0 of a [`Simulator`] is
//! the start of the rest period (`cups.rest_time_s`); trajectory time 0 comes after it.
//!
//! # Differences from Warp 1.6 / the reference code (deliberate)
//! * Bending clamps the `acos` argument to [−1, 1] (Warp can return NaN for flat hinges).
//! * Particle-disc contact uses the analytic cylinder (radius, thickness) instead of the 58-gon
//!   mesh. Like Warp, the closest point (body frame) and normal (world frame) are regenerated every
//!   `disc.contact_refresh_substeps` (reference 512 = once per 60 Hz frame) and frozen in between.
//!   Recomputing them every substep (setting 1) sounds strictly better but is not: a frozen normal
//!   acts as a contact plane that holds the film under the disc, while per-substep normals let
//!   the coarse particle net slide around the disc's rim, and in the reference scene the disc then
//!   falls through the lower sheet (observed on the 11x13 grid). Particles beyond the disc's
//!   bounding sphere (+ particle radius) get no contact force (Warp would apply a frozen plane
//!   there too). Cup particles collide with the disc only if `cups.collide_with_disc`.
//!   Disc-ground contact uses `disc.rim_points` points per rim (the mesh's rim vertices).
//! * Boundary bending edges (Warp adds them but skips them at run time) are not stored.
//! * The tool trajectory is interpolated linearly (nlerp for orientations) at its own timestamps;
//!   the reference uses a cubic spline on a slightly stretched time base.
//! * Health checks freeze an environment whose state is non-finite or exploding.
//! * Optionally ([`Placement::disc_hold`], `disc.hold_at_recorded_start`) the disc is carried to
//!   the recorded object's start during the rest and released at trajectory time 0, optionally
//!   (`disc.hold_orientation`) turned to [`Placement::disc_orientation`] on the way. The reference
//!   lets it slide freely during the rest; in its scene the disc then starts a replay 3-4 cm from
//!   where the recording has it, and that offset persists through the whole trajectory.
//!
//! # Determinism
//! Each environment's arithmetic is independent of the others and of the thread count: lanes never
//! interact, there is no fused multiply-add, and sums run in a fixed order. An environment gives
//! bit-identical results alone, in any batch, on any number of threads.

// Lane loops index several parallel arrays by lane on purpose: that is the pattern the compiler
// turns into packed SIMD.
#![allow(clippy::needless_range_loop)]
#![warn(missing_docs)]

pub mod bench;
pub mod config;
mod constants;
pub mod embed;
pub mod episode;
pub mod error;
pub mod forces;
pub mod math;
pub mod model;
pub mod randomize;
mod simulator;
mod solvers;
mod state;
#[cfg(test)]
mod test_support;
pub mod tool;
pub mod trajectory;

pub use config::{DriveMode, InertiaModel, Params, SceneConfig, SealConfig, Solver, ToolLimits};
pub use embed::{EmbeddedPoint, Sheet, SurfaceEmbedding};
pub use episode::{
    CupLoad, DiscState, EnvObservation, EpisodeSpec, HealthEvent, HealthReason, NoSealReason,
    Placement, SealEvent, SealEventKind,
};
pub use error::SimError;
pub use model::{marker_grid_points, DiscMass, Model};
pub use randomize::{PosteriorDraws, Randomization};
pub use simulator::{EnvSnapshot, Simulator, LANES};
pub use tool::{ToolCommand, ToolCommandReport, ToolState};
pub use trajectory::{ToolPose, ToolSample, ToolTrajectory};
