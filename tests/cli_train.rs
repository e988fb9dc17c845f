//! End-to-end tests of `rlpkg train` and `rlpkg eval <run>` on tiny configurations.

use std::path::Path;
use std::process::Output;

const TINY_CARTPOLE: &str = r#"
[run]
env = "CartPole-v1"
num_envs = 4
seed = 3
total_steps = 1024
checkpoint_every = 1

[ppo]
rollout_steps = 64
epochs = 2
minibatches = 2
gamma = 0.99
gae_lambda = 0.95
clip_ratio = 0.2
clip_value_loss = true
value_coef = 0.5
entropy_coef = 0.01
max_grad_norm = 0.5
learning_rate = 1e-3
lr_schedule = "linear"
desired_kl = 0.01
normalize_advantages = true
adam_epsilon = 1e-5

[policy]
actor_hidden = [16, 16]
critic_hidden = [16, 16]
activation = "tanh"
init_log_std = 0.0
action_transform = "clip"

[normalization]
observations = true
rewards = true
clip_obs = 10.0
clip_reward = 10.0
epsilon = 1e-8
"#;

mod common;

use common::ok;

fn rlpkg(args: &[&str], dir: &Path) -> Output {
    common::rlpkg_in(args, dir, None)
}

/// The stderr of `rlpkg args` in `dir`, which must exit with 2 (bad input).
fn refused(args: &[&str], dir: &Path) -> String {
    let out = rlpkg(args, dir);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    stderr
}

fn eval_json(dir: &Path, run: &str) -> serde_json::Value {
    let out = ok(&rlpkg(&["eval", run, "--episodes", "5", "--json"], dir));
    serde_json::from_str(&out).expect("eval --json prints JSON")
}

#[test]
fn train_eval_and_resume() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();

    // An uninterrupted run: config copied, checkpoint, TensorBoard events, ONNX export.
    let out = ok(&rlpkg(&["train", "tiny.toml", "--quiet"], dir.path()));
    assert!(out.contains("4 / 4 updates"), "{out}");
    let run = dir.path().join("runs/tiny");
    assert_eq!(
        std::fs::read_to_string(run.join("config.toml")).unwrap(),
        TINY_CARTPOLE
    );
    assert!(run.join("checkpoints/latest").exists());
    assert!(run.join("policy.onnx").exists());
    let events = std::fs::read_dir(&run)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .contains("tfevents")
        })
        .count();
    assert!(events >= 1);
    // The wall-time shares of the update and the environment are logged under perf/.
    let event_bytes: Vec<u8> = std::fs::read_dir(&run)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("tfevents"))
        .flat_map(|p| std::fs::read(p).unwrap())
        .collect();
    for tag in ["perf/update_share", "perf/env_step_share"] {
        assert!(
            event_bytes.windows(tag.len()).any(|w| w == tag.as_bytes()),
            "{tag} missing from the TensorBoard events"
        );
    }

    let summary = eval_json(dir.path(), "runs/tiny");
    assert_eq!(summary["env_id"], "CartPole-v1");
    assert_eq!(summary["episodes"], 5);
    assert_eq!(summary["update"], 4);
    let mean = summary["mean_return"].as_f64().unwrap();
    assert!((8.0..=500.0).contains(&mean), "{mean}");
    let text = ok(&rlpkg(
        &["eval", "runs/tiny", "--episodes", "5"],
        dir.path(),
    ));
    assert!(text.contains("+-"), "{text}");

    // Interrupted after 2 updates, then resumed: the same policy as the uninterrupted run.
    ok(&rlpkg(
        &[
            "train",
            "tiny.toml",
            "--name",
            "split",
            "--stop-after",
            "2",
            "--quiet",
        ],
        dir.path(),
    ));
    assert_eq!(eval_json(dir.path(), "runs/split")["update"], 2);
    // What a second Ctrl-C (an immediate exit) can leave: an unfinished checkpoint folder and the
    // temporary copies of `latest`, `config.toml` and `policy.onnx`. The resume removes them and
    // nothing else.
    let split = dir.path().join("runs/split");
    let leftovers = [
        "checkpoints/.partial-Ab3dE9",
        "checkpoints/.latest.Xy12Zw",
        ".config.toml.Qw34Er",
        ".policy.onnx.Zx56Cv",
    ];
    std::fs::create_dir(split.join(leftovers[0])).unwrap();
    std::fs::write(split.join(leftovers[0]).join("state.json"), "{").unwrap();
    for file in &leftovers[1..] {
        std::fs::write(split.join(file), "half").unwrap();
    }
    let kept = ["notes.txt", ".config.toml.orig", "checkpoints/.latest.bak"];
    for file in kept {
        std::fs::write(split.join(file), "mine").unwrap();
    }
    let resumed = rlpkg(
        &["train", "--resume", "runs/split", "--quiet", "--no-export"],
        dir.path(),
    );
    let out = ok(&resumed);
    assert!(out.contains("4 / 4 updates"), "{out}");
    for file in leftovers {
        assert!(!split.join(file).exists(), "{file} left behind");
    }
    for file in kept {
        assert!(split.join(file).exists(), "{file} removed");
    }
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    assert!(
        stderr.contains("removed the leftover temporary") && stderr.contains(".partial-Ab3dE9"),
        "{stderr}"
    );
    assert_eq!(eval_json(dir.path(), "runs/split"), summary);
    // TensorBoard sees every update once, in order, from the one event file of the run.
    let events: Vec<_> = std::fs::read_dir(dir.path().join("runs/split"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("tfevents"))
        .collect();
    assert_eq!(events.len(), 1, "{events:?}");
    let scalars = rlpkg_agents::runners::read_scalars(&events[0]).unwrap();
    let steps: Vec<i64> = scalars
        .iter()
        .filter(|e| e.tag == "losses/policy_loss")
        .map(|e| e.step)
        .collect();
    assert_eq!(steps, [256, 512, 768, 1024]);

    // The same name again is refused (input error).
    let again = rlpkg(&["train", "tiny.toml", "--quiet"], dir.path());
    assert_eq!(again.status.code(), Some(2));
}

