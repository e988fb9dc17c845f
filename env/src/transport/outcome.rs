//! Episode outcomes of the transport task for any driver (a trained policy, the scripted
//! baseline), over the same seeded episodes, and the summary the evaluation table prints.

use glam::DVec3;
use serde::Serialize;

use super::geometry::{quat, v3};
use super::{info_names, Transport};
use crate::{EnvError, VecEnv};
use rlpkg_sim::config::PARAM_NAMES;

/// How an episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ending {
    /// Placed within the tolerances with the object settled.
    Success,
    /// A cup's seal failed (peeled, slid, or never sealed).
    CupDetached,
    /// The object left the package's reach (further than the failure distance from the tool).
    Dropped,
    /// The simulation's health check stopped the copy.
    Unhealthy,
    /// The time limit came first.
    TimedOut,
}

impl Ending {
    /// The ending as `summary.json` and `episodes.csv` name it.
    pub fn name(self) -> &'static str {
        match self {
            Ending::Success => "success",
            Ending::CupDetached => "cup_detached",
            Ending::Dropped => "dropped",
            Ending::Unhealthy => "unhealthy",
            Ending::TimedOut => "timed_out",
        }
    }
}

/// One episode's outcome.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EpisodeOutcome {
    /// How it ended.
    pub ending: Ending,
    /// Simulated time from pick to the end of the episode (s).
    pub time_s: f64,
    /// Undiscounted return.
    pub episode_return: f64,
    /// Distance the object travelled relative to the tool over the episode (m).
    pub object_motion_m: f64,
    /// Largest seal utilisation (load / capacity) of any cup at any control step.
    pub peak_seal_utilisation: f64,
    /// The tool's angular jerk, mean over the episode's control steps of the change of its
    /// angular acceleration per step over the step (rad/s^3): what a wobbling tool costs.
    pub angular_jerk_rad_s3: f64,
    /// Settled package (variant) the episode started from.
    pub package: usize,
}

/// The tool and the object of one copy at one control step (see [`Transport::trace_point`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TracePoint {
    /// Time since the episode's start (s).
    pub time_s: f64,
    /// Commanded speed along the path (m/s).
    pub path_speed_m_s: f64,
    /// The tool's measured speed (m/s).
    pub tool_speed_m_s: f64,
    /// Angle of the tool's axis from its orientation at pick (degrees).
    pub tool_tilt_deg: f64,
    /// The object's centre in the tool frame (m).
    pub object_in_tool_m: [f64; 3],
    /// Largest seal utilisation of any cup.
    pub peak_seal_utilisation: f64,
}

impl Transport {
    /// Copy `env`'s tool and object now, for plots of an episode.
    pub fn trace_point(&self, env: usize) -> TracePoint {
        let episode = &self.episodes[env];
        let state = &self.states[env];
        let start_axis = self.paths[episode.path].start_orientation * DVec3::Y;
        let axis = quat(state.tool_orientation) * DVec3::Y;
        TracePoint {
            time_s: episode.steps as f64 * self.dt,
            path_speed_m_s: episode.path_speed,
            tool_speed_m_s: v3(state.tool_velocity).length(),
            tool_tilt_deg: axis.dot(start_axis).clamp(-1.0, 1.0).acos().to_degrees(),
            object_in_tool_m: v3(state.disc_in_tool.position).to_array(),
            peak_seal_utilisation: self.peak_utilisation(env),
        }
    }
}

/// Runs the first episode of every copy of `env` (copy `i` is seeded from `seed` as
/// [`VecEnv::reset`] does) with `act` choosing the actions from the environment and its actor
/// observations, and returns one outcome per copy. Finished copies are retired
/// ([`Transport::set_retire_finished`]), so each block of copies costs its slowest episode.
pub fn run_episodes<E: From<EnvError>>(
    env: &mut Transport,
    seed: u64,
    act: impl FnMut(&Transport, &[f32]) -> Result<Vec<f32>, E>,
) -> Result<Vec<EpisodeOutcome>, E> {
    Ok(run_traced_episodes(env, seed, &[], act)?.0)
}

