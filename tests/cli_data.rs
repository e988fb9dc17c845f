//! End-to-end tests of `rlpkg data import-motive` (and of the dataset loader behind `simulate`)
//! through the binary: a working import, the robot's tool track, the clean-up of an interrupted
//! import, and a table of bad inputs that must each exit with code 2, name the file and the key or
//! line, and leave no output behind.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use rlpkg_mocap::motive::read_take;
use rlpkg_mocap::{Dataset, Split};

const EXCERPT: &str = "a30_m0.5_high_excerpt";

/// The excerpt listed in [takes], as a config must do.
const EXCERPT_TAKE: &str =
    "[takes.\"a30_m0.5_high_excerpt\"]\nsplit = \"train\"\nobject_total_mass_kg = 0.2268\n";

/// packages-v1's robot-to-mocap transform, `p_mocap = R (p_robot - o)`, as `[robot]` keys.
const PACKAGES_V1_ROBOT: &str = "[robot]\nrotation_xyzw = [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]\ntranslation_m = [-0.4, 0.0, 0.15]\n";

fn rlpkg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn fixture(name: &str) -> String {
    root()
        .join("mocap/tests/fixtures")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn config() -> String {
    root()
        .join("configs/import/motive.toml")
        .to_string_lossy()
        .into_owned()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The shipped config with the excerpts listed, written into `dir`.
fn excerpt_config(dir: &Path) -> String {
    let mut text = fs::read_to_string(config()).unwrap();
    text += &format!("\"{EXCERPT}\" = {{ split = \"train\", object_total_mass_kg = 0.2268 }}\n");
    text += &format!("\"{EXCERPT}_mm\" = {{ split = \"test\", object_total_mass_kg = 0.34 }}\n");
    let path = dir.join("import.toml");
    fs::write(&path, text).unwrap();
    path.to_string_lossy().into_owned()
}

#[test]
fn importing_a_take_writes_a_loadable_dataset_and_reports_retention() {
    let dir = tempfile::tempdir().unwrap();
    let config = excerpt_config(dir.path());
    let out = dir.path().join("takes");
    let out_arg = out.to_str().unwrap();
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        out_arg,
        "--config",
        &config,
    ]);
    let stdout = text(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", text(&run.stderr));
    assert!(
        stdout.contains("a30_m0.5_high_excerpt: frames kept 250 of 250 (100.0 %) at 250 Hz"),
        "{stdout}"
    );
    assert!(stdout.contains("marker samples kept"), "{stdout}");
    for file in ["tool.csv", "object.csv", "markers.csv", "meta.toml"] {
        assert!(out.join(EXCERPT).join(file).is_file(), "{file} missing");
    }
    let dataset = Dataset::open(&out).unwrap();
    assert_eq!(dataset.ids(None), vec![EXCERPT]);
    assert_eq!(dataset.entries[0].split, Split::Train);
    assert_eq!(dataset.entries[0].frames, 250);
    // `load` checks the manifest's promises, the marker row count among them.
    assert!(dataset.entries[0].marker_rows.is_some());
    let trajectory = dataset.load(EXCERPT).unwrap();
    assert_eq!(trajectory.tool.t.len(), 250);
    assert_eq!(trajectory.markers.len(), 250);
    assert!(trajectory.meta.initial_marker_positions_m.len() >= 20);

    // A second import into the same folder keeps the first entry.
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt_mm.csv.gz"),
        "--out",
        out_arg,
        "--config",
        &config,
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let dataset = Dataset::open(&out).unwrap();
    assert_eq!(
        dataset.ids(None),
        vec![EXCERPT.to_string(), format!("{EXCERPT}_mm")]
    );
    assert_eq!(dataset.entries[1].split, Split::Test);
    assert_eq!(dataset.entries[1].object_total_mass_kg, 0.34);
}

#[test]
fn excluded_takes_are_reported_but_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("import.toml");
    fs::write(
        &config,
        "[takes]\n\"a30_m0.5_high_excerpt\" = { exclude = true, object_total_mass_kg = 0.2268 }\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        out.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    assert!(text(&run.stdout).contains("[excluded by config, not written]"));
    assert!(!out.join(EXCERPT).exists());
    assert!(Dataset::open(&out).unwrap().entries.is_empty());
}

#[test]
fn an_interrupted_import_is_cleaned_up_by_the_next_one() {
    let dir = tempfile::tempdir().unwrap();
    let config = excerpt_config(dir.path());
    let out = dir.path().join("out");
    // What a run killed while writing leaves: an unfinished trajectory folder and an unfinished
    // manifest file, and no manifest entry.
    fs::create_dir_all(out.join(format!(".rlpkg-tmp-{EXCERPT}"))).unwrap();
    fs::write(out.join(format!(".rlpkg-tmp-{EXCERPT}/tool.csv")), "t,px\n").unwrap();
    fs::write(out.join(".manifest.toml.Ab12Cd"), "[[traj").unwrap();
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        out.to_str().unwrap(),
        "--config",
        &config,
    ]);
    let stdout = text(&run.stdout);
    assert!(run.status.success(), "{}", text(&run.stderr));
    assert!(
        stdout.contains("removed the unfinished folder")
            && stdout.contains(".manifest.toml.Ab12Cd"),
        "{stdout}"
    );
    let mut names: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, [EXCERPT, "manifest.toml"]);
    assert!(Dataset::open(&out).unwrap().load(EXCERPT).is_ok());
}