#[test]
fn bad_configs_and_run_folders_exit_with_code_2() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("gamma = 0.99", "gamma = 2.0", "ppo.gamma"),
        ("seed = 3", "seed = 3\nsed = 4", "sed"),
        ("epochs = 2", "epochs = \"two\"", "epochs"),
        ("minibatches = 2", "minibatches = 7", "ppo.minibatches"),
    ];
    for (i, (from, to, key)) in cases.iter().enumerate() {
        let file = format!("bad{i}.toml");
        std::fs::write(dir.path().join(&file), TINY_CARTPOLE.replace(from, to)).unwrap();
        let out = rlpkg(&["train", &file, "--quiet"], dir.path());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(&file) && stderr.contains(key), "{stderr}");
        assert!(!dir.path().join("runs").join(format!("bad{i}")).exists());
    }
    let missing = rlpkg(&["train", "missing.toml"], dir.path());
    assert_eq!(missing.status.code(), Some(2));
    let not_a_run = rlpkg(&["eval", "nowhere"], dir.path());
    assert_eq!(not_a_run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&not_a_run.stderr).contains("not a run folder"));
}

#[test]
fn set_overrides_are_stored_in_the_run_and_bad_ones_exit_with_code_2() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();
    let args = [
        "train",
        "tiny.toml",
        "--name",
        "lr",
        "--quiet",
        "--no-export",
        "--stop-after",
        "1",
        "--set",
        "ppo.learning_rate=1e-4",
        "--set",
        "run.seed=7",
    ];
    let out = rlpkg(&args, dir.path());
    // --stop-after ends the run early on purpose (exit 0 or the interrupted code).
    let stored = std::fs::read_to_string(dir.path().join("runs/lr/config.toml"))
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stderr)));
    let table: toml::Table = stored.parse().unwrap();
    assert_eq!(table["ppo"]["learning_rate"].as_float(), Some(1e-4));
    assert_eq!(table["run"]["seed"].as_integer(), Some(7));
    assert_eq!(table["ppo"]["epochs"].as_integer(), Some(2));
    assert!(stored.starts_with("# tiny.toml --set ppo.learning_rate=1e-4 --set run.seed=7\n"));
    for (set, key) in [
        ("ppo.gamma=2.0", "--set ppo.gamma=2.0"),
        ("ppo.lerning_rate=1e-4", "--set ppo.lerning_rate=1e-4"),
        ("run.seed=abc", "--set run.seed=abc"),
        ("ppo=3", "--set ppo=3"),
        ("ppo.gamma", "--set"),
    ] {
        let out = rlpkg(
            &[
                "train",
                "tiny.toml",
                "--name",
                "bad",
                "--quiet",
                "--set",
                set,
            ],
            dir.path(),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{set}: {stderr}");
        assert!(stderr.contains(key), "{set}: {stderr}");
        assert!(!dir.path().join("runs/bad").exists(), "{set}");
    }
    // A value of the wrong type is named by its key: the merged text's line numbers are not the
    // file's, so none is given.
    let stderr = refused(
        &[
            "train",
            "tiny.toml",
            "--name",
            "bad",
            "--set",
            "ppo.learning_rate=\"abc\"",
        ],
        dir.path(),
    );
    assert!(
        stderr.contains("key `ppo.learning_rate`") && !stderr.contains("line"),
        "{stderr}"
    );
}

