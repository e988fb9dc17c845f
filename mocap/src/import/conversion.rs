//! The conversion of a parsed take into a trajectory, its manifest entry and its retention
//! report.

use glam::{DQuat, DVec3};
use nalgebra::Vector3;

use crate::clean::{self, Butterworth, CleanError, Series};
use crate::dataset::{ManifestEntry, MarkerFrames, Meta, ObjectTrack, ToolTrack, Trajectory};
use crate::derivative::{angular_velocity, gradient};
use crate::motive::{MarkerKind, MotiveTake};
use crate::robot::{self, covered_frames, RigidTransform, RobotTrajectory};

use super::rigid_body::clean_rigid_body;
use super::{ImportConfig, ImportError, MarkerSource, RetentionReport, RobotFit};

/// One converted take.
#[derive(Debug, Clone)]
pub struct ImportedTake {
    /// The trajectory, ready for [`Trajectory::save`].
    pub trajectory: Trajectory,
    /// Its manifest entry.
    pub entry: ManifestEntry,
    /// What was kept.
    pub report: RetentionReport,
    /// False if the config excludes this take from the dataset.
    pub include: bool,
}

/// Cleans and converts a parsed take into trajectory `id`.
pub fn convert(
    take: &MotiveTake,
    id: &str,
    config: &ImportConfig,
) -> Result<ImportedTake, ImportError> {
    convert_with_robot(take, id, config, None)
}