/// As [`run_episodes`], and the trace of each copy in `traced` (its start, then every control
/// step until its episode ends).
pub fn run_traced_episodes<E: From<EnvError>>(
    env: &mut Transport,
    seed: u64,
    traced: &[usize],
    mut act: impl FnMut(&Transport, &[f32]) -> Result<Vec<f32>, E>,
) -> Result<(Vec<EpisodeOutcome>, Vec<Vec<TracePoint>>), E> {
    let n = env.num_envs();
    let names = info_names();
    let column = |name: &str| names.iter().position(|x| x == name).expect("info name");
    let (success, detached, dropped, unhealthy) = (
        column("episode/success"),
        column("episode/failure_cup_detached"),
        column("episode/failure_dropped"),
        column("episode/failure_unhealthy"),
    );
    let (seal, motion) = (
        column("state/peak_seal_utilisation"),
        column("state/object_motion_m"),
    );
    let width = names.len();
    let dt = env.control_interval_s();
    let mut buffers = env.buffers();
    env.set_retire_finished(true);
    env.try_reset(seed, &mut buffers)?;
    let mut traces: Vec<Vec<TracePoint>> =
        traced.iter().map(|&c| vec![env.trace_point(c)]).collect();
    let mut outcomes: Vec<Option<EpisodeOutcome>> = vec![None; n];
    let mut running = vec![
        EpisodeOutcome {
            ending: Ending::TimedOut,
            time_s: 0.0,
            episode_return: 0.0,
            object_motion_m: 0.0,
            peak_seal_utilisation: 0.0,
            angular_jerk_rad_s3: 0.0,
            package: 0,
        };
        n
    ];
    for (copy, o) in running.iter_mut().enumerate() {
        o.package = env.episodes[copy].variant;
    }
    // Each copy's tool angular velocity and acceleration at the last step, and its jerk summed.
    let angular_velocity =
        |env: &Transport, copy: usize| v3(env.states[copy].tool_angular_velocity);
    let mut last_velocity: Vec<DVec3> = (0..n).map(|c| angular_velocity(env, c)).collect();
    let mut last_accel = vec![DVec3::ZERO; n];
    let mut jerk_sum = vec![0.0; n];
    while outcomes.iter().any(Option::is_none) {
        let actions = act(env, &buffers.obs)?;
        env.step(&actions, &mut buffers)?;
        for (trace, &copy) in traces.iter_mut().zip(traced) {
            if outcomes[copy].is_none() {
                trace.push(env.trace_point(copy));
            }
        }
        let info = env.info();
        for copy in 0..n {
            if outcomes[copy].is_some() {
                continue;
            }
            let row = &info[copy * width..(copy + 1) * width];
            let velocity = angular_velocity(env, copy);
            let accel = (velocity - last_velocity[copy]) / dt;
            jerk_sum[copy] += (accel - last_accel[copy]).length() / dt;
            (last_velocity[copy], last_accel[copy]) = (velocity, accel);
            let o = &mut running[copy];
            o.time_s += dt;
            o.episode_return += buffers.rewards[copy] as f64;
            o.object_motion_m += row[motion] as f64;
            o.peak_seal_utilisation = o.peak_seal_utilisation.max(row[seal] as f64);
            if buffers.done(copy) {
                o.angular_jerk_rad_s3 = jerk_sum[copy] / (o.time_s / dt).round().max(1.0);
                o.ending = if row[success] > 0.5 {
                    Ending::Success
                } else if row[detached] > 0.5 {
                    Ending::CupDetached
                } else if row[dropped] > 0.5 {
                    Ending::Dropped
                } else if row[unhealthy] > 0.5 {
                    Ending::Unhealthy
                } else {
                    Ending::TimedOut
                };
                outcomes[copy] = Some(*o);
            }
        }
    }
    env.set_retire_finished(false);
    Ok((outcomes.into_iter().flatten().collect(), traces))
}