#[test]
fn a_config_that_extends_another_runs_as_the_merged_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();
    std::fs::create_dir(dir.path().join("jobs")).unwrap();
    let job = "extends = \"../tiny.toml\"\n[run]\nseed = 7\n[ppo]\nlearning_rate = 1e-4\n";
    std::fs::write(dir.path().join("jobs/job.toml"), job).unwrap();
    let train = [
        "train",
        "jobs/job.toml",
        "--name",
        "ext",
        "--quiet",
        "--no-export",
    ];
    let out = rlpkg(&[&train[..], &["--stop-after", "1"]].concat(), dir.path());
    let stored_path = dir.path().join("runs/ext/config.toml");
    let stored = std::fs::read_to_string(&stored_path)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stderr)));
    // The run keeps the merged configuration, which names no base.
    let table: toml::Table = stored.parse().unwrap();
    assert!(!table.contains_key("extends"), "{stored}");
    assert_eq!(table["run"]["seed"].as_integer(), Some(7));
    assert_eq!(table["ppo"]["learning_rate"].as_float(), Some(1e-4));
    assert_eq!(table["ppo"]["epochs"].as_integer(), Some(2));
    assert!(stored.starts_with("# jobs/job.toml, merged with its bases (jobs/../tiny.toml)"));
    // So a base edited later changes neither the resumed run nor what it stores.
    common::edit(&dir.path().join("tiny.toml"), "epochs = 2", "epochs = 3");
    ok(&rlpkg(
        &["train", "--resume", "runs/ext", "--quiet", "--no-export"],
        dir.path(),
    ));
    assert_eq!(std::fs::read_to_string(&stored_path).unwrap(), stored);

    // A bad chain or a bad value in it: exit 2, the file and the key named, nothing written.
    for (text, expected) in [
        (
            "extends = \"nowhere.toml\"\n",
            "jobs/bad.toml: key `extends` = \"nowhere.toml\"",
        ),
        (
            "extends = [\"../tiny.toml\"]\n",
            "key `extends` = [\"../tiny.toml\"]: expected the path",
        ),
        ("extends = \"bad.toml\"\n", "already in the chain"),
        (
            "extends = \"../tiny.toml\"\n[ppo]\nlearning_rate = \"abc\"\n",
            "key `ppo.learning_rate`",
        ),
    ] {
        std::fs::write(dir.path().join("jobs/bad.toml"), text).unwrap();
        let stderr = refused(&["train", "jobs/bad.toml", "--name", "bad"], dir.path());
        assert!(stderr.contains(expected), "{text}: {stderr}");
        assert!(!dir.path().join("runs/bad").exists(), "{text}");
    }
    let stderr = refused(&["train", "jobs/bad.toml", "--name", "bad"], dir.path());
    assert!(stderr.contains("extending jobs/../tiny.toml"), "{stderr}");
}

