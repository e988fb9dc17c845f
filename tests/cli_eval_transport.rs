//! End-to-end test of `rlpkg eval --policy <file.onnx> --config <file.toml>` on the transport task:
//! the exported file of a tiny sensors-only run gives the same table as the run's checkpoint.

use std::path::Path;
use std::process::Output;

mod common;

use common::ok;

fn rlpkg(args: &[&str], dir: &Path) -> Output {
    common::rlpkg_in(args, dir, None)
}

/// The shipped training config `name`, shrunk: 2 copies on an 11 x 13 grid, 2 s episodes, 2
/// updates, one settled variant.
fn tiny(name: &str) -> String {
    common::tiny_training(name, 16, "2.0")
}

/// The printed table: every line after the first (which names what was evaluated) up to the
/// line naming the plots (their folder differs).
fn table(printed: &str) -> String {
    printed
        .lines()
        .skip(1)
        .take_while(|line| !line.starts_with("plots:"))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn the_exported_transport_policy_evaluates_exactly_as_its_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let config = "transport-sensors.toml";
    std::fs::write(dir.path().join(config), tiny(config)).unwrap();
    ok(&rlpkg(&["train", config, "--quiet"], dir.path()));
    let onnx = "runs/transport-sensors/policy.onnx";
    assert!(dir.path().join(onnx).exists());
    let options = [
        "--episodes",
        "3",
        "--seed",
        "4",
        "--scripted",
        "1.0",
        "--recorded",
        "medium",
    ];
    let mut by_run = vec!["eval", "runs/transport-sensors"];
    by_run.extend(options);
    let from_checkpoint = ok(&rlpkg(&by_run, dir.path()));
    let mut by_file = vec!["eval", "--policy", onnx, "--config", config];
    by_file.extend(options);
    let from_file = ok(&rlpkg(&by_file, dir.path()));
    assert!(
        from_file.starts_with(&format!("{onnx} (exported policy, through tract)")),
        "{from_file}"
    );
    let expected = table(&from_checkpoint);
    assert!(expected.contains("policy") && expected.contains("scripted x1"));
    assert_eq!(
        table(&from_file),
        expected,
        "{from_checkpoint}\n{from_file}"
    );
    // `--set` evaluates the file on a changed configuration: with a 1 s time limit every episode
    // ends by 1 s, so the table changes; a bad value is refused naming the option.
    let mut shorter = by_file.clone();
    shorter.extend(["--set", "transport.time_limit_s=1.0", "--json"]);
    let report: serde_json::Value =
        serde_json::from_str(&ok(&rlpkg(&shorter, dir.path()))).unwrap();
    assert_eq!(report["settled_packages"], 1, "{report}");
    assert!(report["replaced_packages"].as_u64().is_some_and(|n| n <= 1));
    let policy = &report["rows"][0];
    assert_eq!(policy["driver"], "policy");
    assert!(policy["time_to_place_p95_s"]
        .as_f64()
        .is_none_or(|t| t <= 1.0 + 1e-9));
    let scripted = &report["rows"][1];
    assert_eq!(scripted["timed_out_pct"], 100.0, "{report}");
    assert_ne!(
        table(&ok(&rlpkg(&shorter[..shorter.len() - 1], dir.path()))),
        expected
    );
    let mut bad_set = by_file.clone();
    bad_set.extend(["--set", "transport.time_limit_s=-1"]);
    let refused = rlpkg(&bad_set, dir.path());
    assert_eq!(refused.status.code(), Some(2));
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(
        message.contains("--set transport.time_limit_s=-1") && message.contains("time_limit_s"),
        "{message}"
    );
    // A grasp check the scene's own package cannot pass is refused, naming the key.
    let mut strict = by_file.clone();
    strict.extend(["--set", "transport.grasp_min_vacuum_ratio=0.98"]);
    let refused = rlpkg(&strict, dir.path());
    assert_eq!(refused.status.code(), Some(2));
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(message.contains("grasp_min_vacuum_ratio"), "{message}");
    let outputs = dir.path().join("runs/transport-sensors/policy-eval");
    for name in ["summary.json", "episode-0.png", "episode-0.gif"] {
        assert!(outputs.join(name).exists(), "{name}");
    }

    // The privileged task's actor observes other quantities: the file does not fit it.
    std::fs::write(dir.path().join("transport.toml"), tiny("transport.toml")).unwrap();
    let mismatch = rlpkg(
        &["eval", "--policy", onnx, "--config", "transport.toml"],
        dir.path(),
    );
    assert_eq!(mismatch.status.code(), Some(2));
    let message = String::from_utf8_lossy(&mismatch.stderr);
    assert!(
        message.contains(onnx) && message.contains("obs_names"),
        "{message}"
    );
    // Without its settings the transport file cannot be evaluated.
    let bare = rlpkg(&["eval", "--policy", onnx], dir.path());
    assert_eq!(bare.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bare.stderr).contains("--config"));
    // A sensors table without observation = "sensors" names the key.
    let text = tiny(config).replace("observation = \"sensors\"", "");
    std::fs::write(dir.path().join("bad.toml"), text).unwrap();
    let bad = rlpkg(&["train", "bad.toml", "--quiet"], dir.path());
    assert_eq!(bad.status.code(), Some(2));
    let message = String::from_utf8_lossy(&bad.stderr);
    assert!(message.contains("transport.sensors"), "{message}");
}

