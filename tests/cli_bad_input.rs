//! Bad input that could otherwise end with a wrong result and no word, through the binary, one
//! table: a calibration resumed with another objective, non-finite checkpoints and ONNX files,
//! options that would do nothing, signals during long steps, data that cannot be right. Each row
//! gives the arguments, the exit code (2 for bad input, 130 for a signal), words the message must
//! hold, and the case's folder must be left exactly as it was.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

mod common;
use common::{args, copy_dir, edit, repo, TINY_CARTPOLE};

fn dataset() -> String {
    repo()
        .join("data/deformable-sim-real")
        .display()
        .to_string()
}

fn rlpkg(args: &[String], dir: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_rlpkg"));
    command.args(args).current_dir(dir);
    command
}

/// Every file and folder under `dir` with its bytes (folders: empty).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files.insert(path.clone(), Vec::new());
            files.extend(snapshot(&path));
        } else {
            files.insert(path.clone(), std::fs::read(&path).unwrap());
        }
    }
    files
}

/// A CartPole run trained once (4 updates, exported) for every case that needs one.
fn trained_run() -> &'static Path {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &RUN.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();
        let out = rlpkg(&args(&["train", "tiny.toml", "--quiet"]), dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        let run = dir.path().join("runs/tiny");
        (dir, run)
    })
    .1
}

/// Copies the trained run to `dir/run`.
fn run_copy(dir: &Path) -> PathBuf {
    let run = dir.join("run");
    copy_dir(trained_run(), &run);
    run
}

/// The state file of the run's latest checkpoint, as JSON.
fn state_path(run: &Path) -> PathBuf {
    let latest = std::fs::read_to_string(run.join("checkpoints/latest")).unwrap();
    run.join("checkpoints")
        .join(latest.trim())
        .join("state.json")
}

/// Sets `key` of the run's latest state (a float stored as its bits) to `value`.
fn set_state_float(run: &Path, key: &str, index: Option<usize>, value: f64) {
    let path = state_path(run);
    let mut state: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let mut slot = &mut state;
    for part in key.split('.') {
        slot = &mut slot[part];
    }
    if let Some(i) = index {
        slot = &mut slot[i];
    }
    assert!(slot.is_u64(), "{key}");
    *slot = serde_json::Value::from(value.to_bits());
    std::fs::write(&path, serde_json::to_vec(&state).unwrap()).unwrap();
}

/// Replaces the only occurrence of the f32 `from` in `path` with `to`.
fn patch_f32(path: &Path, from: f32, to: f32) {
    let mut bytes = std::fs::read(path).unwrap();
    let pattern = from.to_le_bytes();
    let at: Vec<usize> = (0..bytes.len() - 3)
        .filter(|&i| bytes[i..i + 4] == pattern)
        .collect();
    assert_eq!(
        at.len(),
        1,
        "{} holds {from} {} times",
        path.display(),
        at.len()
    );
    bytes[at[0]..at[0] + 4].copy_from_slice(&to.to_le_bytes());
    std::fs::write(path, bytes).unwrap();
}

/// The study's scene on the coarsest grid (6 x 7) with a 0.2 s rest period, as `dir/quick.toml`.
fn quick_scene(dir: &Path) {
    let study = std::fs::read_to_string(repo().join("configs/scenes/study.toml")).unwrap();
    let quick = study
        .replace("rest_time_s = 2.0", "rest_time_s = 0.2")
        .replace("grid = [21, 25]", "grid = [6, 7]")
        .replace("[health]", "[health]\nobject_outside = false");
    assert!(quick.contains("grid = [6, 7]") && quick.contains("rest_time_s = 0.2"));
    std::fs::write(dir.join("quick.toml"), quick).unwrap();
}

