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
        "--json",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let rows: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let rows = rows.as_array().expect("a JSON array");
    assert_eq!(rows.len(), 2);
    for (row, envs) in rows.iter().zip([1, 3]) {
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