#[test]
fn profile_rows_join_the_table_and_bad_scales_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let config = "transport.toml";
    std::fs::write(dir.path().join(config), tiny(config)).unwrap();
    ok(&rlpkg(&["train", config, "--quiet"], dir.path()));
    let run = "runs/transport";
    let base = [
        "eval",
        run,
        "--episodes",
        "2",
        "--seed",
        "3",
        "--scripted",
        "1.0",
        "--recorded",
        "none",
    ];
    let without = ok(&rlpkg(&base, dir.path()));
    let summary = dir.path().join(run).join("eval/summary.json");
    let plain: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    assert!(plain.get("profile").is_none(), "{plain}");
    let mut with_profile = base.to_vec();
    with_profile.extend(["--profile", "0.5,1", "--json"]);
    let output = rlpkg(&with_profile, dir.path());
    let report: serde_json::Value = serde_json::from_str(&ok(&output)).unwrap();
    let printed = String::from_utf8_lossy(&output.stderr).into_owned();
    // The policy and scripted rows are unchanged; one row per scale follows them.
    let printed_table = table(&printed);
    let rows: Vec<&str> = printed_table.lines().map(str::trim_end).collect();
    for line in table(&without).lines() {
        assert!(rows.contains(&line.trim_end()), "{line}\n{printed}");
    }
    for driver in ["profile x0.5", "profile x1"] {
        assert!(
            rows.iter().any(|r| r.starts_with(&format!("{driver} "))),
            "{driver}\n{printed}"
        );
    }
    let drivers: Vec<&str> = report["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["driver"].as_str().unwrap())
        .collect();
    assert_eq!(
        drivers,
        ["policy", "scripted x1", "profile x0.5", "profile x1"]
    );
    assert_eq!(report["rows"][2]["episodes"], 2);
    // episodes.csv: each driver's episodes, their endings adding up to the table's shares.
    let csv = std::fs::read_to_string(dir.path().join(run).join("eval/episodes.csv")).unwrap();
    let lines: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(lines.len(), 1 + drivers.len() * 2, "{csv}");
    let ending = lines[0].iter().position(|&c| c == "ending").unwrap();
    for (k, driver) in drivers.iter().enumerate() {
        let mine: Vec<&Vec<&str>> = lines[1..]
            .iter()
            .filter(|l| l[0] == format!("\"{driver}\""))
            .collect();
        assert_eq!(mine.len(), 2, "{driver}\n{csv}");
        let placed = mine.iter().filter(|l| l[ending] == "success").count();
        assert_eq!(
            report["rows"][k]["success_pct"].as_f64().unwrap(),
            50.0 * placed as f64,
            "{driver}\n{csv}"
        );
    }
    // Scale 1 stands for the tool's own limits of [transport.limits].
    let limits = &report["profile"]["base_limits"];
    assert_eq!(limits["speed_m_s"], 0.945, "{report}");
    assert_eq!(limits["angular_accel_rad_s2"], 10.0, "{report}");

    for bad in ["0", "-1", "NaN", "10.5", "0.5,0"] {
        let flag = format!("--profile={bad}");
        let mut args = base.to_vec();
        args.push(&flag);
        let refused = rlpkg(&args, dir.path());
        assert_eq!(refused.status.code(), Some(2), "{bad}");
        let message = String::from_utf8_lossy(&refused.stderr);
        assert!(message.contains("--profile"), "{bad}: {message}");
    }
}