/// Cleans and converts a parsed take into trajectory `id`; with `robot`, the tool track is the
/// robot's command carried into the mocap frame by the `[robot]` transform (given, or estimated
/// from the Motive tool rigid body), on the frames the robot file covers.
pub fn convert_with_robot(
    take: &MotiveTake,
    id: &str,
    config: &ImportConfig,
    robot: Option<&RobotTrajectory>,
) -> Result<ImportedTake, ImportError> {
    let take_err = |message: String| ImportError::Take {
        path: take.path.clone(),
        message,
    };
    let clean_err = |e: CleanError| take_err(e.to_string());
    let conversion = &config.conversion;
    let cleaning = &config.cleaning;
    let rate = take.header.export_frame_rate_hz;
    let n = take.len();
    let settings = config.take(id).map_err(take_err)?;

    let tool_index = find_body(take, &conversion.tool_body, 0, "tool").map_err(take_err)?;
    let object_index = find_body(take, &conversion.object_body, 1, "object").map_err(take_err)?;
    if tool_index == object_index {
        return Err(take_err(format!(
            "tool and object are the same rigid body '{}'; expected two different bodies",
            take.rigid_bodies[tool_index].name
        )));
    }
    let max_gap = (conversion.max_rigid_body_gap_s * rate).round() as usize;
    let rigid_filter = (cleaning.rigid_body_cutoff_hz > 0.0)
        .then(|| Butterworth::low_pass(cleaning.filter_order, cleaning.rigid_body_cutoff_hz, rate))
        .transpose()
        .map_err(clean_err)?;
    for &index in &[tool_index, object_index] {
        let body = &take.rigid_bodies[index];
        if let Some(k) = body
            .rotation
            .iter()
            .position(|q| q.is_some_and(|q| DQuat::from_array(q).length_squared() < 0.25))
        {
            return Err(take_err(format!(
                "rigid body '{}' has a rotation quaternion of near-zero length at frame {k} (line {}); expected a unit quaternion",
                body.name,
                k + 8
            )));
        }
    }
    let tool = clean_rigid_body(
        take,
        tool_index,
        max_gap,
        cleaning.velocity_window,
        rigid_filter.as_ref(),
    );
    let object = clean_rigid_body(
        take,
        object_index,
        max_gap,
        cleaning.velocity_window,
        rigid_filter.as_ref(),
    );

    // The usable frames: the longest run where both bodies have a pose.
    let both: Vec<Option<()>> = (0..n)
        .map(|k| {
            (tool.position[k].is_some()
                && tool.rotation[k].is_some()
                && object.position[k].is_some())
            .then_some(())
        })
        .collect();
    let (mut start, mut end) = clean::runs(&both)
        .into_iter()
        .max_by_key(|&(s, e)| (e - s, std::cmp::Reverse(s)))
        .ok_or_else(|| {
            take_err("the tool and object rigid bodies are never both tracked".into())
        })?;

    if let Some(robot) = robot {
        let robot_err = |what: &str| {
            take_err(format!(
                "robot file {} (times {} to {} s) {what}; expected the robot times on the take's clock (its frames {} to {} s)",
                robot.path.display(),
                robot.t[0],
                robot.t[robot.t.len() - 1],
                take.time[0],
                take.time[n - 1]
            ))
        };
        let (first, last) = covered_frames(robot, &take.time)
            .ok_or_else(|| robot_err("covers none of the take's frames"))?;
        if first >= end || last <= start {
            return Err(robot_err(
                "covers none of the frames where both rigid bodies are tracked",
            ));
        }
        start = start.max(first);
        end = end.min(last);
    }

    // Motive also exports the labelled markers of a rigid body as `Marker` columns named
    // `<body>:<marker>`; they belong to the tool or object, not to the package.
    let body_prefixes: Vec<String> = take
        .rigid_bodies
        .iter()
        .map(|b| format!("{}:", b.name))
        .collect();
    let fragments: Vec<Series> = take
        .markers
        .iter()
        .filter(|m| {
            !body_prefixes
                .iter()
                .any(|prefix| m.name.starts_with(prefix.as_str()))
        })
        .filter(|m| match conversion.markers {
            MarkerSource::Unlabeled => m.kind == MarkerKind::Unlabeled,
            MarkerSource::Labeled => m.kind == MarkerKind::Labeled,
            MarkerSource::All => m.kind != MarkerKind::RigidBodyMarker,
        })
        .map(|m| m.position.clone())
        .collect();
    if fragments.is_empty() {
        let wanted = match conversion.markers {
            MarkerSource::Unlabeled => "unlabeled",
            MarkerSource::Labeled => "labeled",
            MarkerSource::All => "labeled or unlabeled",
        };
        return Err(take_err(format!(
            "no {wanted} marker columns (conversion.markers); expected the package markers"
        )));
    }
    let cleaned = clean::clean_markers(&fragments, rate, cleaning).map_err(clean_err)?;

    let t_all = &take.time;
    let tool_position: Vec<[f64; 3]> = (start..end).map(|k| tool.position[k].unwrap()).collect();
    if conversion.trim_to_motion {
        let velocity = gradient(&tool_position, &t_all[start..end]);
        let moving: Vec<usize> = (0..velocity.len())
            .filter(|&k| {
                DVec3::from_array(velocity[k]).length() > conversion.motion_speed_threshold_m_s
            })
            .collect();
        if let (Some(&first), Some(&last)) = (moving.first(), moving.last()) {
            let margin = (conversion.motion_margin_s * rate).round() as usize;
            let new_start = start + first.saturating_sub(margin);
            end = (start + last + 1 + margin).min(end);
            start = new_start;
        }
    }
    if end - start < 2 {
        return Err(take_err(format!(
            "only {} usable frame(s); expected at least 2",
            end - start
        )));
    }

    let t: Vec<f64> = t_all[start..end].iter().map(|x| x - t_all[start]).collect();
    let tool_position: Vec<[f64; 3]> = (start..end).map(|k| tool.position[k].unwrap()).collect();
    let tool_rotation: Vec<[f64; 4]> = (start..end).map(|k| tool.rotation[k].unwrap()).collect();
    let object_position: Vec<[f64; 3]> =
        (start..end).map(|k| object.position[k].unwrap()).collect();
    let object_velocity = gradient(&object_position, &t);
    let (tool_track, robot_fit) = match robot {
        None => {
            let tool_velocity = gradient(&tool_position, &t);
            let angular_velocity = angular_velocity(&tool_rotation, &t);
            let track = ToolTrack {
                acceleration: gradient(&tool_velocity, &t),
                angular_acceleration: gradient(&angular_velocity, &t),
                t: t.clone(),
                position: tool_position,
                orientation: tool_rotation,
                velocity: tool_velocity,
                angular_velocity,
            };
            (track, None)
        }
        Some(robot) => {
            let times = &t_all[start..end];
            let commanded = robot::positions_at(robot, times);
            let body: Vec<Vector3<f64>> = tool_position.iter().map(|&p| p.into()).collect();
            let (transform, estimated) = match config.robot.given() {
                Some(given) => (given, false),
                None => {
                    let fitted = RigidTransform::fit(&commanded, &body).ok_or_else(|| {
                        take_err(format!(
                            "robot file {}: the tool path over the imported frames is (nearly) a straight line, so the robot-to-mocap rotation cannot be estimated; expected [robot] rotation_xyzw and translation_m in the config",
                            robot.path.display()
                        ))
                    })?;
                    (fitted, true)
                }
            };
            let rms_m = transform.rms_error(&commanded, &body);
            if rms_m > config.robot.max_fit_rms_m {
                return Err(take_err(format!(
                    "robot file {}: the {} transform puts the commanded tool point {:.1} mm (RMS) from the Motive tool rigid body, more than robot.max_fit_rms_m = {} m; expected the robot file of this take, with the tool point at the body's pivot",
                    robot.path.display(),
                    if estimated { "best-fitting" } else { "given" },
                    1e3 * rms_m,
                    config.robot.max_fit_rms_m
                )));
            }
            let fit = RobotFit {
                path: robot.path.clone(),
                estimated,
                rms_m,
                rotation_xyzw: {
                    let q = transform.rotation;
                    [q.i, q.j, q.k, q.w]
                },
                translation_m: transform.translation.into(),
            };
            (robot::tool_track(robot, times, &transform), Some(fit))
        }
    };
    let object_track = ObjectTrack {
        acceleration: gradient(&object_velocity, &t),
        t: t.clone(),
        position: object_position,
        velocity: object_velocity,
    };
    let frames: Vec<Vec<[f64; 3]>> = (start..end).map(|k| cleaned.frame(k)).collect();
    let initial_markers = frames[0].clone();
    if initial_markers.len() < 3 {
        return Err(take_err(format!(
            "only {} package marker(s) in the first kept frame (t = {} s); expected at least 3 to place the package",
            initial_markers.len(),
            t_all[start]
        )));
    }
    // Markers on another scale than the package (a take exported in metres but labelled
    // millimetres, or the reverse) would convert without a word into a package 1000x off.
    let spread = initial_markers
        .iter()
        .flat_map(|a| {
            initial_markers
                .iter()
                .map(move |b| DVec3::from_array(*a).distance(DVec3::from_array(*b)))
        })
        .fold(0.0, f64::max);
    let diagonal = config.package.size_m[0].hypot(config.package.size_m[1]);
    if !(diagonal / 10.0..=diagonal * 3.0).contains(&spread) {
        return Err(take_err(format!(
            "the package markers of the first kept frame span {spread:.4} m, the package's diagonal \
             (package.size_m) is {diagonal:.3} m; expected the same scale (check the take's 'Length Units')"
        )));
    }
    let counts: Vec<usize> = frames.iter().map(Vec::len).collect();
    let markers_per_frame = (*counts.iter().min().unwrap(), *counts.iter().max().unwrap());

    let object_total_mass_kg = settings.object_total_mass_kg;
    let cup = DQuat::from_array(tool_track.orientation[0])
        .mul_vec3(DVec3::from_array(conversion.tool_to_cup_m))
        .to_array();
    let meta = Meta {
        id: id.to_string(),
        package_size_m: config.package.size_m,
        package_mass_kg: config.package.mass_kg,
        object_diameter_m: config.package.object_diameter_m,
        object_body_mass_kg: config.package.object_body_mass_kg,
        object_total_mass_kg,
        total_mass_kg: config.package.mass_kg + object_total_mass_kg,
        initial_suction_cup_position_m: std::array::from_fn(|i| tool_track.position[0][i] + cup[i]),
        initial_marker_positions_m: initial_markers,
        marker_inset_m: config.package.marker_inset_m,
        initial_lower_marker_positions_m: config.package.lower_marker_positions_m.clone(),
    };
    let entry = ManifestEntry {
        id: id.to_string(),
        split: settings.split,
        mass: settings.mass,
        mass_lb: settings.mass_lb,
        velocity: settings.velocity,
        orientation: settings.orientation,
        frames: t.len(),
        duration_s: *t.last().unwrap(),
        object_total_mass_kg,
        markers_per_frame_min: Some(markers_per_frame.0),
        markers_per_frame_max: Some(markers_per_frame.1),
        marker_rows: Some(counts.iter().sum()),
        failure: settings.failure,
    };
    let include = !settings.exclude;
    let report = RetentionReport {
        id: id.to_string(),
        sample_rate_hz: rate,
        frames_total: n,
        frames_kept: t.len(),
        markers: cleaned.retention(start, end),
        input_ids: cleaned.input_ids,
        reidentified_ids: cleaned.reidentified_ids,
        reid_distance_m: median_and_max(&cleaned.reid_distances_m),
        refused_across_sheets: cleaned.refused_across_sheets,
        tracks_kept: cleaned
            .tracks
            .iter()
            .filter(|tr| tr[start..end].iter().any(Option::is_some))
            .count(),
        short_tracks_dropped: cleaned.short_tracks_dropped,
        markers_per_frame,
        unfiltered_samples: cleaned.unfiltered_samples,
        robot: robot_fit,
        written: include,
        failure: settings.failure,
    };
    let trajectory = Trajectory {
        id: id.to_string(),
        meta,
        tool: tool_track,
        object: object_track,
        markers: MarkerFrames::from_labelled_frames(
            t,
            (start..end).map(|k| cleaned.labelled_frame(k)).collect(),
        ),
    };
    Ok(ImportedTake {
        trajectory,
        entry,
        report,
        include,
    })
}

/// Median and maximum of `values` (zeros when empty).
fn median_and_max(values: &[f64]) -> (f64, f64) {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => (0.0, 0.0),
        n => (sorted[n / 2], sorted[n - 1]),
    }
}

/// Index of the rigid body called `name`, or the `default_index`-th one if `name` is empty.
fn find_body(
    take: &MotiveTake,
    name: &str,
    default_index: usize,
    role: &str,
) -> Result<usize, String> {
    let names: Vec<&str> = take.rigid_bodies.iter().map(|b| b.name.as_str()).collect();
    if name.is_empty() {
        if default_index < names.len() {
            Ok(default_index)
        } else {
            Err(format!(
                "the {role} is rigid body number {} but the take has {} ({names:?}); expected a tool and an object rigid body",
                default_index + 1,
                names.len()
            ))
        }
    } else {
        names
            .iter()
            .position(|n| *n == name)
            .ok_or_else(|| format!("no rigid body named '{name}' for the {role} (conversion.{role}_body); the take has {names:?}"))
    }
}
