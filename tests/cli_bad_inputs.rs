//! Bad inputs through the binary, one table: configurations, run folders and checkpoints, output
//! folders and sizes. Each case must exit with code 2, print a message that names the file, key or
//! option (and line where there is one), never panic, and leave the folder it ran in exactly as it
//! was (no partial output).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

mod common;
use common::{args, copy_dir, edit, repo, TINY_CARTPOLE};

fn trajectory() -> String {
    repo()
        .join("data/deformable-sim-real/HHHHH")
        .display()
        .to_string()
}

/// A run folder trained once for every case that needs one (4 updates, no export).
fn trained_run() -> &'static Path {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &RUN.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("tiny.toml"), TINY_CARTPOLE).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
            .args(["train", "tiny.toml", "--quiet", "--no-export"])
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        let run = dir.path().join("runs/tiny");
        (dir, run)
    })
    .1
}

/// Copies the trained run to `dir/run` and returns `"run"`.
fn run_copy(dir: &Path) -> String {
    copy_dir(trained_run(), &dir.join("run"));
    "run".into()
}

fn write_tiny(dir: &Path) {
    std::fs::write(dir.join("tiny.toml"), TINY_CARTPOLE).unwrap();
}

fn tiny_config(dir: &Path, from: &str, to: &str) {
    assert!(TINY_CARTPOLE.contains(from), "{from}");
    std::fs::write(dir.join("tiny.toml"), TINY_CARTPOLE.replace(from, to)).unwrap();
}

/// The shipped config file `name` (found in one of the folders of `configs/`) copied into `dir` with
/// `from` replaced by `to`.
fn shipped_config(dir: &Path, name: &str, from: &str, to: &str) {
    let path = ["scenes", "calibrate", "train", "import"]
        .iter()
        .map(|kind| repo().join("configs").join(kind).join(name))
        .find(|path| path.exists())
        .unwrap_or_else(|| panic!("no shipped config {name}"));
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{name} lacks {from}");
    std::fs::write(dir.join(name), text.replace(from, to)).unwrap();
}

/// `dir/optimize.toml`: the shipped `configs/optimize/transport.toml` with its task found in the
/// repository and `from` replaced by `to`.
fn optimize_config(dir: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(repo().join("configs/optimize/transport.toml")).unwrap();
    let task = repo().join("configs/train/transport.toml");
    let text = text.replace(
        "transport = \"configs/train/transport.toml\"",
        &format!("transport = {:?}", task.to_str().unwrap()),
    );
    assert!(
        text.contains(from) && text.contains(task.to_str().unwrap()),
        "{from}"
    );
    std::fs::write(dir.join("optimize.toml"), text.replace(from, to)).unwrap();
}

/// The shipped `transport-posterior.toml` in `dir`, its posterior `posterior/samples.csv` holding
/// `rows`; returns the arguments that train it.
fn posterior_draws(dir: &Path, rows: &str) -> Vec<String> {
    shipped_config(
        dir,
        "transport-posterior.toml",
        "posterior = \"data/posteriors/coarse-soft-film\"",
        "posterior = \"posterior/samples.csv\"",
    );
    std::fs::create_dir(dir.join("posterior")).unwrap();
    std::fs::write(dir.join("posterior/samples.csv"), rows).unwrap();
    args(&["train", "transport-posterior.toml"])
}

/// `dir/seal.toml`: a two-vacuum seal fit of the real recordings (which flag no failure) on the
/// study's scene, 0.1 s each, into `out`.
fn seal_config(dir: &Path) {
    let text = format!(
        "dataset = {:?}\nscene = {:?}\nout = \"out\"\nmax_seconds = 0.1\n\n\
         [grid]\nvacuum_kpa = {{ min = 20.0, max = 30.0, steps = 2 }}\n",
        repo()
            .join("data/deformable-sim-real")
            .display()
            .to_string(),
        repo()
            .join("configs/scenes/study.toml")
            .display()
            .to_string(),
    );
    std::fs::write(dir.join("seal.toml"), text).unwrap();
}

/// `dir/calibrate.toml`: one batch of two on the first 0.05 s of HHHHH in the scene `preset`, into
/// `out`.
fn tiny_calibration(dir: &Path, preset: &str) {
    let data = repo().join("data/deformable-sim-real");
    std::fs::write(
        dir.join("calibrate.toml"),
        format!(
            "data = \"{}\"\ntrajectories = [\"HHHHH\"]\nout_dir = \"out\"\n\n\
             [sim]\npreset = \"{preset}\"\nbetween = 0\nmax_seconds = 0.05\n\n\
             [optimiser]\niterations = 1\nbatch_size = 2\ninitial_points = 1\nseed = 5\n\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 1.0e4\nupper = 1.0e6\nlog = true\n",
            data.display()
        ),
    )
    .unwrap();
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

/// Writes `<dir>/<folder>/.lock` naming this test's process: a running process holds the folder.
fn held_by_this_test(dir: &Path, folder: &str) {
    std::fs::create_dir_all(dir.join(folder)).unwrap();
    std::fs::write(
        dir.join(folder).join(".lock"),
        format!("{}\n", std::process::id()),
    )
    .unwrap();
}

/// `rlpkg data import-motive` of the fixture take into `dir/out` with `dir/motive.toml`.
fn import_args() -> Vec<String> {
    let take = repo().join("mocap/tests/fixtures/a30_m0.5_high_excerpt.csv.gz");
    args(&[
        "data",
        "import-motive",
        &take.display().to_string(),
        "--out",
        "out",
        "--config",
        "motive.toml",
    ])
}

/// A folder nothing can be written into: a read-only folder, or (when running as root, which
/// ignores permissions) a folder under /proc.
fn read_only_folder(dir: &Path) -> String {
    use std::os::unix::fs::PermissionsExt;
    let folder = dir.join("read-only");
    std::fs::create_dir(&folder).unwrap();
    std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o555)).unwrap();
    if std::fs::write(folder.join("probe"), "").is_ok() {
        std::fs::remove_file(folder.join("probe")).unwrap();
        return "/proc/rlpkg-bad-inputs".into();
    }
    "read-only".into()
}

