//! Tests of the import: whole takes (the shipped fixtures and synthetic ones) through the
//! config, the conversion and the report.

use std::path::{Path, PathBuf};

use super::*;
use crate::dataset::Split;
use crate::motive;
use crate::robot::read_robot;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

const DEFAULT_TAKE: &str = "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2268\n";

/// The built-in settings with a `[default_take]` (train, 0.2268 kg), so any take imports.
fn with_default_take() -> ImportConfig {
    ImportConfig {
        default_take: Some(TakeConfig {
            split: Some(Split::Train),
            object_total_mass_kg: Some(0.2268),
            ..TakeConfig::default()
        }),
        ..ImportConfig::default()
    }
}

#[test]
fn takes_need_their_split_and_mass_from_the_config() {
    let take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
    let mut config = ImportConfig {
        conversion: ConversionConfig {
            markers: MarkerSource::Labeled,
            ..ConversionConfig::default()
        },
        ..ImportConfig::default()
    };
    let msg = convert(&take, "lab", &config).unwrap_err().to_string();
    assert!(
        msg.contains(
            "lab.csv: take \"lab\" is not listed in [takes] and there is no [default_take]"
        ),
        "{msg}"
    );
    config.takes.insert(
        "lab".into(),
        TakeConfig {
            object_total_mass_kg: Some(0.3),
            ..TakeConfig::default()
        },
    );
    let msg = config.validate().unwrap_err();
    assert!(msg.contains("takes.\"lab\".split is missing"), "{msg}");
    // [default_take] completes what the take leaves out; the take's own values win.
    config.default_take = Some(TakeConfig {
        split: Some(Split::Test),
        object_total_mass_kg: Some(0.5),
        ..TakeConfig::default()
    });
    config.validate().unwrap();
    let imported = convert(&take, "lab", &config).unwrap();
    assert_eq!(imported.entry.split, Split::Test);
    assert_eq!(imported.entry.object_total_mass_kg, 0.3);
    assert_eq!(config.take("other").unwrap().object_total_mass_kg, 0.5);
    // An excluded take needs no split.
    config.default_take = None;
    config.takes.get_mut("lab").unwrap().exclude = Some(true);
    assert!(config.take("lab").unwrap().exclude);
}

fn shipped_config() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/import/motive.toml")
}

/// Non-empty marker triples in the data rows, counted straight from the file's text.
fn raw_marker_samples(path: &Path) -> usize {
    let take = motive::read_take(path).unwrap();
    let text = {
        use std::io::Read;
        let mut s = String::new();
        flate2::read::GzDecoder::new(std::fs::File::open(path).unwrap())
            .read_to_string(&mut s)
            .unwrap();
        s
    };
    let first_marker_column = 2 + 8 * take.rigid_bodies.len();
    text.lines()
        .skip(7)
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            cells[first_marker_column..]
                .chunks(3)
                .filter(|c| !c[0].is_empty())
                .count()
        })
        .sum()
}

#[test]
fn the_shipped_config_spells_out_the_defaults() {
    let config = ImportConfig::load(&shipped_config()).unwrap();
    let defaults = with_default_take();
    assert_eq!(config.cleaning, defaults.cleaning);
    assert_eq!(config.conversion, defaults.conversion);
    assert_eq!(config.package, defaults.package);
    assert_eq!(config.robot, defaults.robot);
    assert_eq!(config.takes.len(), 27);
    assert_eq!(
        config
            .takes
            .values()
            .filter(|t| t.split == Some(Split::Test) && t.exclude != Some(true))
            .count(),
        4
    );
}

