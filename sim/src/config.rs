//! Scene configuration: the TOML presets under `configs/` (`scenes/study.toml` as `reference`, `scenes/physical-explicit.toml` as `physical`),
//! loaded with serde (`deny_unknown_fields`) and range-checked with errors naming file, key and
//! expected range. Units are SI throughout.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::SimError;

/// Text of `configs/scenes/study.toml`, embedded at build time.
pub const REFERENCE_TOML: &str = include_str!("../../configs/scenes/study.toml");
/// Text of `configs/scenes/physical-explicit.toml`, embedded at build time.
pub const PHYSICAL_TOML: &str = include_str!("../../configs/scenes/physical-explicit.toml");

/// The names of the material parameters, in [`Params::entries`] order.
pub const PARAM_NAMES: [&str; 14] = [
    "k_tri_e", "k_tri_a", "k_tri_d", "k_edge_e", "k_edge_d", "k_cup_e", "k_cup_a", "k_cup_d",
    "k_spr_e", "k_spr_d", "k_con_e", "k_con_d", "k_con_f", "mu_con",
];

/// The range of every parameter, in [`PARAM_NAMES`] order: physical signs (area stiffnesses
/// strictly positive) and bounds far beyond any material, against typos.
const PARAM_RANGES: [(f32, f32); 14] = [
    (0.0, 1e10),
    (1e-6, 1e10),
    (0.0, 1e8),
    (0.0, 1e8),
    (0.0, 1e6),
    (0.0, 1e10),
    (1e-6, 1e10),
    (0.0, 1e8),
    (0.0, 1e10),
    (0.0, 1e8),
    (0.0, 1e10),
    (0.0, 1e8),
    (0.0, 1e8),
    (0.0, 100.0),
];

/// Material parameters of one environment, named as in the paper.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Package triangle deviatoric stiffness (Warp `tri_ke`, k_mu).
    pub k_tri_e: f32,
    /// Package triangle area stiffness (Warp `tri_ka`, k_lambda).
    pub k_tri_a: f32,
    /// Package triangle damping (Warp `tri_kd`).
    pub k_tri_d: f32,
    /// Package bending stiffness (Warp `edge_ke`).
    pub k_edge_e: f32,
    /// Package bending damping (Warp `edge_kd`).
    pub k_edge_d: f32,
    /// Cup shell triangle stiffness.
    pub k_cup_e: f32,
    /// Cup shell triangle area stiffness.
    pub k_cup_a: f32,
    /// Cup shell triangle damping.
    pub k_cup_d: f32,
    /// Cup-to-package attachment spring stiffness (N/m).
    pub k_spr_e: f32,
    /// Cup-to-package attachment spring damping (N·s/m).
    pub k_spr_d: f32,
    /// Disc contact stiffness (the disc shape's `ke`).
    pub k_con_e: f32,
    /// Disc contact damping (shape `kd`).
    pub k_con_d: f32,
    /// Disc contact friction stiffness (shape `kf`).
    pub k_con_f: f32,
    /// Disc contact friction coefficient (shape `mu`).
    pub mu_con: f32,
}