/// Packages-v1's rotation (robot z up -> mocap y up) applied to a vector, and its inverse.
fn robot_to_mocap(v: [f64; 3]) -> [f64; 3] {
    [v[0], v[2], -v[1]]
}
fn mocap_to_robot(v: [f64; 3]) -> [f64; 3] {
    [v[0], -v[2], v[1]]
}

/// A robot trajectory file for the excerpt: its Motive tool body carried back into the robot
/// frame (so the transform matches) and moved by `shift_m` along x, with made-up constant
/// commanded rates.
fn write_robot_file(path: &Path, shift_m: f64) {
    let take = read_take(Path::new(&fixture("a30_m0.5_high_excerpt.csv.gz"))).unwrap();
    let tool = &take.rigid_bodies[0];
    let mut text = String::from("time_s,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,omega_x,omega_y,omega_z,acc_x,acc_y,acc_z\n");
    for (k, &t) in take.time.iter().enumerate() {
        let p = tool.position[k].unwrap();
        let p = mocap_to_robot([p[0] + 0.4 + shift_m, p[1], p[2] - 0.15]);
        let q = tool.rotation[k].unwrap();
        let q = mocap_to_robot([q[0], q[1], q[2]]);
        let w = tool.rotation[k].unwrap()[3];
        text += &format!(
            "{t:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{w:.6},0.1,0,0,0,0,0.2,0,0,1\n",
            p[0], p[1], p[2], q[0], q[1], q[2]
        );
    }
    fs::write(path, text).unwrap();
}