/// One row of the evaluation table: a driver's outcomes over the same episodes as the others.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OutcomeSummary {
    /// What drove the tool (`policy`, `scripted x1.25`, ...).
    pub driver: String,
    /// Episodes run.
    pub episodes: usize,
    /// Share of episodes placed successfully (%).
    pub success_pct: f64,
    /// Share ended by a seal failure (%).
    pub cup_detached_pct: f64,
    /// Share ended by the object leaving the package's reach (%).
    pub dropped_pct: f64,
    /// Share stopped by the health check (%).
    pub unhealthy_pct: f64,
    /// Share that ran out of time (%).
    pub timed_out_pct: f64,
    /// Mean time to place over the successful episodes (s; `None` without one).
    pub time_to_place_mean_s: Option<f64>,
    /// 95th percentile of the time to place over the successful episodes (s).
    pub time_to_place_p95_s: Option<f64>,
    /// Mean object motion relative to the tool per episode (m).
    pub object_motion_mean_m: f64,
    /// Largest object motion of an episode (m).
    pub object_motion_max_m: f64,
    /// Mean over episodes of the peak seal utilisation.
    pub peak_seal_mean: f64,
    /// Largest seal utilisation seen.
    pub peak_seal_max: f64,
    /// Mean over episodes of the tool's angular jerk (rad/s^3, [`EpisodeOutcome`]).
    pub angular_jerk_mean_rad_s3: f64,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// Settled packages the episodes started from.
    pub packages: usize,
    /// 10th percentile, over those packages, of each package's share of successful episodes (%):
    /// how the driver does on the hardest tenth of the packages (nearest rank).
    pub package_success_p10_pct: f64,
}

impl OutcomeSummary {
    /// Summarises `outcomes` under the name `driver`.
    pub fn of(driver: &str, outcomes: &[EpisodeOutcome]) -> Self {
        let n = outcomes.len().max(1) as f64;
        let pct = |e: Ending| 100.0 * outcomes.iter().filter(|o| o.ending == e).count() as f64 / n;
        let mut times: Vec<f64> = outcomes
            .iter()
            .filter(|o| o.ending == Ending::Success)
            .map(|o| o.time_s)
            .collect();
        times.sort_by(f64::total_cmp);
        let mean = |xs: &mut dyn Iterator<Item = f64>| xs.sum::<f64>() / n;
        let max = |xs: &mut dyn Iterator<Item = f64>| xs.fold(0.0, f64::max);
        // (episodes, successes) per settled package, in package order.
        let mut tally = std::collections::BTreeMap::<usize, (usize, usize)>::new();
        for o in outcomes {
            let t = tally.entry(o.package).or_default();
            t.0 += 1;
            t.1 += usize::from(o.ending == Ending::Success);
        }
        let mut per_package: Vec<f64> = tally
            .values()
            .map(|&(n, ok)| 100.0 * ok as f64 / n as f64)
            .collect();
        per_package.sort_by(f64::total_cmp);
        OutcomeSummary {
            driver: driver.to_string(),
            episodes: outcomes.len(),
            success_pct: pct(Ending::Success),
            cup_detached_pct: pct(Ending::CupDetached),
            dropped_pct: pct(Ending::Dropped),
            unhealthy_pct: pct(Ending::Unhealthy),
            timed_out_pct: pct(Ending::TimedOut),
            time_to_place_mean_s: (!times.is_empty())
                .then(|| times.iter().sum::<f64>() / times.len() as f64),
            time_to_place_p95_s: percentile(&times, 0.95),
            object_motion_mean_m: mean(&mut outcomes.iter().map(|o| o.object_motion_m)),
            object_motion_max_m: max(&mut outcomes.iter().map(|o| o.object_motion_m)),
            peak_seal_mean: mean(&mut outcomes.iter().map(|o| o.peak_seal_utilisation)),
            peak_seal_max: max(&mut outcomes.iter().map(|o| o.peak_seal_utilisation)),
            angular_jerk_mean_rad_s3: mean(&mut outcomes.iter().map(|o| o.angular_jerk_rad_s3)),
            mean_return: mean(&mut outcomes.iter().map(|o| o.episode_return)),
            packages: per_package.len(),
            package_success_p10_pct: percentile(&per_package, 0.10).unwrap_or(0.0),
        }
    }

