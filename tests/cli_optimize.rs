//! End-to-end tests of `rlpkg optimize <config.toml>` on a tiny transport scene: the optimised
//! command costs less than the one it starts from, the output folder is byte-identical whatever
//! the number of threads, `rlpkg eval --optimized` plays the command on the same episodes with
//! the same return (and a library's commands by target tilt), receding-horizon control (`--mpc`)
//! gives the same episodes on one and two threads, and a bad config or output folder exits 2
//! naming the key.

use std::path::Path;
use std::process::Output;

mod common;

use common::{ok, tiny_training};

fn rlpkg(args: &[&str], dir: &Path, threads: &str) -> Output {
    common::rlpkg_in(args, dir, Some(threads))
}

/// The tiny optimisation config: 6 candidates x 2 packages, 3 iterations, 3 knots per action.
const TINY: &str = r#"
transport = "transport.toml"
out_dir = "out"

[conditions]
seed = 3
packages = 2

[risk]
quantile = 0.75
weight = 0.5

[cem]
population = 6
elites = 2
iterations = 3
smoothing = 0.8
seed = 5

[knots]
count = 3
horizon_s = 2.0
initial_speed_m_s = 0.3
speed_std_m_s = 0.3
tilt_std_deg = 3.0
"#;

fn setup(dir: &Path, optimize: &str) {
    std::fs::write(
        dir.join("transport.toml"),
        tiny_training("transport.toml", 32, "3.0"),
    )
    .unwrap();
    std::fs::write(dir.join("optimize.toml"), optimize).unwrap();
}

fn read_dir(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    files.sort();
    files
}

#[test]
fn optimisation_lowers_the_cost_and_writes_the_same_files_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path(), TINY);
    let printed = ok(&rlpkg(
        &["optimize", "optimize.toml", "--quiet", "--out", "one"],
        dir.path(),
        "1",
    ));
    ok(&rlpkg(
        &["optimize", "optimize.toml", "--quiet", "--out", "two"],
        dir.path(),
        "2",
    ));
    let (one, two) = (
        read_dir(&dir.path().join("one")),
        read_dir(&dir.path().join("two")),
    );
    let names: Vec<&str> = one.iter().map(|f| f.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "commands.csv",
            "costs.csv",
            "costs.png",
            "summary.json",
            "trajectory.csv"
        ],
        "{printed}"
    );
    for (a, b) in one.iter().zip(&two) {
        assert!(a == b, "{} differs between 1 and 2 threads", a.0);
    }
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("one/summary.json")).unwrap())
            .unwrap();
    let (start, best) = (
        summary["start_cost"].as_f64().unwrap(),
        summary["best_cost"].as_f64().unwrap(),
    );
    assert!(best < start, "{best} against {start} at the start");
    assert_eq!(summary["iterations"].as_array().unwrap().len(), 3);
    assert_eq!(summary["best_package_costs"].as_array().unwrap().len(), 2);
    // The trajectory reads as a robot file: the header, then time increasing from 0.
    let csv = String::from_utf8(one[4].1.clone()).unwrap();
    let mut lines = csv.lines();
    assert!(lines
        .next()
        .unwrap()
        .starts_with("time_s,pos_x,pos_y,pos_z,quat_x"));
    let times: Vec<f64> = lines
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times[0], 0.0);
    assert!(times.windows(2).all(|w| w[1] > w[0]) && times.len() > 2);

    // The command evaluated on the first episodes of the optimisation's seed: the packages it
    // was optimised on, so its return is minus its mean cost there.
    ok(&rlpkg(
        &["train", "transport.toml", "--quiet"],
        dir.path(),
        "2",
    ));
    let eval = [
        "eval",
        "runs/transport",
        "--episodes",
        "2",
        "--seed",
        "3",
        "--scripted",
        "1.0",
        "--recorded",
        "none",
        "--json",
        "--optimized",
    ];
    let with = |folder: &str| {
        let mut args = eval.to_vec();
        args.push(folder);
        rlpkg(&args, dir.path(), "2")
    };
    let report: serde_json::Value = serde_json::from_str(&ok(&with("one"))).unwrap();
    let row = &report["rows"][2];
    assert_eq!(row["driver"], "optimized one", "{report}");
    assert_eq!(row["episodes"], 2);
    let costs: Vec<f64> = summary["best_package_costs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_f64().unwrap())
        .collect();
    let expected = -(costs[0] + costs[1]) / 2.0;
    let got = row["mean_return"].as_f64().unwrap();
    assert!(
        (got - expected).abs() <= 1e-9 * expected.abs().max(1.0),
        "eval return {got}, optimisation {expected}"
    );
    assert_eq!(report["optimized"][0]["packages"], 2);

    // A library: one command per target tilt for the nominal package, each no costlier than
    // its start; eval plays it as one row, and each tilt's folder as a command of its own.
    let library = TINY
        .replace(
            "packages = 2",
            "packages = 1\nnominal_target_tilts_deg = [35.0, 55.0]",
        )
        .replace("iterations = 3", "iterations = 2");
    std::fs::write(dir.path().join("library.toml"), library).unwrap();
    ok(&rlpkg(
        &["optimize", "library.toml", "--quiet", "--out", "lib"],
        dir.path(),
        "2",
    ));
    let lib: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("lib/summary.json")).unwrap())
            .unwrap();
    let entries = lib["library"].as_array().unwrap();
    assert_eq!(entries.len(), 2, "{lib}");
    for (entry, tilt) in entries.iter().zip([35.0, 55.0]) {
        assert_eq!(entry["target_tilt_deg"], tilt);
        assert!(entry["best_cost"].as_f64().unwrap() <= entry["start_cost"].as_f64().unwrap());
        let folder = dir
            .path()
            .join("lib")
            .join(entry["folder"].as_str().unwrap());
        assert!(folder.join("trajectory.csv").exists());
    }
    let both = ok(&with("lib,lib/tilt-35"));
    let report: serde_json::Value = serde_json::from_str(&both).unwrap();
    assert_eq!(report["rows"][2]["driver"], "optimized lib");
    assert_eq!(report["rows"][3]["driver"], "optimized tilt-35");
    assert_eq!(
        report["optimized"][0]["target_tilts_deg"],
        serde_json::json!([35.0, 55.0])
    );
    assert!(report["optimized"][1].get("target_tilts_deg").is_none());

    // A folder without a summary, or a summary with the wrong number of knots, exits 2.
    let refused = with("missing");
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--optimized missing"));
    let bad = dir.path().join("bad");
    std::fs::create_dir(&bad).unwrap();
    let mut broken = summary.clone();
    broken["best_knots"].as_array_mut().unwrap().pop();
    std::fs::write(bad.join("summary.json"), broken.to_string()).unwrap();
    let refused = with("bad");
    assert_eq!(refused.status.code(), Some(2));
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(
        message.contains("best_knots") && message.contains("9 finite numbers"),
        "{message}"
    );
}