#[test]
fn transport_trains_on_the_shipped_posterior_draws() {
    // The shipped posterior configs shrunk, reading their draws from data/posteriors: the loader
    // checks them against the calibration their summary.json names (a path from the working
    // directory, hence the link to the repository's configs).
    let root = env!("CARGO_MANIFEST_DIR");
    for (name, posterior) in [
        ("transport-posterior.toml", "coarse-soft-film"),
        ("transport-sensors-posterior.toml", "real-film-sampled"),
    ] {
        let text = common::tiny_training(name, 16, "2.0").replace(
            "posterior = \"data/",
            &format!("posterior = \"{root}/data/"),
        );
        let key = format!("posterior = \"{root}/data/posteriors/{posterior}\"");
        assert!(text.contains(&key), "{name}");
        let dir = tempfile::tempdir().unwrap();
        std::os::unix::fs::symlink(format!("{root}/configs"), dir.path().join("configs")).unwrap();
        std::fs::write(dir.path().join(name), text).unwrap();
        let out = ok(&rlpkg(&["train", name, "--no-export"], dir.path()));
        assert!(out.contains("settled packages: 1, "), "{name}: {out}");
        let run = name.trim_end_matches(".toml");
        let stored =
            std::fs::read_to_string(dir.path().join(format!("runs/{run}/config.toml"))).unwrap();
        assert!(stored.contains(&key), "{name}: {stored}");
    }
}

#[test]
fn an_input_edited_after_training_stops_a_resume_and_is_named_by_eval() {
    // The transport task on a copy of its scene: the run records what its config names.
    let root = env!("CARGO_MANIFEST_DIR");
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::copy(
        format!("{root}/configs/scenes/calibrated-coarse-soft-film.toml"),
        &scene,
    )
    .unwrap();
    let text = common::tiny_training("transport.toml", 32, "2.0").replace(
        &format!("scene = \"{root}/configs/scenes/calibrated-coarse-soft-film.toml\""),
        "scene = \"scene.toml\"",
    );
    assert!(text.contains("scene = \"scene.toml\""));
    std::fs::write(dir.path().join("transport.toml"), text).unwrap();
    ok(&rlpkg(
        &[
            "train",
            "transport.toml",
            "--quiet",
            "--no-export",
            "--stop-after",
            "1",
        ],
        dir.path(),
    ));
    let inputs = std::fs::read_to_string(dir.path().join("runs/transport/inputs.toml")).unwrap();
    assert!(
        inputs.contains("scene.toml") && inputs.contains("deformable-sim-real"),
        "{inputs}"
    );
    let original = std::fs::read_to_string(&scene).unwrap();
    let edited = original.replacen("mu_con = ", "mu_con = 2.5 # was ", 1);
    assert_ne!(edited, original);
    std::fs::write(&scene, edited).unwrap();
    let stderr = refused(
        &[
            "train",
            "--resume",
            "runs/transport",
            "--quiet",
            "--no-export",
        ],
        dir.path(),
    );
    assert!(
        stderr.contains("scene.toml") && stderr.contains("changed since the run was created"),
        "{stderr}"
    );
    let eval = rlpkg(&["eval", "runs/transport", "--episodes", "1"], dir.path());
    let stderr = String::from_utf8_lossy(&eval.stderr);
    assert!(eval.status.success(), "{stderr}");
    assert!(
        stderr.contains("note: scene.toml changed since runs/transport was trained"),
        "{stderr}"
    );
    // Put back, the run goes on.
    std::fs::write(&scene, original).unwrap();
    ok(&rlpkg(
        &[
            "train",
            "--resume",
            "runs/transport",
            "--quiet",
            "--no-export",
        ],
        dir.path(),
    ));
}