impl Params {
    /// (name, value, lowest, highest) of every parameter, for range checks and display.
    pub fn entries(&self) -> [(&'static str, f32, f32, f32); 14] {
        let values = [
            self.k_tri_e,
            self.k_tri_a,
            self.k_tri_d,
            self.k_edge_e,
            self.k_edge_d,
            self.k_cup_e,
            self.k_cup_a,
            self.k_cup_d,
            self.k_spr_e,
            self.k_spr_d,
            self.k_con_e,
            self.k_con_d,
            self.k_con_f,
            self.mu_con,
        ];
        std::array::from_fn(|i| {
            let (lo, hi) = PARAM_RANGES[i];
            (PARAM_NAMES[i], values[i], lo, hi)
        })
    }

    /// The `[lowest, highest]` value the parameter called `name` may take (as in
    /// [`Params::entries`]); `None` for a name that is not a parameter.
    pub fn range(name: &str) -> Option<(f32, f32)> {
        PARAM_NAMES
            .iter()
            .position(|n| *n == name)
            .map(|i| PARAM_RANGES[i])
    }

    /// The parameter named `name` (as in [`Params::entries`]), for setting by name.
    pub fn get_mut(&mut self, name: &str) -> Option<&mut f32> {
        Some(match name {
            "k_tri_e" => &mut self.k_tri_e,
            "k_tri_a" => &mut self.k_tri_a,
            "k_tri_d" => &mut self.k_tri_d,
            "k_edge_e" => &mut self.k_edge_e,
            "k_edge_d" => &mut self.k_edge_d,
            "k_cup_e" => &mut self.k_cup_e,
            "k_cup_a" => &mut self.k_cup_a,
            "k_cup_d" => &mut self.k_cup_d,
            "k_spr_e" => &mut self.k_spr_e,
            "k_spr_d" => &mut self.k_spr_d,
            "k_con_e" => &mut self.k_con_e,
            "k_con_d" => &mut self.k_con_d,
            "k_con_f" => &mut self.k_con_f,
            "mu_con" => &mut self.mu_con,
            _ => return None,
        })
    }

    /// Checks every value is finite and in range; `source` names the file for the message.
    pub fn validate(&self, source: &str) -> Result<(), SimError> {
        for (name, value, lo, hi) in self.entries() {
            check(
                source,
                &format!("params.{name}"),
                value as f64,
                lo as f64,
                hi as f64,
            )?;
        }
        Ok(())
    }
}

/// The two-layer package.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PackageConfig {
    /// Vertices per layer: [along the short side (world z), along the long side (world x)].
    /// Table 2 sizes are [11, 13], [16, 19], [21, 25], [26, 31]; the reference "marker grid 6x7
    /// with p particles in between" is [6 + 5p, 7 + 6p].
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub grid: [usize; 2],
    /// Package size [short side, long side] in m.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub size_m: [f32; 2],
    /// Distance between the two layers at build time (m).
    pub thickness_m: f32,
    /// Mass of every package particle (kg); the reference uses 0.8. Exclusive with `film_mass_kg`.
    #[serde(default)]
    pub particle_mass_kg: Option<f32>,
    /// Total film mass spread evenly over the particles (kg); the real film is 0.022.
    #[serde(default)]
    pub film_mass_kg: Option<f32>,
    /// Contact radius of package and cup particles (m); default max(cell sizes, thickness) as in
    /// the reference.
    #[serde(default)]
    pub particle_radius_m: Option<f32>,
}

/// How the cups follow the tool.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriveMode {
    /// The reference velocity servo: v = Kp·(target − x) + Kff·v_tool, then integrated with forces.
    Servo,
    /// Cup particles are placed exactly on their targets every substep.
    Kinematic,
}

/// The suction tool: cups, their rings, attachment springs and drive.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CupsConfig {
    /// Cup centres sit on a horizontal circle of this radius around the tool's cup point (m).
    pub circle_radius_m: f32,
    /// Angle of each cup on that circle (degrees; offset = r·(sin a, 0, cos a)). One entry per cup.
    pub angles_deg: Vec<f32>,
    /// Angular samples per ring (reference 8).
    pub samples: usize,
    /// Rings per cup (reference 3).
    pub rings: usize,
    /// Inner ring radius (m).
    pub inner_radius_m: f32,
    /// Nominal outer radius (m); ring h has radius inner + (outer − inner)·h / rings, as the
    /// reference (so the outer radius itself is never reached).
    pub outer_radius_m: f32,
    /// Mass of one cup, spread over its particles (kg); the reference uses 1e5.
    pub cup_mass_kg: f32,
    /// Cup bending stiffness (fixed, not calibrated).
    pub edge_ke: f32,
    /// Cup bending damping.
    pub edge_kd: f32,
    /// All springs share the minimum initial length as rest length (reference) when true; each
    /// keeps its own initial length when false.
    pub common_rest_length: bool,
    /// Servo or kinematic drive.
    pub drive: DriveMode,
    /// Servo proportional gain Kp (1/s).
    pub servo_kp: f32,
    /// Servo feed-forward gain Kff.
    pub servo_kff: f32,
    /// Cup offsets from the tool are world-frame vectors rotated by the absolute tool orientation
    /// (reference, §12 item 7) when false; tool-frame offsets (the correct rigid transform) when true.
    pub offsets_in_tool_frame: bool,
    /// Seconds the tool is held at its first pose before the trajectory starts (reference 2.0).
    pub rest_time_s: f32,
    /// Cup particles also collide with the disc (reference: they do; physically the film is
    /// always between them).
    pub collide_with_disc: bool,
}