#[test]
fn the_excerpt_imports_with_known_values() {
    let path = fixture("a30_m0.5_high_excerpt.csv.gz");
    let mut config = ImportConfig::load(&shipped_config()).unwrap();
    config.takes.insert(
        "a30_m0.5_high_excerpt".into(),
        config.takes["a30_m0.5_high"].clone(),
    );
    let imported = import_take(&path, &config).unwrap();
    let (trajectory, report) = (&imported.trajectory, &imported.report);
    assert_eq!(trajectory.id, "a30_m0.5_high_excerpt");
    assert_eq!((report.frames_total, report.frames_kept), (250, 250));
    assert_eq!(report.sample_rate_hz, 250.0);
    assert_eq!(trajectory.tool.t.len(), 250);
    assert!((trajectory.tool.t[249] - 0.996).abs() < 1e-9);
    // Frame 0, `Unlabeled 1000` = (-0.532215, 0.016989, 0.256647) m in the file; the low-pass
    // moves it by a fraction of the 0.3 mm noise.
    let known = [-0.532215, 0.016989, 0.256647];
    let nearest = trajectory
        .meta
        .initial_marker_positions_m
        .iter()
        .map(|p| dist(*p, known))
        .fold(f64::MAX, f64::min);
    assert!(nearest < 1e-3, "nearest initial marker is {nearest} m away");
    // Tool pivot at frame 0 = (-0.399960, 0.033121, 0.150052); the cup 5 mm below it.
    let tool0 = trajectory.tool.position[0];
    assert!(
        dist(tool0, [-0.399960, 0.033121, 0.150052]) < 5e-4,
        "{tool0:?}"
    );
    let cup = trajectory.meta.initial_suction_cup_position_m;
    assert!(
        dist(cup, [tool0[0], tool0[1] - 0.005, tool0[2]]) < 1e-4,
        "{cup:?}"
    );
    assert_eq!(trajectory.meta.object_total_mass_kg, 0.2268);
    // Retention: every raw sample is either kept or dropped as spurious; nearly all are kept.
    let m = report.markers;
    assert_eq!(m.raw_samples, raw_marker_samples(&path));
    assert_eq!(m.observed_kept + m.spurious_samples, m.raw_samples);
    assert!(m.kept_percent() > 97.0, "{report}");
    // 20 top markers are visible from the start; re-identification joins their ids again.
    assert!(report.reidentified_ids > 0);
    assert!(report.tracks_kept < report.input_ids);
    assert!((20..=45).contains(&report.tracks_kept), "{report}");
    assert!(report.markers_per_frame.0 >= 15, "{report}");
    assert_eq!(imported.entry.frames, 250);
    assert!(imported.include);
}

#[test]
fn millimetre_and_metre_exports_give_the_same_trajectory() {
    let config = with_default_take();
    let m = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
        .unwrap()
        .trajectory;
    let mm = import_take(&fixture("a30_m0.5_high_excerpt_mm.csv.gz"), &config)
        .unwrap()
        .trajectory;
    for k in [0, 100, 249] {
        assert!(dist(m.tool.position[k], mm.tool.position[k]) < 1e-9);
        assert!(dist(m.object.position[k], mm.object.position[k]) < 1e-9);
        assert_eq!(m.markers.frame(k).len(), mm.markers.frame(k).len());
        for (a, b) in m.markers.frame(k).iter().zip(mm.markers.frame(k)) {
            assert!(dist(*a, *b) < 1e-9);
        }
    }
}

#[test]
fn markers_on_another_scale_than_the_package_are_refused() {
    // The same take against a package a tenth of its size: as if its units were mislabelled.
    let mut config = with_default_take();
    config.package.size_m = [0.0254, 0.03048];
    let err = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("a30_m0.5_high_excerpt.csv.gz"), "{err}");
    assert!(err.contains("expected the same scale"), "{err}");
    assert!(err.contains("'Length Units'"), "{err}");
}

#[test]
fn trimming_to_motion_drops_the_settle_phase() {
    // packages-v1: the tool is still for the first 0.3 s (75 frames), then lifts.
    let mut config = with_default_take();
    config.conversion.trim_to_motion = true;
    let imported = import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config).unwrap();
    let kept = imported.report.frames_kept;
    assert!((100..=175).contains(&kept), "kept {kept} frames");
    assert_eq!(imported.trajectory.tool.t[0], 0.0);
}

