//! End-to-end tests of `rlpkg bench sim` through the binary.

use std::process::Command;

fn rlpkg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

#[test]
fn bench_sim_prints_json_rows_with_positive_throughput() {
    let out = rlpkg(&[
        "bench",
        "sim",
        "--grid",
        "6x7",
        "--envs",
        "1,3",
        "--seconds",
        "0.1",
        "--workload",
        "motionless",
        "--scene",
        "reference,physical",
        "--json",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let rows: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let rows = rows.as_array().expect("a JSON array");
    // Both scenes in the same run, one after the other.
    assert_eq!(rows.len(), 4);
    let scenes = ["reference", "reference", "physical", "physical"];
    for ((row, envs), scene) in rows.iter().zip([1, 3, 1, 3]).zip(scenes) {
        assert_eq!(row["scene"], scene);
        assert_eq!(row["envs"], envs);
        // 2 layers x 6 x 7 package particles + 4 cups x 24 ring particles.
        assert_eq!(row["particles"], 2 * 6 * 7 + 96);
        assert!(row["particle_substeps_per_s"].as_f64().unwrap() > 0.0);
        assert!(row["real_time_factor_per_env"].as_f64().unwrap() > 0.0);
    }
    assert!(
        stderr.contains("particle-ss/s"),
        "the table goes to stderr with --json: {stderr}"
    );
}

#[test]
fn bench_sim_rejects_a_malformed_grid_with_exit_code_2() {
    let out = rlpkg(&["bench", "sim", "--grid", "5", "--seconds", "0.1"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--grid"), "{stderr}");
}

#[test]
fn bench_sim_runs_every_workload_side_by_side() {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/data/deformable-sim-real");
    let out = rlpkg(&[
        "bench",
        "sim",
        "--grid",
        "11x13",
        "--envs",
        "1,3",
        "--seconds",
        "0.2",
        "--data",
        data,
        "--seed",
        "4",
        "--json",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let rows: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let rows = rows.as_array().expect("a JSON array");
    let expected = [
        ("motionless", 1),
        ("replay", 1),
        ("command", 1),
        ("motionless", 3),
        ("replay", 3),
        ("command", 3),
    ];
    assert_eq!(rows.len(), expected.len());
    for (row, (workload, envs)) in rows.iter().zip(expected) {
        assert_eq!(row["workload"], workload);
        assert_eq!(row["envs"], envs);
        assert_eq!(row["particles"], 2 * 11 * 13 + 96);
        assert_eq!(row["frozen_envs"], 0, "{row}");
        let simulated = row["simulated_s_per_wall_s"].as_f64().unwrap();
        let total = row["real_time_factor_per_env"].as_f64().unwrap() * envs as f64;
        assert!(
            simulated > 0.0 && (simulated - total).abs() <= 1e-9 * total,
            "{row}"
        );
        // Only the command workload commands the tools, within the limits.
        let commands = row["commands"].as_u64().unwrap();
        assert_eq!(commands > 0, workload == "command", "{row}");
        assert_eq!(row["clamped_commands"], 0);
    }
    for workload in ["motionless", "replay", "command"] {
        assert!(stderr.contains(workload), "{stderr}");
    }
}

#[test]
fn bench_sim_rejects_an_unknown_workload_and_a_missing_dataset_with_exit_code_2() {
    let out = rlpkg(&["bench", "sim", "--workload", "moving", "--seconds", "0"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--workload") && stderr.contains("moving"),
        "{stderr}"
    );
    let out = rlpkg(&[
        "bench",
        "sim",
        "--workload",
        "replay",
        "--data",
        "no/such/dataset",
        "--seconds",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no/such/dataset"), "{stderr}");
}

#[test]
fn bench_ppo_prints_throughput_and_phase_shares_per_backend() {
    let out = rlpkg(&[
        "bench",
        "ppo",
        "--backend",
        "flex,ndarray",
        "--minibatch",
        "64",
        "--minibatches",
        "2",
        "--obs-dim",
        "5",
        "--action-dim",
        "2",
        "--hidden",
        "16,8",
        "--env-steps",
        "0",
        "--json",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let updates = json["ppo_update"].as_array().expect("ppo_update rows");
    let backends: Vec<&str> = updates
        .iter()
        .map(|row| row["backend"].as_str().unwrap())
        .collect();
    assert_eq!(backends, ["flex", "ndarray"]);
    for row in updates {
        // A 5-16-8-2 actor, a 5-16-8-1 critic and two log-stds.
        let actor = (5 * 16 + 16) + (16 * 8 + 8) + (8 * 2 + 2);
        let critic = (5 * 16 + 16) + (16 * 8 + 8) + (8 + 1);
        assert_eq!(row["parameters"], actor + critic + 2);
        assert!(row["samples_per_second"].as_f64().unwrap() > 0.0);
        let shares = &row["shares"];
        let sum: f64 = ["batch", "forward", "backward", "optimiser"]
            .iter()
            .map(|k| shares[k].as_f64().unwrap())
            .sum();
        assert!(sum > 0.5 && sum <= 1.0 + 1e-9, "{shares}");
        assert!(shares["backward"].as_f64().unwrap() > 0.0);
    }
    // Three layer products per backend.
    assert_eq!(json["matmul"].as_array().unwrap().len(), 6);
    assert!(json["matmul"][0]["gflops"].as_f64().unwrap() > 0.0);
}

#[test]
fn bench_ppo_rejects_an_unknown_backend_with_exit_code_2() {
    let out = rlpkg(&["bench", "ppo", "--backend", "cuda", "--env-steps", "0"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--backend cuda"), "{stderr}");
}