/// How the disc's inertia is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InertiaModel {
    /// The reference code's: the diameter used as the radius for the scaled mass, plus a solid
    /// cylinder of `extra_mass_kg` (the mesh's own density-1000 mass).
    Reference,
    /// A solid cylinder of the total mass with the true radius.
    SolidCylinder,
}

/// The rigid disc inside the package.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscConfig {
    /// Disc radius (m).
    pub radius_m: f32,
    /// Disc thickness (m).
    pub thickness_m: f32,
    /// The object mass given per environment is multiplied by this (reference 100).
    pub mass_scale: f32,
    /// Mass added on top (reference: the mesh's own 0.301 kg).
    pub extra_mass_kg: f32,
    /// Inertia rule.
    pub inertia: InertiaModel,
    /// Points per rim used for disc-ground contact (the reference mesh has 58-gon rims).
    pub rim_points: usize,
    /// Disc shape thickness subtracted in disc-ground contact (Warp default 1e-5).
    pub shape_thickness_m: f32,
    /// Particle-disc contacts (closest point in the body frame, world normal) are regenerated
    /// every this many substeps and frozen in between, as Warp's once-per-frame `collide()`
    /// (reference 512). 1 recomputes the analytic closest point every substep.
    pub contact_refresh_substeps: u32,
    /// When a recording is replayed, hold the disc at the recorded object's start position during
    /// the rest period and release it at trajectory time 0 (`Placement::disc_hold`), so the replay
    /// starts where the recording does. False (the reference's rule): the disc is free from the
    /// start and slides to wherever the sagging package lets it rest.
    #[serde(default)]
    pub hold_at_recorded_start: bool,
    /// During a rest-period hold (`Placement::disc_hold`), also carry the disc's orientation:
    /// turned from level to `Placement::disc_orientation` over the first half of the rest, held
    /// there for the second half, released with the centre. Needed for a tilted disc (started
    /// tilted, its rim cuts through the flat package's film) and keeps a level one from turning
    /// into the film while its centre is held (on the coarse SI scene: no disc lost in 300
    /// randomised scripted transports, against 4.3 % with a free rotation). False: the rotation is
    /// free throughout the hold (as `configs/scenes/calibrated-study.toml` was fitted).
    #[serde(default)]
    pub hold_orientation: bool,
}

/// Contact materials other than the calibrated disc parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactConfig {
    /// Model-wide soft contact stiffness (particle-ground; averaged into particle-disc).
    pub soft_ke: f32,
    /// Model-wide soft contact damping.
    pub soft_kd: f32,
    /// Model-wide soft contact friction stiffness.
    pub soft_kf: f32,
    /// Model-wide soft contact friction coefficient.
    pub soft_mu: f32,
    /// Average the disc parameters with the model-wide values, as Warp does (reference); use the
    /// disc parameters as they are when false.
    pub average_disc_with_soft: bool,
    /// Ground shape stiffness (averaged with the disc's for disc-ground contact).
    pub ground_ke: f32,
    /// Ground shape damping.
    pub ground_kd: f32,
    /// Ground shape friction stiffness.
    pub ground_kf: f32,
    /// Ground shape friction coefficient.
    pub ground_mu: f32,
}