    /// The rows as a plain-text table.
    pub fn table(rows: &[Self]) -> String {
        let opt = |x: Option<f64>| x.map_or_else(|| "-".to_string(), |t| format!("{t:.2}"));
        let mut s = format!(
            "{:<16} {:>5} {:>7} {:>7} {:>7} {:>7} {:>7} {:>9} {:>8} {:>9} {:>9} {:>6} {:>6} {:>9} {:>8} {:>5} {:>8}\n",
            "driver", "eps", "succ%", "cup%", "drop%", "unh%", "tout%", "place s", "p95 s",
            "obj mean", "obj max", "seal", "seal^", "ang jerk", "return", "pkgs", "pkg p10%"
        );
        for r in rows {
            s += &format!(
                "{:<16} {:>5} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>9} {:>8} {:>8.3}m {:>8.3}m \
                 {:>6.2} {:>6.2} {:>9.1} {:>8.2} {:>5} {:>8.1}\n",
                r.driver,
                r.episodes,
                r.success_pct,
                r.cup_detached_pct,
                r.dropped_pct,
                r.unhealthy_pct,
                r.timed_out_pct,
                opt(r.time_to_place_mean_s),
                opt(r.time_to_place_p95_s),
                r.object_motion_mean_m,
                r.object_motion_max_m,
                r.peak_seal_mean,
                r.peak_seal_max,
                r.angular_jerk_mean_rad_s3,
                r.mean_return,
                r.packages,
                r.package_success_p10_pct
            );
        }
        s
    }
}

/// An evaluation's `episodes.csv`: one row per driver and episode, with what the episode drew
/// (settled package, path, target tilt, object mass, supply vacuum, every material parameter of
/// the package) beside how it ended, so that failures can be traced to the packages and
/// conditions behind them. `grasp_vacuum_ratio` is the randomised package's lowest cup vacuum
/// over the supply after settling ([`Transport::grasp_vacuum_ratios`], what the grasp check
/// compares; for a replaced package its own, not the stand-in's; empty when the settled
/// packages were restored from a saved state).
#[derive(Debug, Clone)]
pub struct EpisodeTable {
    csv: String,
}

impl Default for EpisodeTable {
    fn default() -> Self {
        let params = PARAM_NAMES.join(",");
        Self {
            csv: format!(
                "driver,episode,package,path,target_tilt_deg,object_mass_kg,vacuum_kpa,{params},\
                 grasp_vacuum_ratio,ending,time_s,object_motion_m,peak_seal_utilisation,\
                 angular_jerk_rad_s3\n"
            ),
        }
    }
}

impl EpisodeTable {
    /// Appends `driver`'s `outcomes` as [`run_traced_episodes`] returned them on `env` (episode
    /// `i` ran in copy `i`; call before `env` is reset again, which draws new episodes).
    pub fn add(&mut self, driver: &str, env: &Transport, outcomes: &[EpisodeOutcome]) {
        let scene_vacuum = env.model.config.seal.vacuum_kpa;
        // Quoted as CSV quotes: a driver's name can hold a folder's (`optimized <folder>`).
        let driver = format!("\"{}\"", driver.replace('"', "\"\""));
        for (episode, o) in outcomes.iter().enumerate() {
            let drawn = env.conditions(episode);
            let spec = env.sim.spec(episode);
            let params = spec
                .params
                .entries()
                .map(|(_, value, ..)| value.to_string());
            self.csv += &format!(
                "{driver},{episode},{},{},{:.3},{},{},{},{},{},{:.4},{:.6},{:.6},{:.3}\n",
                o.package,
                drawn.path_id,
                drawn.target_tilt_rad.to_degrees(),
                drawn.object_mass_kg,
                spec.vacuum_kpa.unwrap_or(scene_vacuum),
                params.join(","),
                env.grasp_vacuum_ratios()
                    .get(o.package)
                    .map_or(String::new(), |r| format!("{r:.4}")),
                o.ending.name(),
                o.time_s,
                o.object_motion_m,
                o.peak_seal_utilisation,
                o.angular_jerk_rad_s3,
            );
        }
    }