#[test]
fn config_errors_name_file_key_and_range() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("import.toml");
    std::fs::write(&path, "[cleaning]\nfilter_order = 4\nbogus = 1\n").unwrap();
    let msg = ImportConfig::load(&path).unwrap_err().to_string();
    assert!(
        msg.contains("import.toml: line 3") && msg.contains("bogus"),
        "{msg}"
    );
    std::fs::write(&path, "[cleaning]\nmarker_cutoff_hz = -2.0\n").unwrap();
    let msg = ImportConfig::load(&path).unwrap_err().to_string();
    assert!(
        msg.contains("cleaning.marker_cutoff_hz = -2: expected a number >= 0"),
        "{msg}"
    );
    std::fs::write(&path, "[package]\nmarker_inset_m = [0.02, 0.2]\n").unwrap();
    let msg = ImportConfig::load(&path).unwrap_err().to_string();
    assert!(
        msg.contains("package.marker_inset_m = [0.02, 0.2]: expected 2 numbers in [0, 0.127) m"),
        "{msg}"
    );
    // What importing the excerpt says under a config whose text is `text` and the default take.
    let import_error = |text: &str| {
        std::fs::write(&path, format!("{text}{DEFAULT_TAKE}")).unwrap();
        let config = ImportConfig::load(&path).unwrap();
        import_take(&fixture("a30_m0.5_high_excerpt.csv.gz"), &config)
            .unwrap_err()
            .to_string()
    };
    let msg = import_error("[conversion]\ntool_body = \"Gripper\"\n");
    assert!(
        msg.contains("no rigid body named 'Gripper'") && msg.contains("[\"Tool\", \"Object\"]"),
        "{msg}"
    );
    // A cut-off above the Nyquist frequency of the take is caught when the take's rate is known.
    let msg = import_error("[cleaning]\nmarker_cutoff_hz = 200.0\n");
    assert!(
        msg.contains("a30_m0.5_high_excerpt.csv.gz") && msg.contains("(0, 125) Hz"),
        "{msg}"
    );
}

/// A synthetic millimetre take: tool and object at rest, three labelled package markers and
/// one labelled tool marker, 60 frames at 100 Hz.
fn labelled_take() -> String {
    let mut text = String::from(
        "Format Version,1.23,Take Name,lab,Capture Frame Rate,100,Export Frame Rate,100,Rotation Type,Quaternion,Length Units,Millimeters\n\n",
    );
    let bodies = ["Tool", "Object"];
    let markers = ["Pkg:A", "Pkg:B", "Pkg:C", "Tool:Marker1"];
    let mut rows = [
        vec![",Type".to_string()],
        vec![",Name".into()],
        vec![",ID".into()],
        vec![",".into()],
        vec!["Frame,Time (Seconds)".into()],
    ];
    for (i, body) in bodies.iter().enumerate() {
        for (property, axis) in [
            ("Rotation", "X"),
            ("Rotation", "Y"),
            ("Rotation", "Z"),
            ("Rotation", "W"),
            ("Position", "X"),
            ("Position", "Y"),
            ("Position", "Z"),
        ] {
            for (row, cell) in
                rows.iter_mut()
                    .zip(["Rigid Body", body, &(i + 1).to_string(), property, axis])
            {
                row.push(cell.to_string());
            }
        }
    }
    for (i, marker) in markers.iter().enumerate() {
        for axis in ["X", "Y", "Z"] {
            for (row, cell) in
                rows.iter_mut()
                    .zip(["Marker", marker, &(10 + i).to_string(), "Position", axis])
            {
                row.push(cell.to_string());
            }
        }
    }
    for row in rows {
        text += &(row.join(",") + "\n");
    }
    for k in 0..60 {
        let mut cells = vec![k.to_string(), format!("{:.2}", k as f64 / 100.0)];
        cells.extend(["0", "0", "0", "1", "100", "200", "300"].map(String::from));
        cells.extend(["0", "0", "0", "1", "100", "150", "300"].map(String::from));
        for (i, _) in markers.iter().enumerate() {
            cells.extend([format!("{}", 50 * i), "180".into(), format!("{}", 300 + k)]);
        }
        text += &(cells.join(",") + "\n");
    }
    text
}