/// Every file under `dir` with its bytes, and every folder.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            let key = path.strip_prefix(dir).unwrap().to_path_buf();
            if path.is_dir() {
                files.insert(key, None);
                stack.push(path);
            } else {
                files.insert(key, Some(std::fs::read(&path).unwrap()));
            }
        }
    }
    files
}

struct Case {
    name: &'static str,
    /// Prepares the folder and returns the arguments.
    setup: fn(&Path) -> Vec<String>,
    /// Texts the error message must contain.
    expected: &'static [&'static str],
}

fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "rollout too large for memory",
            setup: |dir| {
                tiny_config(dir, "num_envs = 4", "num_envs = 1048576");
                edit(
                    &dir.join("tiny.toml"),
                    "rollout_steps = 64",
                    "rollout_steps = 1048576",
                );
                edit(
                    &dir.join("tiny.toml"),
                    "total_steps = 1024",
                    "total_steps = 1099511627776",
                );
                args(&["train", "tiny.toml"])
            },
            expected: &[
                "tiny.toml",
                "run.num_envs x ppo.rollout_steps",
                "would need about",
                "TiB",
            ],
        },
        Case {
            name: "hidden layers too large for memory",
            setup: |dir| {
                tiny_config(
                    dir,
                    "actor_hidden = [16, 16]",
                    "actor_hidden = [65536, 65536]",
                );
                args(&["train", "tiny.toml"])
            },
            expected: &["tiny.toml", "policy.actor_hidden", "would need about"],
        },
        Case {
            name: "unknown key",
            setup: |dir| {
                tiny_config(dir, "gamma = 0.99", "gamma = 0.99\ngama = 0.9");
                args(&["train", "tiny.toml"])
            },
            expected: &["tiny.toml", "line 14", "gama"],
        },
        Case {
            name: "config that is not text",
            setup: |dir| {
                std::fs::write(dir.join("tiny.toml"), [0xff, 0xfe, 0x00, 0x9f]).unwrap();
                args(&["train", "tiny.toml"])
            },
            expected: &["tiny.toml", "not UTF-8"],
        },
        Case {
            name: "empty run name",
            setup: |dir| {
                write_tiny(dir);
                args(&["train", "tiny.toml", "--name", ""])
            },
            expected: &["--name", "plain folder name"],
        },
        Case {
            name: "run name leaving the output folder",
            setup: |dir| {
                write_tiny(dir);
                args(&["train", "tiny.toml", "--name", "../x"])
            },
            expected: &["--name", "../x", "plain folder name"],
        },
        Case {
            name: "run name with a line break",
            setup: |dir| {
                write_tiny(dir);
                args(&["train", "tiny.toml", "--name", "a\nb"])
            },
            expected: &["--name", "\"a\\nb\"", "without line breaks"],
        },
        Case {
            name: "one key set twice",
            setup: |dir| {
                write_tiny(dir);
                args(&[
                    "train",
                    "tiny.toml",
                    "--set",
                    "run.seed=1",
                    "--set",
                    "run.seed=2",
                ])
            },
            expected: &["--set run.seed=2", "already set by --set run.seed=1"],
        },
        Case {
            name: "output folder that is a file",
            setup: |dir| {
                write_tiny(dir);
                std::fs::write(dir.join("runs"), "").unwrap();
                args(&["train", "tiny.toml"])
            },
            expected: &["--out-dir runs", "is a file"],
        },
        Case {
            name: "read-only output folder",
            setup: |dir| {
                write_tiny(dir);
                let folder = read_only_folder(dir);
                args(&["train", "tiny.toml", "--out-dir", &folder, "--quiet"])
            },
            expected: &["tiny", "os error"],
        },
        Case {
            name: "latest names a missing checkpoint",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(dir.join("run/checkpoints/latest"), "update_000009").unwrap();
                args(&["train", "--resume", &run])
            },
            expected: &["checkpoints/latest", "update_000009", "holds no checkpoint"],
        },
        Case {
            name: "latest is empty",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(dir.join("run/checkpoints/latest"), "").unwrap();
                args(&["eval", &run, "--episodes", "2"])
            },
            expected: &["checkpoints/latest", "holds ``", "update_000010"],
        },
        Case {
            name: "latest is an absolute path",
            setup: |dir| {
                let run = run_copy(dir);
                let absolute = dir.join("run/checkpoints/update_000004");
                std::fs::write(
                    dir.join("run/checkpoints/latest"),
                    absolute.display().to_string(),
                )
                .unwrap();
                args(&["export", &run])
            },
            expected: &["checkpoints/latest", "holds `/", "inside"],
        },
        Case {
            name: "latest points into another run",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(
                    dir.join("run/checkpoints/latest"),
                    "../../other/checkpoints/update_000004",
                )
                .unwrap();
                args(&["train", "--resume", &run])
            },
            expected: &["checkpoints/latest", "../../other"],
        },
        Case {
            name: "hand-edited update counter",
            setup: |dir| {
                let run = run_copy(dir);
                edit(
                    &dir.join("run/checkpoints/update_000004/state.json"),
                    "\"update\":4",
                    "\"update\":2",
                );
                args(&["train", "--resume", &run])
            },
            expected: &["update_000004/state.json", "`update` = 2"],
        },
        Case {
            name: "update counter beyond the run length",
            setup: |dir| {
                let run = run_copy(dir);
                edit(
                    &dir.join("run/checkpoints/update_000004/state.json"),
                    "\"update\":4",
                    "\"update\":400",
                );
                args(&["train", "--resume", &run])
            },
            expected: &["state.json", "`update` = 400", "[1, 4]"],
        },
        Case {
            name: "hand-edited step counter",
            setup: |dir| {
                let run = run_copy(dir);
                edit(
                    &dir.join("run/checkpoints/update_000004/state.json"),
                    "\"global_step\":1024",
                    "\"global_step\":999",
                );
                args(&["train", "--resume", &run])
            },
            expected: &["state.json", "`global_step` = 999", "1024"],
        },
        Case {
            name: "garbage config.toml in a run folder",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(dir.join("run/config.toml"), [0x00, 0xc3, 0x28, 0x0a]).unwrap();
                args(&["train", "--resume", &run])
            },
            expected: &["run/config.toml", "not UTF-8"],
        },
        Case {
            name: "malformed config.toml in a run folder",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(dir.join("run/config.toml"), "[run\nenv = 1\n").unwrap();
                args(&["eval", &run])
            },
            expected: &["run/config.toml", "line 1"],
        },
        Case {
            name: "eval of a run with --params",
            setup: |dir| {
                let run = run_copy(dir);
                args(&[
                    "eval",
                    &run,
                    "--params",
                    "configs/scenes/calibrated-study.toml",
                ])
            },
            expected: &["--params", "cannot be used with"],
        },
        Case {
            name: "eval of a run with --policy",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--policy", "policy.onnx"])
            },
            expected: &["--policy", "cannot be used with"],
        },
        Case {
            name: "dataset options without --params",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--split", "train"])
            },
            expected: &["--split", "cannot be used with"],
        },
        Case {
            name: "more evaluation episodes than memory",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--episodes", "100000000000"])
            },
            expected: &["--episodes 100000000000", "would need about"],
        },
        Case {
            name: "endless latency measurement",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["export", &run, "--latency", "1000000000000"])
            },
            expected: &["--latency", "1000000000000", "1000000"],
        },
        Case {
            name: "no environment copies in the PPO benchmark",
            setup: |_| args(&["bench", "ppo", "--num-envs", "0"]),
            expected: &["--num-envs", "0", "1..=65536"],
        },
        Case {
            name: "a burn-in beyond any chain",
            setup: |_| {
                let config = repo().join("configs/calibrate/study.toml");
                args(&[
                    "posterior",
                    config.to_str().unwrap(),
                    "--burn-in",
                    "1000000000000",
                ])
            },
            expected: &["--burn-in", "1000000000000", "0..=1000000"],
        },
        Case {
            name: "a posterior threshold above every loss",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                std::fs::create_dir(dir.join("out")).unwrap();
                std::fs::write(
                    dir.join("out/evaluations.csv"),
                    "batch,candidate,k_tri_e,objective,loss,chamfer_m,object_mse_m2\n\
                     0,0,5e4,-2.995732273553991,0.05,0.1,0.001\n\
                     0,1,5e5,-2.5257286443082556,0.08,0.1,0.001\n",
                )
                .unwrap();
                args(&["posterior", "calibrate.toml", "--epsilon-loss", "1e19"])
            },
            expected: &[
                "--epsilon-loss 1e19",
                "out/evaluations.csv",
                "the posterior would be the prior's box",
            ],
        },
        Case {
            name: "a posterior config given to the surrogate posterior",
            setup: |_| {
                let config = repo().join("configs/calibrate/posterior-real-film.toml");
                args(&["posterior", config.to_str().unwrap()])
            },
            expected: &["posterior-real-film.toml", "[smc]", "rlpkg calibrate"],
        },
        Case {
            name: "more simulated environments than memory",
            setup: |_| {
                args(&[
                    "bench",
                    "sim",
                    "--grid",
                    "11x13",
                    "--envs",
                    "1000000000",
                    "--seconds",
                    "0",
                ])
            },
            expected: &["--grid 11x13 --envs 1000000000", "would need about"],
        },
        Case {
            name: "simulate into a file",
            setup: |dir| {
                std::fs::write(dir.join("out"), "").unwrap();
                args(&[
                    "simulate",
                    &trajectory(),
                    "--out",
                    "out",
                    "--seconds",
                    "0.01",
                ])
            },
            expected: &["--out out", "is a file"],
        },
        Case {
            name: "three numbers for a two-number grid",
            setup: |dir| {
                let reference = std::fs::read_to_string(repo().join("configs/scenes/study.toml"))
                    .unwrap()
                    .replace("grid = [21, 25]", "grid = [16, 19, 3]");
                std::fs::write(dir.join("scene.toml"), reference).unwrap();
                args(&["simulate", &trajectory(), "--params", "scene.toml"])
            },
            expected: &["scene.toml", "grid", "2"],
        },
        Case {
            name: "scene size with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "physical-explicit.toml",
                    "size_m = [0.254, 0.3048]",
                    "size_m = [0.254, 0.3048, 0.012]",
                );
                args(&[
                    "simulate",
                    &trajectory(),
                    "--params",
                    "physical-explicit.toml",
                ])
            },
            expected: &[
                "physical-explicit.toml",
                "size_m = [0.254, 0.3048, 0.012]",
                "invalid length 3, expected an array of length 2",
            ],
        },
        Case {
            name: "import: cup offset with four values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "motive.toml",
                    "tool_to_cup_m = [0.0, -0.005, 0.0]",
                    "tool_to_cup_m = [0.0, -0.005, 0.0, 1.0]",
                );
                import_args()
            },
            expected: &[
                "motive.toml: line 50: key `conversion.tool_to_cup_m`",
                "invalid length 4, expected an array of length 3",
            ],
        },
        Case {
            name: "import: package size with one value",
            setup: |dir| {
                shipped_config(
                    dir,
                    "motive.toml",
                    "size_m = [0.254, 0.3048]",
                    "size_m = [0.254]",
                );
                import_args()
            },
            expected: &[
                "motive.toml: line 62: key `package.size_m`",
                "invalid length 1, expected an array of length 2",
            ],
        },
        Case {
            name: "import: robot rotation with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "motive.toml",
                    "# rotation_xyzw = [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]\n# translation_m = [-0.4, 0.0, 0.15]",
                    "rotation_xyzw = [-0.7071067811865476, 0.0, 0.7071067811865476]\ntranslation_m = [-0.4, 0.0, 0.15]",
                );
                import_args()
            },
            expected: &[
                "motive.toml: line 72: key `robot.rotation_xyzw`",
                "invalid length 3, expected an array of length 4",
            ],
        },
        Case {
            name: "import: robot translation with two values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "motive.toml",
                    "# rotation_xyzw = [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]\n# translation_m = [-0.4, 0.0, 0.15]",
                    "rotation_xyzw = [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]\ntranslation_m = [-0.4, 0.15]",
                );
                import_args()
            },
            expected: &[
                "motive.toml: line 73: key `robot.translation_m`",
                "invalid length 2, expected an array of length 3",
            ],
        },
        Case {
            name: "transport: target tilt with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "transport.toml",
                    "target_tilt_deg = [30.0, 60.0]",
                    "target_tilt_deg = [30.0, 45.0, 60.0]",
                );
                args(&["train", "transport.toml"])
            },
            expected: &[
                "transport.toml",
                "key `transport.randomization.target_tilt_deg`",
                "invalid length 3, expected an array of length 2",
            ],
        },
        Case {
            name: "transport: package grid with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "transport.toml",
                    "grid = [11, 13]",
                    "grid = [11, 13, 2]",
                );
                args(&["train", "transport.toml"])
            },
            expected: &[
                "transport.toml",
                "key `transport.grid`",
                "invalid length 3, expected an array of length 2",
            ],
        },
        Case {
            name: "transport: one value for a mass range",
            setup: |dir| {
                shipped_config(
                    dir,
                    "transport.toml",
                    "object_mass_kg = [0.287, 0.595]",
                    "object_mass_kg = [0.287]",
                );
                args(&["train", "transport.toml"])
            },
            expected: &[
                "transport.toml",
                "key `transport.randomization.package.object_mass_kg`",
                "invalid length 1, expected an array of length 2",
            ],
        },
        Case {
            name: "transport: yaw range with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "transport.toml",
                    "package_yaw_deg = [-10.0, 10.0]",
                    "package_yaw_deg = [-10.0, 0.0, 10.0]",
                );
                args(&["train", "transport.toml"])
            },
            expected: &[
                "transport.toml",
                "key `transport.randomization.package.package_yaw_deg`",
                "invalid length 3, expected an array of length 2",
            ],
        },
        Case {
            name: "transport: material scale with three values",
            setup: |dir| {
                shipped_config(
                    dir,
                    "transport.toml",
                    "k_tri_d = [0.8, 1.25]",
                    "k_tri_d = [0.8, 1.0, 1.25]",
                );
                args(&["train", "transport.toml"])
            },
            expected: &[
                "transport.toml",
                "key `transport.randomization.package.param_scale.k_tri_d`",
                "invalid length 3, expected an array of length 2",
            ],
        },
        Case {
            name: "transport: posterior draw with a negative stiffness",
            setup: |dir| {
                posterior_draws(dir, "k_tri_e,k_spr_e,mu_con\n2000,30,0.5\n-2000,30,0.5\n")
            },
            expected: &[
                "transport-posterior.toml",
                "transport.randomization.package.posterior",
                "posterior/samples.csv line 3 column 1",
                "key `k_tri_e` = -2000",
            ],
        },
        Case {
            name: "tanh_scale on discrete actions",
            setup: |dir| {
                tiny_config(
                    dir,
                    "action_transform = \"clip\"",
                    "action_transform = \"tanh_scale\"",
                );
                args(&["train", "tiny.toml"])
            },
            expected: &["tiny.toml", "policy.action_transform", "discrete actions"],
        },
        Case {
            name: "resume given a new run name",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["train", "--resume", &run, "--name", "other"])
            },
            expected: &["--name", "cannot be used with", "--resume"],
        },
        Case {
            name: "optimize: a horizon of days",
            setup: |dir| {
                optimize_config(dir, "horizon_s = 3.5", "horizon_s = 1e6");
                args(&["optimize", "optimize.toml"])
            },
            expected: &["optimize.toml", "knots.horizon_s = 1000000", "(0, 600]"],
        },
        Case {
            name: "optimize: starting faster than the task allows",
            setup: |dir| {
                optimize_config(dir, "initial_speed_m_s = 0.5", "initial_speed_m_s = 100");
                args(&["optimize", "optimize.toml"])
            },
            expected: &[
                "optimize.toml",
                "knots.initial_speed_m_s = 100",
                "limits.max_path_speed_m_s",
            ],
        },
        Case {
            name: "optimize: a speed spread beyond the task's limit",
            setup: |dir| {
                optimize_config(dir, "speed_std_m_s = 0.25", "speed_std_m_s = 1e30");
                args(&["optimize", "optimize.toml"])
            },
            expected: &[
                "optimize.toml",
                "knots.speed_std_m_s = 1000000000000000000000000000000",
                "limits.max_path_speed_m_s",
            ],
        },
        Case {
            name: "optimize: a tilt spread of a turn",
            setup: |dir| {
                optimize_config(dir, "tilt_std_deg = 4.0", "tilt_std_deg = 360.0");
                args(&["optimize", "optimize.toml"])
            },
            expected: &["optimize.toml", "knots.tilt_std_deg = 360", "[0, 90]"],
        },
        Case {
            name: "optimize: a task file that is not there",
            setup: |dir| {
                let text = std::fs::read_to_string(repo().join("configs/optimize/transport.toml"))
                    .unwrap()
                    .replace("configs/train/transport.toml", "configs/train/none.toml");
                std::fs::write(dir.join("optimize.toml"), text).unwrap();
                args(&["optimize", "optimize.toml"])
            },
            expected: &[
                "optimize.toml",
                "transport = \"configs/train/none.toml\"",
                "expected a training config",
            ],
        },
        Case {
            name: "transport: posterior draw beyond a parameter's range",
            setup: |dir| posterior_draws(dir, "k_tri_e,k_spr_e,mu_con\n2000,30,0.5\n2000,30,1e6\n"),
            expected: &[
                "posterior/samples.csv line 3 column 3",
                "key `mu_con` = 1e6",
                "[0, 1e2]",
            ],
        },
        Case {
            name: "calibration listing a recording twice",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                edit(
                    &dir.join("calibrate.toml"),
                    "trajectories = [\"HHHHH\"]",
                    "trajectories = [\"HHHHH\", \"HHHHH\"]",
                );
                args(&["calibrate", "calibrate.toml"])
            },
            expected: &[
                "calibrate.toml",
                "trajectories[1]",
                "each trajectory id once",
            ],
        },
        Case {
            name: "calibration given a recording twice on the command line",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                args(&[
                    "calibrate",
                    "calibrate.toml",
                    "--trajectories",
                    "HHHHH,HHLHL,HHHHH",
                ])
            },
            expected: &["--trajectories", "HHHHH is listed twice"],
        },
        Case {
            name: "recording: cup position with four values in meta.toml",
            setup: |dir| {
                copy_dir(
                    &repo().join("data/deformable-sim-real/HHHHH"),
                    &dir.join("HHHHH"),
                );
                edit(
                    &dir.join("HHHHH/meta.toml"),
                    "initial_suction_cup_position_m = [0.241590, 0.246999, -0.461197]",
                    "initial_suction_cup_position_m = [0.241590, 0.246999, -0.461197, 0.0]",
                );
                args(&["simulate", "HHHHH", "--seconds", "0.01"])
            },
            expected: &[
                "HHHHH/meta.toml:8:",
                "key `initial_suction_cup_position_m`",
                "invalid length 4, expected an array of length 3",
            ],
        },
        Case {
            name: "recording: a marker with two coordinates in meta.toml",
            setup: |dir| {
                copy_dir(
                    &repo().join("data/deformable-sim-real/HHHHH"),
                    &dir.join("HHHHH"),
                );
                edit(
                    &dir.join("HHHHH/meta.toml"),
                    "  [0.373205, 0.249217, -0.377125],",
                    "  [0.373205, 0.249217],",
                );
                args(&["simulate", "HHHHH", "--seconds", "0.01"])
            },
            expected: &[
                "HHHHH/meta.toml:9:",
                "key `initial_marker_positions_m`",
                "invalid length 2, expected an array of length 3",
            ],
        },
        Case {
            name: "particles between markers overflowing",
            setup: |_| {
                args(&[
                    "simulate",
                    &trajectory(),
                    "--between",
                    "3074457345618258603",
                ])
            },
            expected: &["--between 3074457345618258603"],
        },
        Case {
            name: "calibration into a file",
            setup: |dir| {
                std::fs::write(dir.join("out"), "").unwrap();
                let config = repo()
                    .join("configs/calibrate/study.toml")
                    .display()
                    .to_string();
                args(&["calibrate", &config, "--out", "out"])
            },
            expected: &["out: is a file", "calibrate/study.toml"],
        },
        Case {
            name: "calibration log row outside the bounds",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                std::fs::create_dir(dir.join("out")).unwrap();
                std::fs::write(
                    dir.join("out/evaluations.csv"),
                    "batch,candidate,k_tri_e,objective,loss,chamfer_m,object_mse_m2\n\
                     0,0,5e7,-3,0.05,0.1,0.001\n",
                )
                .unwrap();
                args(&["calibrate", "calibrate.toml"])
            },
            expected: &[
                "out/evaluations.csv",
                "line 2",
                "`k_tri_e` = 50000000",
                "outside its bounds",
            ],
        },
        Case {
            name: "resuming a run another process is training",
            setup: |dir| {
                let run = run_copy(dir);
                held_by_this_test(dir, &run);
                args(&["train", "--resume", &run, "--quiet"])
            },
            expected: &["run: in use by process", "run/.lock", "wait until"],
        },
        Case {
            name: "a new run into a folder another process holds",
            setup: |dir| {
                write_tiny(dir);
                held_by_this_test(dir, "runs/tiny");
                args(&["train", "tiny.toml", "--quiet"])
            },
            expected: &["runs/tiny: in use by process", "runs/tiny/.lock"],
        },
        Case {
            name: "calibration into a folder another process holds",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                held_by_this_test(dir, "out");
                std::fs::write(dir.join("out/.evaluations.csv.Ab12Cd"), "being written").unwrap();
                args(&["calibrate", "calibrate.toml", "--fresh"])
            },
            expected: &["out: in use by process", "out/.lock"],
        },
        Case {
            name: "a run folder whose lock file holds no process id",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::write(dir.join(&run).join(".lock"), "not a pid\n").unwrap();
                args(&["train", "--resume", &run, "--quiet"])
            },
            expected: &["run/.lock", "not a process id", "remove the file"],
        },
        Case {
            name: "minus infinity for a number of seconds",
            setup: |_| {
                args(&[
                    "simulate",
                    &trajectory(),
                    "--out",
                    "out",
                    "--seconds",
                    "-inf",
                ])
            },
            expected: &["--seconds -inf"],
        },
        Case {
            name: "minus infinity in a list of batch sizes",
            setup: |_| args(&["bench", "sim", "--grid", "6x7", "--envs", "-inf"]),
            expected: &["envs", "-inf"],
        },
        Case {
            name: "a negative grid",
            setup: |_| args(&["simulate", &trajectory(), "--out", "out", "--grid", "-5x5"]),
            expected: &["--grid", "-5x5"],
        },
        Case {
            name: "export over a checkpoint of the run",
            setup: |dir| {
                let run = run_copy(dir);
                args(&[
                    "export",
                    &run,
                    "--out",
                    "run/checkpoints/update_000004/model.bpk",
                ])
            },
            expected: &[
                "--out run/checkpoints/update_000004/model.bpk",
                "a file of the run's checkpoints",
                "would destroy the run",
            ],
        },
        Case {
            name: "export over the run's config.toml",
            setup: |dir| {
                let run = run_copy(dir);
                std::fs::create_dir(dir.join("elsewhere")).unwrap();
                args(&["export", &run, "--out", "elsewhere/../run/config.toml"])
            },
            expected: &[
                "--out elsewhere/../run/config.toml",
                "the run's configuration",
            ],
        },
        Case {
            name: "calibration writing its scene over its own config",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                args(&[
                    "calibrate",
                    "calibrate.toml",
                    "--write-params",
                    "calibrate.toml",
                ])
            },
            expected: &[
                "--write-params calibrate.toml",
                "the calibration config",
                "which this command reads",
            ],
        },
        Case {
            name: "calibration writing its scene over its preset scene",
            setup: |dir| {
                std::fs::copy(
                    repo().join("configs/scenes/study.toml"),
                    dir.join("scene.toml"),
                )
                .unwrap();
                tiny_calibration(dir, "scene.toml");
                std::fs::create_dir(dir.join("sub")).unwrap();
                args(&[
                    "calibrate",
                    "calibrate.toml",
                    "--write-params",
                    "sub/../scene.toml",
                ])
            },
            expected: &["--write-params sub/../scene.toml", "`sim.preset`"],
        },
        Case {
            name: "calibration writing its scene into a missing folder",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                args(&[
                    "calibrate",
                    "calibrate.toml",
                    "--write-params",
                    "nodir/x.toml",
                ])
            },
            expected: &[
                "--write-params nodir/x.toml",
                "the folder nodir does not exist",
            ],
        },
        Case {
            name: "calibration writing its scene to a device",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                args(&["calibrate", "calibrate.toml", "--write-params", "/dev/null"])
            },
            expected: &["--write-params /dev/null", "is a character device"],
        },
        Case {
            name: "calibration whose config is a file its output folder gets",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                std::fs::create_dir(dir.join("out")).unwrap();
                std::fs::rename(dir.join("calibrate.toml"), dir.join("out/best.toml")).unwrap();
                args(&["calibrate", "out/best.toml"])
            },
            expected: &[
                "out/best.toml: key `out_dir` = out",
                "writes out/best.toml there",
                "the calibration config",
                "another output folder",
            ],
        },
        Case {
            name: "calibration whose scene is a file its output folder gets",
            setup: |dir| {
                tiny_calibration(dir, "out/calibrated.toml");
                std::fs::create_dir(dir.join("out")).unwrap();
                std::fs::copy(
                    repo().join("configs/scenes/study.toml"),
                    dir.join("out/calibrated.toml"),
                )
                .unwrap();
                args(&["calibrate", "calibrate.toml", "--out", "./out"])
            },
            expected: &[
                "--out ./out",
                "writes ./out/calibrated.toml there",
                "`sim.preset`",
            ],
        },
        Case {
            name: "simulate: a span beyond the recording",
            setup: |_| {
                args(&[
                    "simulate",
                    &trajectory(),
                    "--seconds",
                    "1e300",
                    "--out",
                    "out",
                ])
            },
            expected: &[
                "--seconds 1e300",
                "at most the recording's 5.8792 s",
                "HHHHH",
            ],
        },
        Case {
            name: "simulate: stills closer than the recorded frames",
            setup: |_| args(&["simulate", &trajectory(), "--png-every", "1e-300"]),
            expected: &["--png-every 1e-300", "one recorded frame"],
        },
        Case {
            name: "simulate: one GIF frame in ages",
            setup: |_| {
                args(&[
                    "simulate",
                    &trajectory(),
                    "--frames-every",
                    "1000000000000000",
                ])
            },
            expected: &["--frames-every 1000000000000000", "an hour of recording"],
        },
        Case {
            name: "calibration window beyond every recording (option)",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                args(&["calibrate", "calibrate.toml", "--max-seconds", "1e300"])
            },
            expected: &["--max-seconds 1e300", "longest recording's"],
        },
        Case {
            name: "calibration window beyond every recording (config)",
            setup: |dir| {
                tiny_calibration(dir, "reference");
                edit(
                    &dir.join("calibrate.toml"),
                    "max_seconds = 0.05",
                    "max_seconds = 1e30",
                );
                args(&["calibrate", "calibrate.toml"])
            },
            expected: &[
                "calibrate.toml: key `sim.max_seconds`",
                "longest recording's",
            ],
        },
        Case {
            name: "scene: a lattice search without end",
            setup: |_| {
                let manifest = repo().join("data/packages-v1/manifest.json");
                args(&[
                    "scene",
                    "from-manifest",
                    manifest.to_str().unwrap(),
                    "--out",
                    "scene.toml",
                    "--max-vertices",
                    "1000000000000",
                ])
            },
            expected: &["--max-vertices", "1000000000000", "2..=1000"],
        },
        Case {
            name: "scene written over its base scene",
            setup: |dir| {
                std::fs::copy(
                    repo().join("configs/scenes/calibrated-coarse-soft-film.toml"),
                    dir.join("base.toml"),
                )
                .unwrap();
                let manifest = repo().join("data/packages-v1/manifest.json");
                args(&[
                    "scene",
                    "from-manifest",
                    manifest.to_str().unwrap(),
                    "--base",
                    "base.toml",
                    "--out",
                    "./base.toml",
                ])
            },
            expected: &["--out ./base.toml", "the base scene (--base)"],
        },
        Case {
            name: "scene written over its manifest",
            setup: |dir| {
                std::fs::copy(
                    repo().join("data/packages-v1/manifest.json"),
                    dir.join("manifest.json"),
                )
                .unwrap();
                args(&[
                    "scene",
                    "from-manifest",
                    "manifest.json",
                    "--out",
                    "manifest.json",
                ])
            },
            expected: &["--out manifest.json", "the manifest"],
        },
        Case {
            name: "seal fit on a dataset without a failure take",
            setup: |dir| {
                seal_config(dir);
                args(&["seal", "fit", "seal.toml"])
            },
            expected: &[
                "manifest.toml",
                "0 of 18 takes flagged",
                "at least one failure take",
            ],
        },
        Case {
            name: "seal fit into a folder of other files",
            setup: |dir| {
                seal_config(dir);
                std::fs::create_dir(dir.join("out")).unwrap();
                std::fs::write(dir.join("out/scene-of-mine.toml"), "kept").unwrap();
                args(&["seal", "fit", "seal.toml"])
            },
            expected: &["seal.toml", "key `out`", "scene-of-mine.toml"],
        },
        Case {
            name: "seal grid of one step over a range",
            setup: |dir| {
                seal_config(dir);
                edit(&dir.join("seal.toml"), "steps = 2", "steps = 1");
                args(&["seal", "fit", "seal.toml"])
            },
            expected: &["seal.toml", "vacuum_kpa.steps", "at least 2"],
        },
        Case {
            name: "seal fit into a file",
            setup: |dir| {
                seal_config(dir);
                std::fs::write(dir.join("out"), "").unwrap();
                args(&["seal", "fit", "seal.toml"])
            },
            expected: &[
                "seal.toml",
                "key `out` = out",
                "is a file",
                "candidates.csv",
            ],
        },
    ]
}