#[test]
fn a_robot_file_becomes_the_tool_track() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("import.toml");
    fs::write(&config, format!("{EXCERPT_TAKE}{PACKAGES_V1_ROBOT}")).unwrap();
    let robot = dir.path().join(format!("{EXCERPT}_robot.csv"));
    write_robot_file(&robot, 0.0);
    let out = dir.path().join("out");
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--robot",
        robot.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    let stdout = text(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", text(&run.stderr));
    assert!(
        stdout.contains("tool track from") && stdout.contains("(given transform"),
        "{stdout}"
    );
    let trajectory = Dataset::open(&out).unwrap().load(EXCERPT).unwrap();
    let tool = &trajectory.tool;
    assert_eq!(tool.t.len(), 250);
    // The commanded rates, rotated into the mocap frame, not differences of the positions.
    for k in [0, 100, 249] {
        assert_eq!(tool.velocity[k], robot_to_mocap([0.1, 0.0, 0.0]));
        assert_eq!(tool.angular_velocity[k], robot_to_mocap([0.0, 0.0, 0.2]));
        assert_eq!(tool.acceleration[k], robot_to_mocap([0.0, 0.0, 1.0]));
    }
    // The positions are the Motive body's again (to the file's 6 decimals).
    let take = read_take(Path::new(&fixture("a30_m0.5_high_excerpt.csv.gz"))).unwrap();
    let body = take.rigid_bodies[0].position[120].unwrap();
    let p = tool.position[120];
    assert!(
        (0..3).all(|i| (p[i] - body[i]).abs() < 2e-6),
        "{p:?} vs {body:?}"
    );

    // A robot file 5 cm off the Motive tool body (another take's, or a wrong transform) is refused.
    write_robot_file(&robot, 0.05);
    let elsewhere = dir.path().join("elsewhere");
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--robot",
        robot.to_str().unwrap(),
        "--out",
        elsewhere.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    let stderr = text(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("_robot.csv: the given transform puts the commanded tool point 50.0 mm (RMS) from the Motive tool rigid body, more than robot.max_fit_rms_m = 0.005 m"),
        "{stderr}"
    );
    assert!(!elsewhere.exists());

    // Without a transform in the config it is estimated, which this excerpt's path (still, then
    // straight up) cannot support: an error that says what to add.
    fs::write(&config, EXCERPT_TAKE).unwrap();
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--robot",
        robot.to_str().unwrap(),
        "--out",
        elsewhere.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    let stderr = text(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("(nearly) a straight line")
            && stderr.contains("expected [robot] rotation_xyzw and translation_m"),
        "{stderr}"
    );
    assert!(!elsewhere.exists());
}

/// One bad input: files to create in the test folder, the arguments (`{dir}` is the test folder),
/// and what stderr must contain.
struct Case {
    name: &'static str,
    files: &'static [(&'static str, &'static str)],
    args: &'static [&'static str],
    expect: &'static [&'static str],
}

const TAKE: &str = "{fixtures}/a30_m0.5_high_excerpt.csv.gz";

/// A small take whose line 9 (frame 1) has a garbled time cell.
const GARBLED_TAKE: &str = "Format Version,1.23,Take Name,bad,Capture Frame Rate,100,Export Frame Rate,100,Rotation Type,Quaternion,Length Units,Meters\n\n\
,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker\n\
,Name,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000\n\
,ID,1,1,1,1,1,1,1,1000,1000,1000\n\
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Position,Position,Position\n\
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,X,Y,Z\n\
0,0.00,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n\
1,0.0o4,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n";

/// The same take cut at a line boundary: its header promises 3 frames.
const CUT_TAKE: &str = "Format Version,1.23,Take Name,cut,Capture Frame Rate,100,Export Frame Rate,100,Total Exported Frames,3,Rotation Type,Quaternion,Length Units,Meters\n\n\
,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker\n\
,Name,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000\n\
,ID,1,1,1,1,1,1,1,1000,1000,1000\n\
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Position,Position,Position\n\
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,X,Y,Z\n\
0,0.00,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n\
1,0.01,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n";

const ROBOT_HEADER: &str = "time_s,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,omega_x,omega_y,omega_z,acc_x,acc_y,acc_z\n";