#[test]
fn labelled_package_markers_exclude_the_rigid_bodies_own_markers() {
    let take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
    let mut config = with_default_take();
    config.conversion.markers = MarkerSource::Labeled;
    let imported = convert(&take, "lab", &config).unwrap();
    let initial = &imported.trajectory.meta.initial_marker_positions_m;
    assert_eq!(initial.len(), 3);
    assert!((initial[2][0] - 0.1).abs() < 1e-9 && (initial[2][1] - 0.18).abs() < 1e-9);
    // Only the package's columns count; the tool's own marker is not a package marker.
    assert_eq!(imported.report.markers.raw_samples, 3 * 60);
    assert_eq!(imported.report.tracks_kept, 3);
    config.conversion.markers = MarkerSource::Unlabeled;
    let msg = convert(&take, "lab", &config).unwrap_err().to_string();
    assert!(
        msg.contains("lab.csv: no unlabeled marker columns"),
        "{msg}"
    );
}

#[test]
fn the_robot_transform_is_estimated_from_the_tool_body() {
    // The tool of the synthetic take moves on a helix; the robot file holds the same motion
    // in a robot frame with z up, shifted by (0.4, 0.15, 0) (packages-v1's frames).
    let mut take = motive::parse_take(&labelled_take(), Path::new("lab.csv")).unwrap();
    let helix = |k: usize| {
        let a = k as f64 / 59.0 * std::f64::consts::TAU;
        [0.1 * a.cos(), 0.05 * k as f64 / 59.0, 0.1 * a.sin()]
    };
    for (k, p) in take.rigid_bodies[0].position.iter_mut().enumerate() {
        *p = Some(helix(k));
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lab_robot.csv");
    let mut text = crate::robot::ROBOT_HEADER.join(",") + "\n";
    for (k, t) in take.time.iter().enumerate() {
        let p = helix(k);
        // p_robot = R^T p_mocap + o, with R taking robot z (up) to mocap y.
        let robot = [p[0] + 0.4, -p[2] + 0.15, p[1]];
        text += &format!(
            "{t},{},{},{},0,0,0,1,0,0,0,0,0,0,0,0,0\n",
            robot[0], robot[1], robot[2]
        );
    }
    std::fs::write(&path, text).unwrap();
    let robot = read_robot(&path).unwrap();
    let mut config = with_default_take();
    config.conversion.markers = MarkerSource::Labeled;
    config.cleaning.rigid_body_cutoff_hz = 0.0;
    let imported = convert_with_robot(&take, "lab", &config, Some(&robot)).unwrap();
    let fit = imported.report.robot.clone().expect("a robot fit");
    assert!(fit.estimated && fit.rms_m < 1e-9, "{fit:?}");
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let expected = [-half, 0.0, 0.0, half];
    let sign = fit.rotation_xyzw[3].signum();
    for (got, want) in fit.rotation_xyzw.iter().zip(expected) {
        assert!((sign * got - want).abs() < 1e-9, "{fit:?}");
    }
    for (i, t) in [-0.4, 0.0, 0.15].into_iter().enumerate() {
        assert!((fit.translation_m[i] - t).abs() < 1e-9, "{fit:?}");
    }
    let tool = &imported.trajectory.tool;
    for k in [0, 30, 59] {
        assert!(dist(tool.position[k], helix(k)) < 1e-9);
    }
    assert!(imported.report.to_string().contains("estimated transform"));
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}