#[test]
fn bad_inputs_exit_with_2_name_the_culprit_and_write_nothing() {
    let mut failures = Vec::new();
    // With RLPKG_BAD_INPUTS_TABLE=<file>, every case as a markdown row (for release notes).
    let mut table = String::from("| case | command | exit code | message |\n|---|---|---|---|\n");
    for case in cases() {
        let dir = tempfile::tempdir().unwrap();
        let args = (case.setup)(dir.path());
        let before = snapshot(dir.path());
        let out = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
            .args(&args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let mut problems = Vec::new();
        if out.status.code() != Some(2) {
            problems.push(format!("exit code {:?}", out.status.code()));
        }
        for text in case.expected {
            if !stderr.contains(text) {
                problems.push(format!("message lacks `{text}`"));
            }
        }
        if stderr.contains("panicked") || stderr.matches("os error").count() > 1 {
            problems.push("panic or repeated OS error".into());
        }
        if snapshot(dir.path()) != before {
            problems.push("the folder changed".into());
        }
        let command = args
            .iter()
            .map(|a| a.replace(&repo().display().to_string(), "<repo>"))
            .collect::<Vec<_>>()
            .join(" ");
        let message: String = stderr.split_whitespace().collect::<Vec<_>>().join(" ");
        table += &format!(
            "| {} | `rlpkg {command}` | {} | {} |\n",
            case.name,
            out.status.code().map_or("signal".into(), |c| c.to_string()),
            message.replace('|', "\\|")
        );
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n  rlpkg {:?}\n  stderr: {stderr}",
                case.name,
                problems.join(", "),
                args
            ));
        }
    }
    if let Some(path) = std::env::var_os("RLPKG_BAD_INPUTS_TABLE") {
        std::fs::write(path, table).unwrap();
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Where a stream of the command goes.
#[derive(Clone, Copy, PartialEq)]
enum Stream {
    /// Read by the test.
    Read,
    /// `/dev/full`: every write fails with ENOSPC.
    Full,
    /// A pipe whose reader went away at once (`| head`): every write fails with EPIPE.
    Closed,
}

impl Stream {
    fn stdio(self) -> std::process::Stdio {
        match self {
            Stream::Read | Stream::Closed => std::process::Stdio::piped(),
            Stream::Full => std::fs::File::create("/dev/full").unwrap().into(),
        }
    }
}

/// A command whose standard output or error cannot be written.
struct StreamCase {
    name: &'static str,
    setup: fn(&Path) -> Vec<String>,
    stdout: Stream,
    stderr: Stream,
    /// 2 when standard output is full (naming it), 0 when its reader went away.
    code: i32,
    expected: &'static [&'static str],
    /// The file the command must have written all the same (the finished work), if it writes one.
    writes: Option<&'static str>,
}