const CASES: &[Case] = &[
    Case {
        name: "config file missing",
        files: &[],
        args: &[TAKE, "--config", "{dir}/missing.toml"],
        expect: &["missing.toml: cannot read file"],
    },
    Case {
        name: "unknown config key",
        files: &[("c.toml", "[cleaning]\nfilter_order = 4\nbogus = 1\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml: line 3", "bogus"],
    },
    Case {
        name: "config value out of range",
        files: &[("c.toml", "[cleaning]\nfilter_order = 40\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml", "cleaning.filter_order = 40: expected 1..=10"],
    },
    Case {
        name: "fixed-length array of the wrong length",
        files: &[("c.toml", "[package]\nsize_m = [0.254]\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml: line 2", "invalid length 1, expected an array of length 2"],
    },
    Case {
        name: "sheet offset not positive",
        files: &[("c.toml", "[cleaning]\nreid_max_sheet_offset_m = 0.0\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml", "cleaning.reid_max_sheet_offset_m = 0: expected a number > 0"],
    },
    Case {
        name: "take not listed and no default",
        files: &[("c.toml", "[takes]\nother = { split = \"train\", object_total_mass_kg = 0.2 }\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &[
            "c.toml: take \"a30_m0.5_high_excerpt\" is not listed in [takes] and there is no [default_take]",
        ],
    },
    Case {
        name: "listed take without a split",
        files: &[("c.toml", "[takes]\n\"a30_m0.5_high_excerpt\" = { object_total_mass_kg = 0.2 }\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml", "takes.\"a30_m0.5_high_excerpt\".split is missing"],
    },
    Case {
        name: "default take without a mass",
        files: &[("c.toml", "[default_take]\nsplit = \"train\"\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml", "default_take.object_total_mass_kg is missing"],
    },
    Case {
        name: "robot rotation without translation",
        files: &[("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n[robot]\nrotation_xyzw = [0.0, 0.0, 0.0, 1.0]\n")],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["c.toml", "robot.rotation_xyzw and robot.translation_m: expected both"],
    },
    Case {
        name: "take file missing",
        files: &[("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n")],
        args: &["{dir}/nothing.csv", "--config", "{dir}/c.toml"],
        expect: &["nothing.csv: take file not found"],
    },
    Case {
        name: "garbled take cell",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("bad_take.csv", GARBLED_TAKE),
        ],
        args: &["{dir}/bad_take.csv", "--config", "{dir}/c.toml"],
        expect: &["bad_take.csv: line 9, column 2: expected a number, found '0.0o4'"],
    },
    Case {
        name: "take cut at a line boundary",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("cut.csv", CUT_TAKE),
        ],
        args: &["{dir}/cut.csv", "--config", "{dir}/c.toml"],
        expect: &["cut.csv: line 1", "'Total Exported Frames' says 3 but the file has 2 data rows"],
    },
    Case {
        name: "the same take twice",
        files: &[("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n")],
        args: &[TAKE, TAKE, "--config", "{dir}/c.toml"],
        expect: &["a30_m0.5_high_excerpt.csv.gz: trajectory id 'a30_m0.5_high_excerpt' is given twice"],
    },
    Case {
        name: "output folder is a file",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("out", "a file"),
        ],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["out: exists and is not a folder"],
    },
    Case {
        name: "a file where the trajectory folder goes",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("out/a30_m0.5_high_excerpt", "a file"),
        ],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["out/a30_m0.5_high_excerpt: exists and is not a folder"],
    },
    Case {
        name: "existing manifest malformed",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("out/manifest.toml", "[[trajectory]]\nid = \"x\"\nframes = \"many\"\n"),
        ],
        args: &[TAKE, "--config", "{dir}/c.toml"],
        expect: &["out/manifest.toml:3:"],
    },
    Case {
        name: "robot file not named after a take",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("commands.csv", ROBOT_HEADER),
        ],
        args: &[TAKE, "--robot", "{dir}/commands.csv", "--config", "{dir}/c.toml"],
        expect: &["commands.csv: a robot file must be named <take id>_robot.csv"],
    },
    Case {
        name: "robot file of another take",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("other_robot.csv", ROBOT_HEADER),
        ],
        args: &[TAKE, "--robot", "{dir}/other_robot.csv", "--config", "{dir}/c.toml"],
        expect: &["other_robot.csv: no take 'other' among the takes given"],
    },
    Case {
        name: "robot file with a wrong header",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            ("a30_m0.5_high_excerpt_robot.csv", "t,x,y,z\n0,0,0,0\n"),
        ],
        args: &[TAKE, "--robot", "{dir}/a30_m0.5_high_excerpt_robot.csv", "--config", "{dir}/c.toml"],
        expect: &["a30_m0.5_high_excerpt_robot.csv:1: expected the header \"time_s,pos_x"],
    },
    Case {
        name: "robot file with a bad quaternion",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            (
                "a30_m0.5_high_excerpt_robot.csv",
                "time_s,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,omega_x,omega_y,omega_z,acc_x,acc_y,acc_z\n0,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0,0\n0.004,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0\n",
            ),
        ],
        args: &[TAKE, "--robot", "{dir}/a30_m0.5_high_excerpt_robot.csv", "--config", "{dir}/c.toml"],
        expect: &["a30_m0.5_high_excerpt_robot.csv:3: quat_x,quat_y,quat_z,quat_w must be a unit quaternion"],
    },
    Case {
        name: "robot file on another clock",
        files: &[
            ("c.toml", "[default_take]\nsplit = \"train\"\nobject_total_mass_kg = 0.2\n"),
            (
                "a30_m0.5_high_excerpt_robot.csv",
                "time_s,pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,omega_x,omega_y,omega_z,acc_x,acc_y,acc_z\n100,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0,0\n101,0,0,0,0,0,0,1,0,0,0,0,0,0,0,0,0\n",
            ),
        ],
        args: &[TAKE, "--robot", "{dir}/a30_m0.5_high_excerpt_robot.csv", "--config", "{dir}/c.toml"],
        expect: &["a30_m0.5_high_excerpt.csv.gz", "robot file", "covers none of the take's frames"],
    },
];