/// Time stepping.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntegratorConfig {
    /// Substeps per simulated second (dt = 1 / rate; reference 30720).
    pub substep_rate_hz: f64,
    /// Gravity along world y (m/s²; reference −4.0).
    pub gravity_m_s2: f32,
    /// Rigid body angular damping (Warp default 0.05).
    pub angular_damping: f32,
    /// Particle speed clamp (Warp `particle_max_velocity`, m/s).
    pub max_particle_speed_m_s: f32,
    /// Which integrator advances the state (the reference preset's is Warp's explicit one).
    #[serde(default)]
    pub solver: Solver,
    /// Iterations per substep of block descent and global descent (sweeps; for global descent
    /// each is a global step and a sweep; ignored by the explicit integrator).
    #[serde(default = "default_iterations")]
    pub iterations: u32,
    /// Block descent: Chebyshev acceleration of the sweeps with this spectral radius estimate
    /// (0 = off; the VBD paper uses about 0.9).
    #[serde(default)]
    pub chebyshev_rho: f32,
}

fn default_iterations() -> u32 {
    10
}

/// The solvers behind [`IntegratorConfig::solver`] (one folder each in `sim/src/solvers/`, one
/// interface).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Solver {
    /// Warp's semi-implicit (symplectic) Euler: one force evaluation per substep, stable only for
    /// small substeps (bending sets the limit). The reference preset's integrator.
    #[default]
    SemiImplicitEuler,
    /// Implicit Euler solved by Vertex Block Descent (Chen et al. 2024): per-vertex 3x3 Newton steps
    /// in Gauss-Seidel order, the disc as a 6-DOF block in the same sweeps; stable at large
    /// substeps. Needs kinematic cups.
    BlockDescent,
    /// Block descent's implicit Euler step with a global step before each sweep: the residual
    /// forces solved through one prefactored banded matrix for the whole sheet (membrane
    /// Laplacian, inertia, springs and contacts), so stiff real film converges at 300 substeps/s.
    /// Needs kinematic cups.
    GlobalDescent,
}

/// Health checks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HealthConfig {
    /// Check every this many substeps.
    pub check_every: u32,
    /// A particle or the disc faster than this is exploding (m/s).
    pub max_speed_m_s: f32,
    /// A particle or the disc further than this from its start is exploding (m).
    pub max_displacement_m: f32,
    /// Freeze an environment whose disc left the package ([`crate::HealthReason::ObjectOutside`]).
    /// On by default; tests of machinery that do not care about the physics of very coarse grids
    /// (where the disc slips through the sheet) turn it off.
    #[serde(default = "yes")]
    pub object_outside: bool,
}

fn yes() -> bool {
    true
}

/// The suction seal between each cup and the film: when a cup holds, peels or slides off.
///
/// The model follows Dex-Net 3.0's suction contact (Mahler et al., ICRA 2018): a cup's lip
/// holds the film with the vacuum force `V = Δp · A` (vacuum gauge pressure times the sealed
/// area inside the lip), it resists pull-off while the normal load stays below `V`, and it resists
/// shear by friction while the tangential load stays below `μ · (V − F_n)`, the vacuum's clamping
/// force minus the normal pull (the vacuum-gripper sizing rule `F = Δp · A` with friction load
/// cases, as in Mantriota 2007). Peeling is modelled per lip element: every attachment spring of a
/// cup is one element of its lip, holding `lip_strength_ratio` times its even share of `V`; an
/// element pulled harder than that along the cup axis lets go, the cup's sealed area (and so `V`)
/// shrinks with the fraction of elements left, and below `min_sealed_fraction` the vacuum is lost
/// and the whole cup detaches. Loads are low-pass filtered with time constant `load_filter_s`
/// (the lip's compliance; without it the explicit integrator's substep-scale ringing would count).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SealConfig {
    /// Seal physics on. Off (the study's model): springs never let go and loads are still reported.
    pub enabled: bool,
    /// Vacuum gauge pressure under a sealed cup (kPa).
    pub vacuum_kpa: f32,
    /// Radius of the cup's lip, which bounds the area the vacuum acts on (m).
    pub lip_radius_m: f32,
    /// Cup-on-film friction coefficient.
    pub friction: f32,
    /// A lip element (one attachment spring) peels when its pull along the cup axis exceeds this
    /// multiple of its even share of the vacuum force.
    pub lip_strength_ratio: f32,
    /// Below this fraction of sealed lip elements the vacuum is lost and the cup detaches.
    pub min_sealed_fraction: f32,
    /// Loading: a cup seals only if its lip is at most this far from the film's plane (m).
    pub max_gap_m: f32,
    /// Loading: a cup seals only if the film's plane under it is tilted at most this much from
    /// the cup's face (degrees).
    pub max_tilt_deg: f32,
    /// Loading: a cup seals only if the film under its lip deviates at most this much from a
    /// plane (m); a fold or wrinkle under the lip leaks.
    pub max_fold_m: f32,
    /// Time constant of the low-pass filter on cup and lip loads (s).
    pub load_filter_s: f32,
}