#[test]
fn bad_config_keys_exit_2_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    for (from, to, key) in [
        ("elites = 2", "elites = 7", "cem.elites"),
        ("packages = 2", "packages = 0", "conditions.packages"),
        ("count = 3", "count = 1", "knots.count"),
        ("weight = 0.5", "weight = 1.5", "risk.weight"),
        (
            "smoothing = 0.8",
            "smoothing = 0.8\npopulaton = 3",
            "populaton",
        ),
        ("horizon_s = 2.0", "horizon_s = -2.0", "knots.horizon_s"),
        (
            "packages = 2",
            "packages = 2\nnominal_target_tilts_deg = [40.0]",
            "conditions.packages",
        ),
        (
            "seed = 5",
            "seed = 5\n[mpc]\nhorizon_s = 0.0\nknots = 2\niterations = 1",
            "mpc.horizon_s",
        ),
    ] {
        setup(dir.path(), &TINY.replace(from, to));
        let output = rlpkg(&["optimize", "optimize.toml", "--quiet"], dir.path(), "1");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{key}: {stderr}");
        assert!(stderr.contains(key), "{key}: {stderr}");
        assert!(!dir.path().join("out").exists(), "{key}: wrote output");
    }
}

#[test]
fn receding_horizon_control_gives_the_same_episodes_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let mpc = TINY
        .replace("packages = 2", "packages = 1")
        .replace("population = 6", "population = 3")
        + "\n[mpc]\nhorizon_s = 0.2\nknots = 2\niterations = 1\n";
    setup(dir.path(), &mpc);
    let mut outcomes = Vec::new();
    for threads in ["1", "2"] {
        let printed = ok(&rlpkg(
            &[
                "optimize",
                "optimize.toml",
                "--mpc",
                "--quiet",
                "--out",
                threads,
            ],
            dir.path(),
            threads,
        ));
        assert!(
            printed.contains("per control step of one episode"),
            "{printed}"
        );
        let summary: serde_json::Value = serde_json::from_slice(
            &std::fs::read(dir.path().join(threads).join("mpc.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(summary["outcome"]["episodes"], 1, "{summary}");
        assert!(summary["control_steps"].as_u64().unwrap() > 1, "{summary}");
        assert!(summary["real_time_factor"].as_f64().unwrap() > 0.0);
        outcomes.push(summary["outcome"].clone());
    }
    assert_eq!(outcomes[0], outcomes[1]);
    // --mpc needs its table.
    setup(dir.path(), TINY);
    let refused = rlpkg(
        &["optimize", "optimize.toml", "--mpc", "--quiet"],
        dir.path(),
        "1",
    );
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("[mpc]"));
}

#[test]
fn a_signal_before_the_files_are_in_place_leaves_the_output_folder_as_it_was() {
    // A one-iteration search stopped by SIGTERM while it settles its packages: the command ends
    // with 130 after the iteration, and the folder holds neither its files nor a staging folder.
    let dir = tempfile::tempdir().unwrap();
    setup(
        dir.path(),
        &TINY.replace("iterations = 3", "iterations = 1"),
    );
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(["optimize", "optimize.toml", "--quiet", "--out", "stopped"])
        .current_dir(dir.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let kill = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    let stopped = dir.path().join("stopped");
    let left = if stopped.exists() {
        read_dir(&stopped)
    } else {
        Vec::new()
    };
    assert!(
        left.is_empty(),
        "{:?}",
        left.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
}