#[test]
fn bad_inputs_exit_with_2_name_file_and_key_or_line_and_write_nothing() {
    let fixtures = root().join("mocap/tests/fixtures");
    let mut failures = Vec::new();
    for case in CASES {
        let dir = tempfile::tempdir().unwrap();
        for (name, content) in case.files {
            let path = dir.path().join(name);
            fs::create_dir_all(path.parent().unwrap()).unwrap();
            fs::write(path, content).unwrap();
        }
        let before = listing(dir.path());
        let expand = |arg: &str| {
            arg.replace("{dir}", dir.path().to_str().unwrap())
                .replace("{fixtures}", fixtures.to_str().unwrap())
        };
        let out = dir.path().join("out");
        let mut args: Vec<String> = vec!["data".into(), "import-motive".into()];
        args.extend(case.args.iter().map(|a| expand(a)));
        args.extend(["--out".into(), out.to_string_lossy().into_owned()]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let run = rlpkg(&args);
        let stderr = text(&run.stderr);
        let problems: Vec<String> = [
            (run.status.code() != Some(2)).then(|| format!("exit code {:?}", run.status.code())),
            case.expect
                .iter()
                .find(|e| !stderr.contains(*e))
                .map(|e| format!("no {e:?} in the message")),
            (listing(dir.path()) != before).then(|| "files were written".to_string()),
        ]
        .into_iter()
        .flatten()
        .collect();
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}; stderr: {stderr}",
                case.name,
                problems.join(", ")
            ));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

/// Every path under `dir` with its size, to tell whether a run wrote anything.
fn listing(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in fs::read_dir(&d).unwrap() {
            let entry = entry.unwrap();
            let meta = entry.metadata().unwrap();
            if meta.is_dir() {
                stack.push(entry.path());
            }
            out.push((entry.path(), meta.len()));
        }
    }
    out.sort();
    out
}

#[test]
fn a_recording_cut_at_a_line_boundary_is_refused_by_simulate() {
    // A copy of a shipped trajectory with its dataset's manifest; markers.csv loses its last line.
    let dir = tempfile::tempdir().unwrap();
    let shipped = root().join("data/deformable-sim-real");
    let traj = dir.path().join("HHLHL");
    fs::create_dir(&traj).unwrap();
    for name in ["tool.csv", "object.csv", "meta.toml"] {
        fs::copy(shipped.join("HHLHL").join(name), traj.join(name)).unwrap();
    }
    let markers = fs::read_to_string(shipped.join("HHLHL/markers.csv")).unwrap();
    let lines: Vec<&str> = markers.lines().collect();
    fs::write(
        traj.join("markers.csv"),
        lines[..lines.len() - 1].join("\n") + "\n",
    )
    .unwrap();
    fs::copy(
        shipped.join("manifest.toml"),
        dir.path().join("manifest.toml"),
    )
    .unwrap();
    let out = dir.path().join("sim");
    let run = rlpkg(&[
        "simulate",
        traj.to_str().unwrap(),
        "--seconds",
        "0.1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stderr = text(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("HHLHL/markers.csv: expected")
            && stderr.contains(&format!("data rows, found {}", lines.len() - 2)),
        "{stderr}"
    );
    assert!(!out.exists());
}