#[test]
fn transport_run_is_evaluated_beside_the_scripted_baseline() {
    // The shipped transport config, shrunk: 2 copies on an 11 x 13 grid, 2 s episodes, 2 updates.
    let text = common::tiny_training("transport.toml", 16, "2.0");
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("transport.toml"), text).unwrap();
    ok(&rlpkg(
        &["train", "transport.toml", "--quiet", "--no-export"],
        dir.path(),
    ));
    let out = ok(&rlpkg(
        &[
            "eval",
            "runs/transport",
            "--episodes",
            "2",
            "--scripted",
            "1.0,1.5",
            "--recorded",
            "medium",
            "--trajectories",
            "test",
            "--json",
        ],
        dir.path(),
    ));
    let report: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    let rows = report["rows"].as_array().expect("rows");
    let drivers: Vec<&str> = rows.iter().map(|r| r["driver"].as_str().unwrap()).collect();
    assert_eq!(
        drivers,
        ["policy", "scripted x1", "scripted x1.5", "recorded medium"]
    );
    // The recorded baseline plays the medium-velocity recording of each path's tilt level.
    let timings = report["recorded"][0]["timings"]
        .as_array()
        .expect("timings");
    assert_eq!(timings[1], serde_json::json!(["HHHHM", "HHHMM"]));
    // Each held-out recording's own conditions: the policy and the recording's own timing, one
    // episode each, and a plot per recording beside the randomised episode 0's.
    let held_out: Vec<&str> = report["trajectories"]
        .as_array()
        .expect("trajectories")
        .iter()
        .map(|r| r["driver"].as_str().unwrap())
        .collect();
    assert_eq!(
        held_out,
        [
            "HHHMM policy",
            "HHHMM recorded",
            "HHLMM policy",
            "HHLMM recorded",
            "HHMMM policy",
            "HHMMM recorded"
        ]
    );
    for name in [
        "episode-0.png",
        "episode-0.gif",
        "episode-0-end.png",
        "HHHMM.png",
        "HHLMM.png",
        "HHMMM.png",
    ] {
        let plot = dir.path().join("runs/transport/eval").join(name);
        assert!(std::fs::metadata(&plot).unwrap().len() > 10_000, "{plot:?}");
    }
    for row in rows {
        assert_eq!(row["episodes"], 2);
        let total: f64 = [
            "success_pct",
            "cup_detached_pct",
            "dropped_pct",
            "unhealthy_pct",
            "timed_out_pct",
        ]
        .iter()
        .map(|k| row[k].as_f64().unwrap())
        .sum();
        assert!((total - 100.0).abs() < 1e-9, "{row}");
    }
    // A bad time scale is a user error.
    let bad = rlpkg(&["eval", "runs/transport", "--scripted", "0"], dir.path());
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--scripted"));
    let bad = rlpkg(
        &["eval", "runs/transport", "--trajectories", "heldout"],
        dir.path(),
    );
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--trajectories heldout"));
    let bad = rlpkg(
        &["eval", "runs/transport", "--recorded", "fast"],
        dir.path(),
    );
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--recorded fast"));
}

/// Every file under `dir` with its bytes.
fn files_under(dir: &Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    let mut files = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files.extend(files_under(&path));
        } else {
            files.insert(path.clone(), std::fs::read(&path).unwrap());
        }
    }
    files
}