impl Default for SealConfig {
    /// Seal physics off, with the physical scene's cup and vacuum values.
    fn default() -> Self {
        SealConfig {
            enabled: false,
            vacuum_kpa: 20.0,
            lip_radius_m: 0.02,
            friction: 0.5,
            lip_strength_ratio: 3.0,
            min_sealed_fraction: 0.5,
            max_gap_m: 0.02,
            max_tilt_deg: 20.0,
            max_fold_m: 0.005,
            load_filter_s: 0.01,
        }
    }
}

/// Hard limits of the robot carrying the tool. Tool commands beyond them are clamped, and every
/// clamp is reported ([`crate::ToolCommandReport`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolLimits {
    /// Largest linear speed of the tool (m/s).
    pub max_speed_m_s: f32,
    /// Largest linear acceleration (m/s²).
    pub max_accel_m_s2: f32,
    /// Largest angular speed (rad/s).
    pub max_angular_speed_rad_s: f32,
    /// Largest angular acceleration (rad/s²).
    pub max_angular_accel_rad_s2: f32,
}

impl Default for ToolLimits {
    /// A UR10e-class arm carrying a light tool: 2 m/s, 10 m/s², π rad/s, 20 rad/s².
    fn default() -> Self {
        ToolLimits {
            max_speed_m_s: 2.0,
            max_accel_m_s2: 10.0,
            max_angular_speed_rad_s: std::f32::consts::PI,
            max_angular_accel_rad_s2: 20.0,
        }
    }
}

/// A whole scene: everything but the per-environment placement and trajectory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// The package.
    pub package: PackageConfig,
    /// The suction tool.
    pub cups: CupsConfig,
    /// The internal object.
    pub disc: DiscConfig,
    /// Contact materials.
    pub contact: ContactConfig,
    /// Time stepping.
    pub integrator: IntegratorConfig,
    /// Health checks.
    pub health: HealthConfig,
    /// Suction seal model (off when the section is absent).
    #[serde(default)]
    pub seal: SealConfig,
    /// Robot limits for commanded tool motion (defaults when the section is absent).
    #[serde(default)]
    pub tool_limits: ToolLimits,
    /// Default material parameters (each environment may override them).
    pub params: Params,
}

fn check(file: &str, key: &str, value: f64, lo: f64, hi: f64) -> Result<(), SimError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(SimError::Range {
            file: file.to_string(),
            key: key.to_string(),
            // An f32 key widened to f64 is echoed as the f32 it is (`-0.1`, not
            // `-0.10000000149011612`); an f64 that is not an f32 keeps all its digits.
            value: if (value as f32) as f64 == value {
                format!("{}", value as f32)
            } else {
                format!("{value}")
            },
            expected: format!("a finite number in [{lo}, {hi}]"),
        })
    }
}

fn check_count(file: &str, key: &str, value: usize, lo: usize, hi: usize) -> Result<(), SimError> {
    if (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(SimError::Range {
            file: file.to_string(),
            key: key.to_string(),
            value: value.to_string(),
            expected: format!("an integer in [{lo}, {hi}]"),
        })
    }
}