    /// The table as CSV text (header first).
    pub fn csv(&self) -> &str {
        &self.csv
    }
}

/// The `q` quantile of sorted `xs` (nearest rank), `None` when empty.
fn percentile(xs: &[f64], q: f64) -> Option<f64> {
    if xs.is_empty() {
        return None;
    }
    let rank = ((q * xs.len() as f64).ceil() as usize).clamp(1, xs.len());
    Some(xs[rank - 1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{env, test_table};

    fn outcome(ending: Ending, time_s: f64, motion: f64) -> EpisodeOutcome {
        EpisodeOutcome {
            ending,
            time_s,
            episode_return: 1.0,
            object_motion_m: motion,
            peak_seal_utilisation: motion,
            angular_jerk_rad_s3: 0.0,
            package: 0,
        }
    }

    #[test]
    fn package_p10_is_the_success_of_the_hardest_tenth_of_the_packages() {
        // Ten packages of two episodes: nine always placed, package 4 placed once.
        let outcomes: Vec<EpisodeOutcome> = (0..20)
            .map(|k| EpisodeOutcome {
                package: k % 10,
                ..outcome(
                    if k == 14 {
                        Ending::CupDetached
                    } else {
                        Ending::Success
                    },
                    2.0,
                    0.1,
                )
            })
            .collect();
        let s = OutcomeSummary::of("x", &outcomes);
        assert_eq!((s.packages, s.success_pct), (10, 95.0));
        assert_eq!(s.package_success_p10_pct, 50.0);
        // With package 4 placed every time, the hardest tenth succeeds fully.
        let mut all = outcomes.clone();
        all[14].ending = Ending::Success;
        assert_eq!(OutcomeSummary::of("y", &all).package_success_p10_pct, 100.0);
    }

    #[test]
    fn summary_counts_endings_and_times_only_successes() {
        let outcomes = [
            outcome(Ending::Success, 4.0, 0.1),
            outcome(Ending::Success, 6.0, 0.3),
            outcome(Ending::CupDetached, 1.0, 0.2),
            outcome(Ending::TimedOut, 12.0, 0.2),
        ];
        let s = OutcomeSummary::of("x", &outcomes);
        assert_eq!(
            (s.success_pct, s.cup_detached_pct, s.timed_out_pct),
            (50.0, 25.0, 25.0)
        );
        assert_eq!(s.time_to_place_mean_s, Some(5.0));
        assert_eq!(s.time_to_place_p95_s, Some(6.0));
        assert!((s.object_motion_mean_m - 0.2).abs() < 1e-12);
        assert_eq!(s.object_motion_max_m, 0.3);
        let none = OutcomeSummary::of("y", &outcomes[2..]);
        assert_eq!(none.time_to_place_mean_s, None);
        assert!(OutcomeSummary::table(&[s, none]).lines().count() == 3);
    }

    #[test]
    fn run_episodes_reports_every_copy_once_with_its_ending_and_time() {
        // A tool held still for a 1 s time limit: every copy times out after 20 control steps, with the
        // seal loaded (the package hangs from the cups) and the object nearly still.
        let mut t = env(
            &test_table().replace("time_limit_s = 12.0", "time_limit_s = 1.0"),
            3,
        );
        let (outcomes, traces) = run_traced_episodes::<EnvError>(&mut t, 5, &[1], |t, _| {
            Ok(vec![0.0; t.num_envs() * t.spec().action.dim()])
        })
        .unwrap();
        assert_eq!(outcomes.len(), 3);
        for (copy, o) in outcomes.iter().enumerate() {
            assert_eq!(o.package, t.conditions(copy).variant);
        }
        // The traced copy: its start and each of its 20 steps; the tool held level and still.
        let trace = &traces[0];
        assert_eq!(trace.len(), 21);
        assert!((trace[20].time_s - 1.0).abs() < 1e-6);
        for p in trace {
            assert_eq!(p.path_speed_m_s, 0.0);
            assert!(p.tool_tilt_deg < 1.0 && p.tool_speed_m_s < 0.05, "{p:?}");
        }
        assert!(trace.iter().any(|p| p.peak_seal_utilisation > 0.0));
        for o in &outcomes {
            assert_eq!(o.ending, Ending::TimedOut, "{o:?}");
            assert!((o.time_s - 1.0).abs() < 1e-6, "{o:?}");
            assert!(
                o.peak_seal_utilisation > 0.0 && o.peak_seal_utilisation < 0.5,
                "{o:?}"
            );
            // The object sways a few centimetres (path length) as the package settles under the cups.
            assert!(o.object_motion_m < 0.1, "{o:?}");
        }
        let summary = OutcomeSummary::of("still", &outcomes);
        assert_eq!(summary.timed_out_pct, 100.0);
        assert_eq!(summary.time_to_place_mean_s, None);
        // A tool whose tilt offset flips every step has far more angular jerk than one held still.
        let mut step = 0;
        let wobbling = run_episodes::<EnvError>(&mut t, 5, |t, _| {
            step += 1;
            let tilt = if step % 2 == 0 { 0.3 } else { -0.3 };
            Ok([0.0, tilt, 0.0].repeat(t.num_envs()))
        })
        .unwrap();
        for (still, wobbling) in outcomes.iter().zip(&wobbling) {
            assert!(
                wobbling.angular_jerk_rad_s3 > 10.0 * still.angular_jerk_rad_s3
                    && wobbling.angular_jerk_rad_s3 > 10.0,
                "{still:?} {wobbling:?}"
            );
        }

        // episodes.csv: a header, then each copy's draw and ending in its own row.
        let mut table = EpisodeTable::default();
        table.add("still", &t, &outcomes);
        let rows: Vec<Vec<&str>> = table
            .csv()
            .lines()
            .map(|l| l.split(',').collect())
            .collect();
        assert_eq!(rows.len(), 1 + outcomes.len());
        let column = |name: &str| rows[0].iter().position(|&c| c == name).unwrap();
        for (copy, row) in rows[1..].iter().enumerate() {
            assert_eq!(row.len(), rows[0].len(), "{row:?}");
            let drawn = t.conditions(copy);
            assert_eq!(row[column("driver")], "\"still\"");
            assert_eq!(row[column("episode")], copy.to_string());
            assert_eq!(row[column("package")], drawn.variant.to_string());
            assert_eq!(row[column("path")], drawn.path_id);
            let mass: f32 = row[column("object_mass_kg")].parse().unwrap();
            assert_eq!(mass, drawn.object_mass_kg);
            let k_spr_e: f32 = row[column("k_spr_e")].parse().unwrap();
            assert_eq!(k_spr_e, t.simulator().spec(copy).params.k_spr_e);
            let grasp: f64 = row[column("grasp_vacuum_ratio")].parse().unwrap();
            let settled = t.grasp_vacuum_ratios()[drawn.variant];
            assert!(
                (grasp - settled).abs() < 1e-4 && grasp < 0.981,
                "{grasp} {settled}"
            );
            assert_eq!(row[column("ending")], "timed_out");
        }
        // A name with quotes and commas (an optimised command's folder) stays one CSV field.
        let mut quoted = EpisodeTable::default();
        quoted.add("optimized a \"b\", c", &t, &outcomes[..1]);
        let row = quoted.csv().lines().nth(1).unwrap();
        assert!(row.starts_with("\"optimized a \"\"b\"\", c\",0,"), "{row}");
    }
}
