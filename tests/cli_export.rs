//! End-to-end tests of `rlpkg export` through the binary.

use std::process::Command;

fn rlpkg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

#[test]
fn help_describes_the_options() {
    let out = rlpkg(&["export", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for word in [
        "--out",
        "--with-value",
        "--check-data",
        "--latency",
        "runs/<name>",
    ] {
        assert!(help.contains(word), "help lacks {word}:\n{help}");
    }
}

#[test]
fn missing_run_folder_exits_with_2_and_names_it() {
    let out = rlpkg(&["export", "runs/does-not-exist-42"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("runs/does-not-exist-42") && err.contains("run folder"),
        "{err}"
    );
}

#[test]
fn a_file_is_not_a_run_folder() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("policy.onnx");
    std::fs::write(&file, b"x").unwrap();
    let out = rlpkg(&["export", file.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("policy.onnx"));
}

#[test]
fn zero_verification_rows_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let out = rlpkg(&["export", dir.path().to_str().unwrap(), "--verify", "0"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--verify"));
}

/// Trains one PPO update on Pendulum (seconds), exports the run and evaluates the file; when
/// `RLPKG_ONNX_CHECK_DIR` is set (CI), the exported file and its check data go there for
/// `tests/onnx_check.py`.
#[test]
fn trained_run_exports_a_file_that_matches_burn_and_evaluates() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/train/pendulum.toml");
    let train = rlpkg(&[
        "train",
        config,
        "--out-dir",
        runs.to_str().unwrap(),
        "--name",
        "pendulum",
        "--stop-after",
        "1",
        "--quiet",
        "--no-export",
    ]);
    assert!(
        train.status.success(),
        "{}",
        String::from_utf8_lossy(&train.stderr)
    );

    let out_dir = match std::env::var_os("RLPKG_ONNX_CHECK_DIR") {
        Some(d) => std::path::PathBuf::from(d),
        None => dir.path().to_path_buf(),
    };
    std::fs::create_dir_all(&out_dir).unwrap();
    let model = out_dir.join("pendulum_trained.onnx");
    let run = runs.join("pendulum");
    let export = rlpkg(&[
        "export",
        run.to_str().unwrap(),
        "--out",
        model.to_str().unwrap(),
        "--with-value",
        "--check-data",
        "--latency",
        "200",
        "--json",
    ]);
    assert!(
        export.status.success(),
        "{}",
        String::from_utf8_lossy(&export.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&export.stdout).unwrap();
    println!("{summary:#}");
    assert_eq!(summary["env_id"], "Pendulum-v1");
    assert_eq!(
        summary["bytes"].as_u64().unwrap(),
        std::fs::metadata(&model).unwrap().len()
    );
    assert!(summary["max_abs_diff"].as_f64().unwrap() <= 1e-5);
    let burn = &summary["burn"];
    assert_eq!(burn["random_rows"], 1000);
    assert_eq!(burn["visited_rows"], 1000);
    assert!(burn["random_max_abs_diff"].as_f64().unwrap() <= 1e-5);
    assert!(burn["visited_max_abs_diff"].as_f64().unwrap() <= 1e-5);
    assert!(model.with_extension("check.json").is_file());
    assert!(summary["latency_us"]["median"].as_f64().unwrap() > 0.0);

    let eval = rlpkg(&[
        "eval",
        "--policy",
        model.to_str().unwrap(),
        "--episodes",
        "3",
        "--json",
    ]);
    assert!(
        eval.status.success(),
        "{}",
        String::from_utf8_lossy(&eval.stderr)
    );
    let eval: serde_json::Value = serde_json::from_slice(&eval.stdout).unwrap();
    assert_eq!(eval["episodes"], 3);
    // Pendulum pays at most 0 per step and runs 200 steps.
    assert_eq!(eval["mean_length"], 200.0);
    assert!(eval["mean_return"].as_f64().unwrap() <= 0.0);

    let garbage = dir.path().join("garbage.onnx");
    std::fs::write(&garbage, b"not a model").unwrap();
    let bad = rlpkg(&["eval", "--policy", garbage.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("garbage.onnx"));
}