/// The id of a process that has ended and been waited for: no process runs under it.
fn ended_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn a_run_in_use_is_refused_and_a_stale_lock_is_taken_over() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();
    ok(&rlpkg(
        &[
            "train",
            "tiny.toml",
            "--stop-after",
            "2",
            "--quiet",
            "--no-export",
        ],
        dir.path(),
    ));
    let run = dir.path().join("runs/tiny");
    let lock = run.join(".lock");
    assert!(!lock.exists(), "the lock outlived a finished command");

    // Another command trains the run: a process that runs, its id in the lock file, and the
    // temporary file of a write it has under way.
    let mut holder = std::process::Command::new("sleep")
        .arg("60")
        .spawn()
        .unwrap();
    std::fs::write(&lock, format!("{}\n", holder.id())).unwrap();
    let writing = run.join(".config.toml.Ab12Cd");
    std::fs::write(&writing, "being written").unwrap();
    let before = files_under(&run);
    for args in [
        &["train", "--resume", "runs/tiny", "--quiet"][..],
        &["train", "tiny.toml", "--quiet"][..],
    ] {
        let refused = rlpkg(args, dir.path());
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains(&format!("runs/tiny: in use by process {}", holder.id()))
                && stderr.contains("runs/tiny/.lock"),
            "{args:?}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
        // Nothing of the holder's is touched: not its lock, not its temporary file.
        assert_eq!(files_under(&run), before, "{args:?}");
    }
    holder.kill().unwrap();
    holder.wait().unwrap();

    // The holder has ended: its lock is stale, taken over with a notice, and its temporary file
    // is now a leftover.
    let resumed = rlpkg(
        &["train", "--resume", "runs/tiny", "--quiet", "--no-export"],
        dir.path(),
    );
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    ok(&resumed);
    assert!(
        stderr.contains(&format!(
            "took over the stale lock runs/tiny/.lock of process {}, which no longer runs",
            holder.id()
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains("removed the leftover temporary"),
        "{stderr}"
    );
    assert!(!writing.exists());
    assert!(!lock.exists(), "the lock outlived a finished command");
    assert_eq!(eval_json(dir.path(), "runs/tiny")["update"], 4);

    // A lock left by a process that ended long ago, on a run that is not there yet: taken over,
    // and removed at the end of the new run (also when the command fails).
    let fresh = dir.path().join("runs/fresh");
    std::fs::create_dir_all(&fresh).unwrap();
    std::fs::write(fresh.join(".lock"), format!("{}\n", ended_pid())).unwrap();
    let failed = rlpkg(
        &[
            "train",
            "tiny.toml",
            "--name",
            "fresh",
            "--set",
            "ppo.gama=0.9",
        ],
        dir.path(),
    );
    assert_eq!(
        failed.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&failed.stderr)
    );
    assert!(
        fresh.join(".lock").exists(),
        "a refused config touches no folder"
    );
    ok(&rlpkg(
        &[
            "train",
            "tiny.toml",
            "--name",
            "fresh",
            "--quiet",
            "--no-export",
        ],
        dir.path(),
    ));
    assert!(!fresh.join(".lock").exists());
    assert!(fresh.join("checkpoints/latest").exists());
}

/// Starts `rlpkg train` of a long CartPole run in `dir` and waits until it has checkpointed its
/// first update (it then holds its lock and stops at a signal after an update).
fn long_training(dir: &Path) -> std::process::Child {
    std::fs::write(
        dir.join("long.toml"),
        TINY_CARTPOLE.replace("total_steps = 1024", "total_steps = 10240000"),
    )
    .unwrap();
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(["train", "long.toml", "--quiet", "--no-export"])
        .current_dir(dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !dir.join("runs/long/checkpoints/latest").exists() {
        assert!(
            std::time::Instant::now() < deadline,
            "no checkpoint within 120 s"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(dir.join("runs/long/.lock").exists());
    child
}

fn send(signal: &str, child: &std::process::Child) {
    let sent = std::process::Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

#[test]
fn ctrl_c_removes_the_lock_also_when_it_ends_the_process_at_once() {
    // One signal: training stops after the current update and the command returns.
    let dir = tempfile::tempdir().unwrap();
    let child = long_training(dir.path());
    send("INT", &child);
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!dir.path().join("runs/long/.lock").exists());

    // Two signals: the second ends the process at once, skipping every destructor.
    let dir = tempfile::tempdir().unwrap();
    let child = long_training(dir.path());
    send("INT", &child);
    send("INT", &child);
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130));
    assert!(!dir.path().join("runs/long/.lock").exists());
    // The next command finds the folder free (its --stop-after is refused only after the lock).
    let stderr = refused(
        &[
            "train",
            "--resume",
            "runs/long",
            "--stop-after",
            "1",
            "--quiet",
        ],
        dir.path(),
    );
    assert!(
        stderr.contains("is already at update") && !stderr.contains("lock"),
        "{stderr}"
    );
}