/// A calibration config on the first 0.05 s of HHHHH in `quick.toml`, into `out`.
fn calibration_config(dir: &Path) {
    std::fs::write(
        dir.join("calibrate.toml"),
        format!(
            "data = \"{}\"\ntrajectories = [\"HHHHH\"]\nout_dir = \"out\"\n\n\
             [sim]\npreset = \"quick.toml\"\nbetween = 0\nmax_seconds = 0.05\n\n\
             [optimiser]\niterations = 1\nbatch_size = 2\ninitial_points = 1\nseed = 5\n\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 1.0e4\nupper = 1.0e6\nlog = true\n",
            dataset()
        ),
    )
    .unwrap();
}

/// A folder with `quick.toml`, `calibrate.toml` and the finished calibration `out/`, made once.
fn calibrated() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        quick_scene(dir.path());
        calibration_config(dir.path());
        let out = rlpkg(&args(&["calibrate", "calibrate.toml"]), dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        dir
    })
    .path()
}

/// Copies the finished calibration into `dir`; the rerun asks for one more batch.
fn resumed_calibration(dir: &Path, extra: &[&str]) -> Vec<String> {
    copy_dir(calibrated(), dir);
    let mut list = args(&["calibrate", "calibrate.toml", "--iterations", "2"]);
    list.extend(args(extra));
    list
}

/// `quick.toml` with a substep rate of 1e8 Hz (in range): one frame is over 400 000 substeps.
fn slow_scene(dir: &Path) {
    quick_scene(dir);
    edit(
        &dir.join("quick.toml"),
        "substep_rate_hz = 30720.0",
        "substep_rate_hz = 1.0e8",
    );
}

/// Copies the shipped recording HHHHH to `dir/rec/<name>` (no manifest beside it).
fn recording(dir: &Path, name: &str) -> PathBuf {
    let target = dir.join("rec").join(name);
    copy_dir(&repo().join("data/deformable-sim-real/HHHHH"), &target);
    target
}

/// `simulate` of the recording `rec/<name>` for 0.01 s into `out`.
fn simulate(name: &str) -> Vec<String> {
    args(&[
        "simulate",
        &format!("rec/{name}"),
        "--seconds",
        "0.01",
        "--out",
        "out",
    ])
}

/// A dataset `dir/rec` holding HHHHH, with `manifest` as its manifest.
fn dataset_with(dir: &Path, manifest: &str) -> Vec<String> {
    quick_scene(dir);
    recording(dir, "HHHHH");
    std::fs::write(dir.join("rec/manifest.toml"), manifest).unwrap();
    args(&[
        "eval",
        "--params",
        "quick.toml",
        "--data",
        "rec",
        "--split",
        "test",
        "--out",
        "out",
    ])
}

/// The shipped manifest's entry of HHHHH, in the test split.
const HHHHH_ENTRY: &str = "[[trajectory]]\nid = \"HHHHH\"\nsplit = \"test\"\nframes = 1412\n\
                           duration_s = 5.8792\nobject_total_mass_kg = 0.569592\n";

/// The excerpt Motive take, decompressed to `dir/a30_m0.5_high.csv` (a take the shipped import
/// config lists) with `from` replaced by `to`.
fn motive_take(dir: &Path, from: &str, to: &str) -> Vec<String> {
    let gz = repo().join("mocap/tests/fixtures/a30_m0.5_high_excerpt.csv.gz");
    let out = Command::new("gzip").arg("-dc").arg(&gz).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains(from), "the take lacks {from}");
    std::fs::write(dir.join("a30_m0.5_high.csv"), text.replacen(from, to, 1)).unwrap();
    let config = repo().join("configs/import/motive.toml");
    args(&[
        "data",
        "import-motive",
        "a30_m0.5_high.csv",
        "--out",
        "takes",
        "--config",
        &config.display().to_string(),
    ])
}

/// One row of the table.
struct Case {
    name: &'static str,
    /// Prepares the case's folder (the working directory) and returns the arguments.
    setup: fn(&Path) -> Vec<String>,
    /// Expected exit code.
    code: i32,
    /// Words the message must hold.
    words: &'static [&'static str],
    /// Send SIGINT (`"INT"`) or SIGTERM (`"TERM"`) this long after the start.
    signal: Option<(&'static str, Duration)>,
}