/// A command that finishes its work into a full standard output: exit 2 naming it.
fn full(
    name: &'static str,
    setup: fn(&Path) -> Vec<String>,
    writes: Option<&'static str>,
) -> StreamCase {
    StreamCase {
        name,
        setup,
        stdout: Stream::Full,
        stderr: Stream::Read,
        code: 2,
        expected: &["error: standard output", "the command finished"],
        writes,
    }
}

fn stream_cases() -> Vec<StreamCase> {
    vec![
        full(
            "eval --json into a full stdout",
            |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--episodes", "2", "--json"])
            },
            None,
        ),
        full(
            "eval into a full stdout",
            |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--episodes", "2"])
            },
            None,
        ),
        full(
            "export --json into a full stdout",
            |dir| {
                let run = run_copy(dir);
                args(&[
                    "export", &run, "--out", "p.onnx", "--verify", "10", "--json",
                ])
            },
            Some("p.onnx"),
        ),
        full(
            "bench ppo into a full stdout",
            |_| {
                args(&[
                    "bench",
                    "ppo",
                    "--backend",
                    "ndarray",
                    "--minibatch",
                    "64",
                    "--minibatches",
                    "1",
                    "--env-steps",
                    "100",
                    "--num-envs",
                    "2",
                    "--json",
                ])
            },
            None,
        ),
        full(
            "bench sim --json into a full stdout",
            |_| {
                args(&[
                    "bench",
                    "sim",
                    "--grid",
                    "6x7",
                    "--envs",
                    "1",
                    "--seconds",
                    "0.1",
                    "--workload",
                    "command",
                    "--json",
                ])
            },
            None,
        ),
        full(
            "simulate into a full stdout",
            |dir| {
                quick_scene(dir);
                args(&[
                    "simulate",
                    &trajectory(),
                    "--params",
                    "quick.toml",
                    "--seconds",
                    "0.01",
                    "--out",
                    "out",
                ])
            },
            Some("out/summary.json"),
        ),
        full(
            "train into a full stdout",
            |dir| {
                write_tiny(dir);
                args(&["train", "tiny.toml"])
            },
            Some("runs/tiny/policy.onnx"),
        ),
        full(
            "scene from-manifest into a full stdout",
            |_| {
                let manifest = repo().join("data/packages-v1/manifest.json");
                args(&[
                    "scene",
                    "from-manifest",
                    manifest.to_str().unwrap(),
                    "--out",
                    "scene.toml",
                    "--base",
                    repo()
                        .join("configs/scenes/calibrated-coarse-soft-film.toml")
                        .to_str()
                        .unwrap(),
                ])
            },
            Some("scene.toml"),
        ),
        full(
            "import-motive into a full stdout",
            |dir| {
                shipped_config(
                    dir,
                    "motive.toml",
                    "\n[takes]\n",
                    "\n[takes]\n\"a30_m0.5_high_excerpt\" = { split = \"train\", object_total_mass_kg = 0.2268 }\n",
                );
                import_args()
            },
            Some("out/manifest.toml"),
        ),
        full(
            "calibrate into a full stdout",
            |dir| {
                quick_scene(dir);
                tiny_calibration(dir, "quick.toml");
                args(&["calibrate", "calibrate.toml"])
            },
            Some("out/calibrated.toml"),
        ),
        StreamCase {
            name: "help into a full stdout",
            setup: |_| args(&["--help"]),
            stdout: Stream::Full,
            stderr: Stream::Read,
            code: 2,
            expected: &["error: standard output"],
            writes: None,
        },
        StreamCase {
            name: "a bad run with a full stderr",
            setup: |_| args(&["eval", "norun"]),
            stdout: Stream::Read,
            stderr: Stream::Full,
            code: 2,
            expected: &[],
            writes: None,
        },
        StreamCase {
            name: "eval into a reader that went away",
            setup: |dir| {
                let run = run_copy(dir);
                args(&["eval", &run, "--episodes", "2"])
            },
            stdout: Stream::Closed,
            stderr: Stream::Read,
            code: 0,
            expected: &[],
            writes: None,
        },
        StreamCase {
            name: "train into a reader that went away (stdout and stderr)",
            setup: |dir| {
                write_tiny(dir);
                args(&["train", "tiny.toml"])
            },
            stdout: Stream::Closed,
            stderr: Stream::Closed,
            code: 0,
            expected: &[],
            writes: Some("runs/tiny/policy.onnx"),
        },
    ]
}