impl SceneConfig {
    /// One of the embedded presets: `reference` or `physical`.
    pub fn preset(name: &str) -> Result<Self, SimError> {
        match name {
            "reference" => Self::from_toml_str(REFERENCE_TOML, "configs/scenes/study.toml"),
            "physical" => {
                Self::from_toml_str(PHYSICAL_TOML, "configs/scenes/physical-explicit.toml")
            }
            other => Err(SimError::UnknownPreset(other.to_string())),
        }
    }

    /// Loads and validates a TOML file.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Parses and validates TOML text; `source` names it in error messages.
    pub fn from_toml_str(text: &str, source: &str) -> Result<Self, SimError> {
        let config: SceneConfig = toml::from_str(text).map_err(|e| SimError::Parse {
            file: source.to_string(),
            message: e.to_string(),
        })?;
        config.validate(source)?;
        Ok(config)
    }

    /// The substep length (s).
    pub fn dt(&self) -> f32 {
        (1.0 / self.integrator.substep_rate_hz) as f32
    }

    /// Range checks of every key; `source` names the file in messages.
    pub fn validate(&self, source: &str) -> Result<(), SimError> {
        let f = source;
        let p = &self.package;
        check_count(f, "package.grid[0]", p.grid[0], 2, 200)?;
        check_count(f, "package.grid[1]", p.grid[1], 2, 200)?;
        check(f, "package.size_m[0]", p.size_m[0] as f64, 1e-3, 10.0)?;
        check(f, "package.size_m[1]", p.size_m[1] as f64, 1e-3, 10.0)?;
        check(f, "package.thickness_m", p.thickness_m as f64, 1e-6, 0.1)?;
        match (p.particle_mass_kg, p.film_mass_kg) {
            (Some(m), None) => check(f, "package.particle_mass_kg", m as f64, 1e-9, 1e4)?,
            (None, Some(m)) => check(f, "package.film_mass_kg", m as f64, 1e-6, 1e5)?,
            _ => {
                return Err(SimError::Range {
                    file: f.to_string(),
                    key: "package.particle_mass_kg / package.film_mass_kg".into(),
                    value: "both or neither".into(),
                    expected: "exactly one of the two keys".into(),
                })
            }
        }
        if let Some(r) = p.particle_radius_m {
            check(f, "package.particle_radius_m", r as f64, 1e-5, 1.0)?;
        }
        let c = &self.cups;
        check(
            f,
            "cups.circle_radius_m",
            c.circle_radius_m as f64,
            0.0,
            1.0,
        )?;
        check_count(
            f,
            "cups.angles_deg (number of cups)",
            c.angles_deg.len(),
            1,
            16,
        )?;
        for (i, a) in c.angles_deg.iter().enumerate() {
            check(
                f,
                &format!("cups.angles_deg[{i}]"),
                *a as f64,
                -360.0,
                360.0,
            )?;
            // Two cups at one angle of the circle would be built in one place.
            let same = |b: &f32| (a - b).rem_euclid(360.0).min((b - a).rem_euclid(360.0)) < 1e-3;
            if c.circle_radius_m > 0.0 && c.angles_deg[..i].iter().any(same) {
                return Err(SimError::Range {
                    file: f.to_string(),
                    key: format!("cups.angles_deg[{i}]"),
                    value: a.to_string(),
                    expected: "an angle no other cup has (each cup at its own place on the circle)"
                        .to_string(),
                });
            }
        }
        check_count(f, "cups.samples", c.samples, 3, 64)?;
        check_count(f, "cups.rings", c.rings, 2, 16)?;
        check(f, "cups.inner_radius_m", c.inner_radius_m as f64, 1e-4, 0.5)?;
        check(
            f,
            "cups.outer_radius_m",
            c.outer_radius_m as f64,
            c.inner_radius_m as f64 + 1e-4,
            0.5,
        )?;
        check(f, "cups.cup_mass_kg", c.cup_mass_kg as f64, 1e-6, 1e8)?;
        check(f, "cups.edge_ke", c.edge_ke as f64, 0.0, 1e8)?;
        check(f, "cups.edge_kd", c.edge_kd as f64, 0.0, 1e6)?;
        check(f, "cups.servo_kp", c.servo_kp as f64, 0.0, 1e4)?;
        check(f, "cups.servo_kff", c.servo_kff as f64, 0.0, 10.0)?;
        check(f, "cups.rest_time_s", c.rest_time_s as f64, 0.0, 60.0)?;
        let d = &self.disc;
        check(f, "disc.radius_m", d.radius_m as f64, 1e-3, 1.0)?;
        check(f, "disc.thickness_m", d.thickness_m as f64, 1e-4, 1.0)?;
        check(f, "disc.mass_scale", d.mass_scale as f64, 1e-3, 1e4)?;
        check(f, "disc.extra_mass_kg", d.extra_mass_kg as f64, 0.0, 1e4)?;
        check_count(f, "disc.rim_points", d.rim_points, 3, 256)?;
        check(
            f,
            "disc.shape_thickness_m",
            d.shape_thickness_m as f64,
            0.0,
            0.01,
        )?;
        check_count(
            f,
            "disc.contact_refresh_substeps",
            d.contact_refresh_substeps as usize,
            1,
            1 << 20,
        )?;
        let k = &self.contact;
        check(f, "contact.soft_ke", k.soft_ke as f64, 0.0, 1e10)?;
        check(f, "contact.soft_kd", k.soft_kd as f64, 0.0, 1e8)?;
        check(f, "contact.soft_kf", k.soft_kf as f64, 0.0, 1e8)?;
        check(f, "contact.soft_mu", k.soft_mu as f64, 0.0, 100.0)?;
        check(f, "contact.ground_ke", k.ground_ke as f64, 0.0, 1e10)?;
        check(f, "contact.ground_kd", k.ground_kd as f64, 0.0, 1e8)?;
        check(f, "contact.ground_kf", k.ground_kf as f64, 0.0, 1e8)?;
        check(f, "contact.ground_mu", k.ground_mu as f64, 0.0, 100.0)?;
        let i = &self.integrator;
        check(
            f,
            "integrator.substep_rate_hz",
            i.substep_rate_hz,
            20.0,
            1e8,
        )?;
        check(
            f,
            "integrator.gravity_m_s2",
            i.gravity_m_s2 as f64,
            -100.0,
            100.0,
        )?;
        check(
            f,
            "integrator.angular_damping",
            i.angular_damping as f64,
            0.0,
            1e3,
        )?;
        check(
            f,
            "integrator.max_particle_speed_m_s",
            i.max_particle_speed_m_s as f64,
            1e-3,
            1e6,
        )?;
        check_count(f, "integrator.iterations", i.iterations as usize, 1, 1000)?;
        check(
            f,
            "integrator.chebyshev_rho",
            i.chebyshev_rho as f64,
            0.0,
            0.999,
        )?;
        let implicit = match i.solver {
            Solver::SemiImplicitEuler => None,
            Solver::BlockDescent => Some("block_descent"),
            Solver::GlobalDescent => Some("global_descent"),
        };
        if let Some(name) = implicit {
            if self.cups.drive != DriveMode::Kinematic {
                return Err(SimError::Range {
                    file: f.to_string(),
                    key: "cups.drive".to_string(),
                    value: "\"servo\"".to_string(),
                    expected: format!("\"kinematic\" with integrator.solver = \"{name}\""),
                });
            }
        }
        let h = &self.health;
        check_count(f, "health.check_every", h.check_every as usize, 1, 1 << 20)?;
        check(f, "health.max_speed_m_s", h.max_speed_m_s as f64, 1e-3, 1e6)?;
        check(
            f,
            "health.max_displacement_m",
            h.max_displacement_m as f64,
            1e-3,
            1e4,
        )?;
        let s = &self.seal;
        check(f, "seal.vacuum_kpa", s.vacuum_kpa as f64, 0.0, 101.325)?;
        check(f, "seal.lip_radius_m", s.lip_radius_m as f64, 1e-4, 0.5)?;
        check(f, "seal.friction", s.friction as f64, 0.0, 10.0)?;
        check(
            f,
            "seal.lip_strength_ratio",
            s.lip_strength_ratio as f64,
            1.0,
            1e3,
        )?;
        check(
            f,
            "seal.min_sealed_fraction",
            s.min_sealed_fraction as f64,
            0.0,
            1.0,
        )?;
        check(f, "seal.max_gap_m", s.max_gap_m as f64, 0.0, 1.0)?;
        check(f, "seal.max_tilt_deg", s.max_tilt_deg as f64, 0.0, 90.0)?;
        check(f, "seal.max_fold_m", s.max_fold_m as f64, 0.0, 1.0)?;
        check(f, "seal.load_filter_s", s.load_filter_s as f64, 0.0, 10.0)?;
        let t = &self.tool_limits;
        check(
            f,
            "tool_limits.max_speed_m_s",
            t.max_speed_m_s as f64,
            1e-3,
            100.0,
        )?;
        check(
            f,
            "tool_limits.max_accel_m_s2",
            t.max_accel_m_s2 as f64,
            1e-3,
            1e4,
        )?;
        check(
            f,
            "tool_limits.max_angular_speed_rad_s",
            t.max_angular_speed_rad_s as f64,
            1e-3,
            1e3,
        )?;
        check(
            f,
            "tool_limits.max_angular_accel_rad_s2",
            t.max_angular_accel_rad_s2 as f64,
            1e-3,
            1e5,
        )?;
        self.params.validate(source)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_load() {
        let r = SceneConfig::preset("reference").unwrap();
        assert_eq!(r.integrator.gravity_m_s2, -4.0);
        assert_eq!(r.integrator.substep_rate_hz, 30720.0);
        assert_eq!(r.package.particle_mass_kg, Some(0.8));
        let p = SceneConfig::preset("physical").unwrap();
        assert_eq!(p.integrator.gravity_m_s2, -9.81);
        assert_eq!(p.package.film_mass_kg, Some(0.022));
        assert!(SceneConfig::preset("nope").is_err());
    }

    #[test]
    fn unknown_key_is_rejected_with_its_name() {
        let text = REFERENCE_TOML.replace("[params]", "[params]\nk_bogus = 1.0");
        let err = SceneConfig::from_toml_str(&text, "my.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("my.toml") && err.contains("k_bogus"), "{err}");
    }

    #[test]
    fn out_of_range_names_file_key_and_range() {
        let text = REFERENCE_TOML.replace("mu_con = 0.5", "mu_con = -3.0");
        let err = SceneConfig::from_toml_str(&text, "bad.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("bad.toml") && err.contains("params.mu_con") && err.contains("[0, 100]"),
            "{err}"
        );
        let text = REFERENCE_TOML.replace("grid = [21, 25]", "grid = [1, 25]");
        let err = SceneConfig::from_toml_str(&text, "bad.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("package.grid[0]"), "{err}");
        // -180 and 180 are one place on the circle.
        let text = REFERENCE_TOML.replace(
            "angles_deg = [0.0, 90.0, 180.0, 270.0]",
            "angles_deg = [0.0, 90.0, 180.0, -180.0]",
        );
        let err = SceneConfig::from_toml_str(&text, "bad.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("cups.angles_deg[3]") && err.contains("no other cup"),
            "{err}"
        );
    }

    #[test]
    fn fixed_length_arrays_reject_extra_and_missing_values() {
        for bad in ["grid = [16, 19, 3]", "grid = [16]"] {
            let text = REFERENCE_TOML.replace("grid = [21, 25]", bad);
            let err = SceneConfig::from_toml_str(&text, "bad.toml")
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("bad.toml")
                    && err.contains("grid")
                    && err.contains("array of length 2"),
                "{err}"
            );
        }
    }

    #[test]
    fn mass_keys_are_exclusive() {
        let text = REFERENCE_TOML.replace(
            "particle_mass_kg = 0.8",
            "particle_mass_kg = 0.8\nfilm_mass_kg = 0.02",
        );
        let err = SceneConfig::from_toml_str(&text, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("exactly one"), "{err}");
    }
}