fn cases() -> Vec<Case> {
    vec![
        // 2. A calibration resumes only the objective its folder fits.
        Case {
            name: "calibration resumed with another time window",
            setup: |dir| resumed_calibration(dir, &["--max-seconds", "0.06"]),
            code: 2,
            words: &[
                "out/objective.toml",
                "line",
                "max_seconds = 0.05",
                "max_seconds = 0.06",
                "--fresh",
            ],
            signal: None,
        },
        Case {
            name: "calibration resumed with other trajectories",
            setup: |dir| resumed_calibration(dir, &["--trajectories", "HHHHM"]),
            code: 2,
            words: &[
                "out/objective.toml",
                "trajectories = [\"HHHHH\"]",
                "trajectories = [\"HHHHM\"]",
            ],
            signal: None,
        },
        Case {
            name: "calibration resumed with other loss weights",
            setup: |dir| {
                let list = resumed_calibration(dir, &[]);
                let config = dir.join("calibrate.toml");
                let text = std::fs::read_to_string(&config).unwrap();
                std::fs::write(&config, text + "\n[loss]\nobject = 1.0\npackage = 0.7\n").unwrap();
                list
            },
            code: 2,
            words: &["out/objective.toml", "package = 0.2", "package = 0.7"],
            signal: None,
        },
        Case {
            name: "calibration resumed with another seed",
            setup: |dir| {
                let list = resumed_calibration(dir, &[]);
                edit(&dir.join("calibrate.toml"), "seed = 5", "seed = 6");
                list
            },
            code: 2,
            words: &["out/objective.toml", "seed = 5", "seed = 6"],
            signal: None,
        },
        Case {
            name: "calibration resumed with another scene",
            setup: |dir| {
                let list = resumed_calibration(dir, &[]);
                edit(&dir.join("quick.toml"), "mu_con = 0.5", "mu_con = 0.6");
                list
            },
            code: 2,
            words: &["out/objective.toml", "mu_con = 0.5", "mu_con = 0.6"],
            signal: None,
        },
        Case {
            name: "calibration resumed with other bounds",
            setup: |dir| {
                let list = resumed_calibration(dir, &[]);
                edit(
                    &dir.join("calibrate.toml"),
                    "upper = 1.0e6",
                    "upper = 2.0e6",
                );
                list
            },
            code: 2,
            words: &[
                "out/objective.toml",
                "upper = 1000000.0",
                "upper = 2000000.0",
            ],
            signal: None,
        },
        // 5. Signals during long steps.
        Case {
            name: "Ctrl-C during a calibration's long first substeps",
            setup: |dir| {
                slow_scene(dir);
                calibration_config(dir);
                args(&["calibrate", "calibrate.toml"])
            },
            code: 130,
            words: &["interrupted"],
            signal: Some(("INT", Duration::from_millis(1500))),
        },
        Case {
            name: "SIGTERM during eval --params with long substeps",
            setup: |dir| {
                slow_scene(dir);
                args(&[
                    "eval",
                    "--params",
                    "quick.toml",
                    "--data",
                    &dataset(),
                    "--out",
                    "eval",
                ])
            },
            code: 130,
            words: &["interrupted"],
            signal: Some(("TERM", Duration::from_millis(1500))),
        },
        Case {
            name: "SIGTERM during a replay into a new folder",
            setup: |dir| {
                slow_scene(dir);
                simulate_shipped_whole("quick.toml")
            },
            code: 130,
            words: &["interrupted"],
            signal: Some(("TERM", Duration::from_millis(1500))),
        },
        Case {
            name: "SIGHUP during a replay into a new folder",
            setup: |dir| {
                slow_scene(dir);
                simulate_shipped_whole("quick.toml")
            },
            code: 130,
            words: &["interrupted"],
            signal: Some(("HUP", Duration::from_millis(1500))),
        },
        // 3. Non-finite state is refused on load.
        Case {
            name: "NaN weight in a checkpoint (eval)",
            setup: |dir| {
                let run = run_copy(dir);
                let model = state_path(&run).with_file_name("model.bpk");
                let mut bytes = std::fs::read(&model).unwrap();
                let end = bytes.len();
                bytes[end - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
                std::fs::write(&model, bytes).unwrap();
                args(&["eval", "run", "--episodes", "2"])
            },
            code: 2,
            words: &["model.bpk", "NaN", "expected finite weights"],
            signal: None,
        },
        Case {
            name: "NaN weight in a checkpoint (export)",
            setup: |dir| {
                let run = run_copy(dir);
                let model = state_path(&run).with_file_name("model.bpk");
                let mut bytes = std::fs::read(&model).unwrap();
                let end = bytes.len();
                bytes[end - 4..].copy_from_slice(&f32::INFINITY.to_le_bytes());
                std::fs::write(&model, bytes).unwrap();
                args(&["export", "run"])
            },
            code: 2,
            words: &["model.bpk", "inf", "expected finite weights"],
            signal: None,
        },
        Case {
            name: "negative learning rate in a run's state (train --resume)",
            setup: |dir| {
                let run = run_copy(dir);
                set_state_float(&run, "learning_rate", None, -1e-3);
                args(&["train", "--resume", "run", "--quiet"])
            },
            code: 2,
            words: &[
                "state.json",
                "`learning_rate` = -0.001",
                "expected a finite rate >= 0",
            ],
            signal: None,
        },
        Case {
            name: "NaN learning rate in a run's state (eval)",
            setup: |dir| {
                let run = run_copy(dir);
                set_state_float(&run, "learning_rate", None, f64::NAN);
                args(&["eval", "run", "--episodes", "2"])
            },
            code: 2,
            words: &["state.json", "`learning_rate` = NaN"],
            signal: None,
        },
        Case {
            name: "NaN in the observation statistics (export)",
            setup: |dir| {
                let run = run_copy(dir);
                set_state_float(&run, "obs_stats.mean", Some(1), f64::NAN);
                args(&["export", "run"])
            },
            code: 2,
            words: &["state.json", "`obs_stats.mean[1]`", "not finite"],
            signal: None,
        },
        Case {
            name: "negative variance in the reward statistics (train --resume)",
            setup: |dir| {
                let run = run_copy(dir);
                set_state_float(&run, "reward_stats.var", Some(0), -1.0);
                args(&["train", "--resume", "run", "--quiet"])
            },
            code: 2,
            words: &["state.json", "`reward_stats.var[0]` = -1", "variance >= 0"],
            signal: None,
        },
        Case {
            name: "infinite constant in an ONNX policy (eval --policy)",
            setup: |dir| {
                let run = run_copy(dir);
                patch_f32(&run.join("policy.onnx"), 10.0, f32::INFINITY);
                args(&["eval", "--policy", "run/policy.onnx", "--episodes", "2"])
            },
            code: 2,
            words: &[
                "run/policy.onnx",
                "norm_clip_high",
                "inf",
                "expected finite weights",
            ],
            signal: None,
        },
        // 7. Options that would do nothing.
        Case {
            name: "--scripted on a CartPole run",
            setup: |dir| {
                run_copy(dir);
                args(&["eval", "run", "--episodes", "2", "--scripted", "1.0"])
            },
            code: 2,
            words: &["--scripted", "Transport-v0", "CartPole-v1"],
            signal: None,
        },
        Case {
            name: "--profile on a CartPole run",
            setup: |dir| {
                run_copy(dir);
                args(&["eval", "run", "--episodes", "2", "--profile", "1"])
            },
            code: 2,
            words: &["--profile", "Transport-v0", "CartPole-v1"],
            signal: None,
        },
        Case {
            name: "--trajectories on an ONNX CartPole policy",
            setup: |dir| {
                run_copy(dir);
                args(&[
                    "eval",
                    "--policy",
                    "run/policy.onnx",
                    "--trajectories",
                    "test",
                ])
            },
            code: 2,
            words: &["--trajectories", "Transport-v0", "--config"],
            signal: None,
        },
        Case {
            name: "--stop-after below the run's update",
            setup: |dir| {
                run_copy(dir);
                args(&["train", "--resume", "run", "--stop-after", "2"])
            },
            code: 2,
            words: &["--stop-after 2", "already at update 4", "> 4"],
            signal: None,
        },
        Case {
            name: "simulate into a folder holding an earlier replay",
            setup: |dir| {
                std::fs::create_dir_all(dir.join("out/frames")).unwrap();
                std::fs::write(dir.join("out/metrics.csv"), "frame,t\n").unwrap();
                std::fs::write(dir.join("out/frames/000_t-2.000s.png"), "").unwrap();
                let take = repo().join("data/deformable-sim-real/HHHHH");
                args(&[
                    "simulate",
                    &take.display().to_string(),
                    "--out",
                    "out",
                    "--seconds",
                    "0.01",
                ])
            },
            code: 2,
            words: &[
                "--out out",
                "metrics.csv",
                "frames/000_t-2.000s.png",
                "another --out",
            ],
            signal: None,
        },
        Case {
            name: "unknown ONNX action_head",
            setup: |dir| {
                let run = run_copy(dir);
                let path = run.join("policy.onnx");
                let mut bytes = std::fs::read(&path).unwrap();
                let head = b"categorical_argmax";
                let at = bytes.windows(head.len()).position(|w| w == head).unwrap();
                bytes[at..at + head.len()].copy_from_slice(b"categorical_sample");
                std::fs::write(&path, bytes).unwrap();
                args(&["eval", "--policy", "run/policy.onnx", "--episodes", "2"])
            },
            code: 2,
            words: &["action_head", "categorical_sample", "categorical_argmax"],
            signal: None,
        },
        // 6. Data that cannot be right.
        Case {
            name: "recording with a coordinate of 1e300",
            setup: |dir| {
                let rec = recording(dir, "HHHHH");
                edit(
                    &rec.join("markers.csv"),
                    "0,0.000000,0.185656,",
                    "0,0.000000,1e300,",
                );
                simulate("HHHHH")
            },
            code: 2,
            words: &["rec/HHHHH/markers.csv:2", "1e300", "plausible"],
            signal: None,
        },
        Case {
            name: "recording without a manifest whose markers stop early",
            setup: |dir| {
                let rec = recording(dir, "HHHHH");
                let path = rec.join("markers.csv");
                let text = std::fs::read_to_string(&path).unwrap();
                let kept: Vec<&str> = text
                    .lines()
                    .filter(|line| !line.starts_with("1411,"))
                    .collect();
                std::fs::write(&path, kept.join("\n") + "\n").unwrap();
                simulate("HHHHH")
            },
            code: 2,
            words: &["rec/HHHHH/markers.csv", "frame 1411 of 1412", "no marker"],
            signal: None,
        },
        Case {
            name: "Motive header rate that contradicts the time column",
            setup: |dir| {
                motive_take(
                    dir,
                    "Export Frame Rate,250.000000",
                    "Export Frame Rate,120.000000",
                )
            },
            code: 2,
            words: &[
                "a30_m0.5_high.csv",
                "line 1",
                "Export Frame Rate",
                "120 Hz",
                "250",
            ],
            signal: None,
        },
        Case {
            name: "manifest with duration_s = nan",
            setup: |dir| dataset_with(dir, &HHHHH_ENTRY.replace("5.8792", "nan")),
            code: 2,
            words: &["rec/manifest.toml", "HHHHH", "`duration_s` = NaN"],
            signal: None,
        },
        Case {
            name: "manifest listing an id twice",
            setup: |dir| dataset_with(dir, &format!("{HHHHH_ENTRY}\n{HHHHH_ENTRY}")),
            code: 2,
            words: &["rec/manifest.toml", "\"HHHHH\" is listed twice"],
            signal: None,
        },
        Case {
            name: "meta.toml id other than its folder",
            setup: |dir| {
                recording(dir, "HHHHM");
                simulate("HHHHM")
            },
            code: 2,
            words: &["rec/HHHHM/meta.toml", "id = \"HHHHH\"", "\"HHHHM\""],
            signal: None,
        },
        Case {
            name: "zero package mass in meta.toml",
            setup: |dir| {
                let rec = recording(dir, "HHHHH");
                edit(
                    &rec.join("meta.toml"),
                    "package_mass_kg = 0.022",
                    "package_mass_kg = 0.0",
                );
                simulate("HHHHH")
            },
            code: 2,
            words: &["rec/HHHHH/meta.toml", "package_mass_kg", "positive"],
            signal: None,
        },
        // 4. Checked before any rollout.
        Case {
            name: "calibration with both loss weights zero",
            setup: |dir| {
                quick_scene(dir);
                calibration_config(dir);
                let config = dir.join("calibrate.toml");
                let text = std::fs::read_to_string(&config).unwrap();
                std::fs::write(&config, text + "\n[loss]\nobject = 0.0\npackage = 0.0\n").unwrap();
                args(&["calibrate", "calibrate.toml"])
            },
            code: 2,
            words: &["calibrate.toml", "`loss`", "at least one weight > 0"],
            signal: None,
        },
        Case {
            name: "calibration bounds beyond the scene's range",
            setup: |dir| {
                quick_scene(dir);
                calibration_config(dir);
                let config = dir.join("calibrate.toml");
                let text = std::fs::read_to_string(&config).unwrap();
                let mu = "\n[[param]]\nname = \"mu_con\"\nlower = 0.0\nupper = 1000.0\n";
                std::fs::write(&config, text + mu).unwrap();
                args(&["calibrate", "calibrate.toml"])
            },
            code: 2,
            words: &[
                "calibrate.toml",
                "`param[1].upper` = 1000",
                "params.mu_con",
                "[0, 100]",
            ],
            signal: None,
        },
        Case {
            name: "--perturb beyond the scene's range",
            setup: |dir| {
                quick_scene(dir);
                args(&[
                    "eval",
                    "--params",
                    "quick.toml",
                    "--data",
                    &dataset(),
                    "--perturb",
                    "100000",
                    "--out",
                    "out",
                ])
            },
            code: 2,
            words: &["--perturb 100000", "params.mu_con", "[0, 100]"],
            signal: None,
        },
        // 8. Messages.
        Case {
            name: "a take file that does not exist",
            setup: |_| {
                let config = repo().join("configs/import/motive.toml");
                args(&[
                    "data",
                    "import-motive",
                    "a30_m0.5_high.csv",
                    "--out",
                    "takes",
                    "--config",
                    &config.display().to_string(),
                ])
            },
            code: 2,
            words: &["a30_m0.5_high.csv", "not found"],
            signal: None,
        },
        Case {
            name: "a negative number for an option that takes one",
            setup: |_| {
                let take = repo().join("data/deformable-sim-real/HHHHH");
                args(&["simulate", &take.display().to_string(), "--seconds", "-1"])
            },
            code: 2,
            words: &["--seconds", "-1"],
            signal: None,
        },
        Case {
            name: "bench sim --envs 0",
            setup: |_| args(&["bench", "sim", "--envs", "0", "--seconds", "0"]),
            code: 2,
            words: &["--envs 0", "cannot read `0`", ">= 1"],
            signal: None,
        },
        Case {
            name: "a run's config.toml changed after training",
            setup: |dir| {
                let run = run_copy(dir);
                edit(
                    &run.join("config.toml"),
                    "learning_rate = 1e-3",
                    "learning_rate = 1e-4",
                );
                args(&["export", "run"])
            },
            code: 2,
            words: &[
                "config.toml",
                "line 20 is `learning_rate = 1e-4`",
                "trained with `learning_rate = 1e-3`",
            ],
            signal: None,
        },
        Case {
            name: "an f32 value echoed as written",
            setup: |dir| {
                quick_scene(dir);
                let path = dir.join("quick.toml");
                let text = std::fs::read_to_string(&path).unwrap();
                let line = text
                    .lines()
                    .find(|l| l.starts_with("soft_mu"))
                    .unwrap()
                    .to_string();
                std::fs::write(&path, text.replace(&line, "soft_mu = -0.1")).unwrap();
                simulate_shipped("quick.toml")
            },
            code: 2,
            words: &["quick.toml", "`contact.soft_mu` = -0.1:"],
            signal: None,
        },
    ]
}

/// `simulate` of the shipped HHHHH for 0.01 s with `params` into `out`.
fn simulate_shipped(params: &str) -> Vec<String> {
    let take = repo().join("data/deformable-sim-real/HHHHH");
    args(&[
        "simulate",
        &take.display().to_string(),
        "--params",
        params,
        "--seconds",
        "0.01",
        "--out",
        "out",
    ])
}

/// `simulate` of the whole shipped HHHHH with `params` into `out`.
fn simulate_shipped_whole(params: &str) -> Vec<String> {
    let take = repo().join("data/deformable-sim-real/HHHHH");
    args(&[
        "simulate",
        &take.display().to_string(),
        "--params",
        params,
        "--out",
        "out",
    ])
}

/// Runs `args` in `dir`, sending `signal` after its delay; the exit code and standard error.
fn run_case(
    args: &[String],
    dir: &Path,
    signal: Option<(&str, Duration)>,
) -> (Option<i32>, String) {
    let mut child = rlpkg(args, dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    if let Some((name, after)) = signal {
        std::thread::sleep(after);
        let sent = Command::new("kill")
            .args([format!("-{name}"), child.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success());
        // The command looks at the request within a chunk of substeps: a bound that only a hang
        // exceeds, whatever the load of the machine.
        let deadline = Instant::now() + Duration::from_secs(30);
        while child.try_wait().unwrap().is_none() {
            if Instant::now() > deadline {
                child.kill().unwrap();
                panic!("rlpkg {args:?} did not stop within 30 s of SIG{name}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let out = child.wait_with_output().unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn bad_input_is_refused_with_its_name_and_leaves_the_folder_as_it_was() {
    let mut failures = Vec::new();
    // With RLPKG_BAD_INPUT_TABLE=<file>, every case as a markdown row.
    let mut table = String::from("| case | command | exit code | message |\n|---|---|---|---|\n");
    for case in cases() {
        let dir = tempfile::tempdir().unwrap();
        let args = (case.setup)(dir.path());
        let before = snapshot(dir.path());
        let (code, stderr) = run_case(&args, dir.path(), case.signal);
        let mut problems = Vec::new();
        if code != Some(case.code) {
            problems.push(format!("exit code {code:?}, expected {}", case.code));
        }
        for word in case.words {
            if !stderr.contains(word) {
                problems.push(format!("message lacks `{word}`"));
            }
        }
        if stderr.contains("panicked") {
            problems.push("panic".into());
        }
        if snapshot(dir.path()) != before {
            problems.push("the folder changed".into());
        }
        let command = args
            .iter()
            .map(|a| a.replace(&repo().display().to_string(), "<repo>"))
            .collect::<Vec<_>>()
            .join(" ");
        let message = stderr
            .lines()
            .filter(|line| line.starts_with("error:"))
            .collect::<Vec<_>>()
            .join(" ");
        table += &format!(
            "| {} | `rlpkg {command}` | {} | {} |\n",
            case.name,
            code.map_or("none".into(), |c| c.to_string()),
            message.replace('|', "\\|")
        );
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n  rlpkg {args:?}\n  stderr: {stderr}",
                case.name,
                problems.join(", ")
            ));
        }
    }
    if let Some(path) = std::env::var_os("RLPKG_BAD_INPUT_TABLE") {
        std::fs::write(path, table).unwrap();
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