#[test]
fn a_full_or_closed_stream_never_panics_nor_loses_the_work() {
    let mut failures = Vec::new();
    for case in stream_cases() {
        let dir = tempfile::tempdir().unwrap();
        let args = (case.setup)(dir.path());
        let before = snapshot(dir.path());
        let mut child = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
            .args(&args)
            .current_dir(dir.path())
            .stdout(case.stdout.stdio())
            .stderr(case.stderr.stdio())
            .spawn()
            .unwrap();
        if case.stdout == Stream::Closed {
            drop(child.stdout.take());
        }
        if case.stderr == Stream::Closed {
            drop(child.stderr.take());
        }
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let mut problems = Vec::new();
        if out.status.code() != Some(case.code) {
            problems.push(format!("exit code {:?}", out.status.code()));
        }
        for text in case.expected {
            if !stderr.contains(text) {
                problems.push(format!("message lacks `{text}`"));
            }
        }
        if stderr.contains("panicked") {
            problems.push("panic".into());
        }
        let after = snapshot(dir.path());
        if before
            .iter()
            .any(|(path, bytes)| after.get(path) != Some(bytes))
        {
            problems.push("an input changed".into());
        }
        match case.writes {
            Some(file) if !dir.path().join(file).is_file() => {
                problems.push(format!("{file} was not written"))
            }
            None if after != before => problems.push("the folder changed".into()),
            _ => {}
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n  rlpkg {:?}\n  stderr: {stderr}",
                case.name,
                problems.join(", "),
                args
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
