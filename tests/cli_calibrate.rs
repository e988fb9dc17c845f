//! End-to-end tests of `rlpkg calibrate` (and `rlpkg eval --params` on its result) through the
//! binary, on a short piece of a real trajectory of the repository's dataset, a coarse 6 x 7 grid
//! and a short rest period, so that each run takes seconds.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn rlpkg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A dataset with the first `frames` frames of HHHHH, in split `split`.
fn small_dataset(dir: &Path, frames: usize, split: &str) -> PathBuf {
    let source = repo().join("data/deformable-sim-real/HHHHH");
    let root = dir.join("data");
    let target = root.join("HHHHH");
    std::fs::create_dir_all(&target).unwrap();
    for file in ["tool.csv", "object.csv"] {
        let body = std::fs::read_to_string(source.join(file)).unwrap();
        let kept: Vec<&str> = body.lines().take(frames + 1).collect();
        std::fs::write(target.join(file), kept.join("\n") + "\n").unwrap();
    }
    let markers = std::fs::read_to_string(source.join("markers.csv")).unwrap();
    let kept: Vec<&str> = markers
        .lines()
        .enumerate()
        .filter(|(i, line)| {
            *i == 0 || line.split(',').next().unwrap().parse::<usize>().unwrap() < frames
        })
        .map(|(_, line)| line)
        .collect();
    std::fs::write(target.join("markers.csv"), kept.join("\n") + "\n").unwrap();
    std::fs::copy(source.join("meta.toml"), target.join("meta.toml")).unwrap();
    let duration = (frames - 1) as f64 / 240.0;
    std::fs::write(
        root.join("manifest.toml"),
        format!(
            "[[trajectory]]\nid = \"HHHHH\"\nsplit = \"{split}\"\nframes = {frames}\n\
             duration_s = {duration}\nobject_total_mass_kg = 0.569592\n"
        ),
    )
    .unwrap();
    root
}

/// The reference scene on the coarsest grid (6 x 7) with a 0.2 s rest period instead of 2 s.
fn quick_preset(dir: &Path) -> PathBuf {
    let reference = std::fs::read_to_string(repo().join("configs/scenes/study.toml")).unwrap();
    assert!(reference.contains("rest_time_s = 2.0") && reference.contains("grid = [21, 25]"));
    let path = dir.join("quick.toml");
    let quick = reference
        .replace("rest_time_s = 2.0", "rest_time_s = 0.2")
        .replace("grid = [21, 25]", "grid = [6, 7]")
        // The disc slips through the 6 x 7 sheet; these tests are about the calibration machinery.
        .replace("[health]", "[health]\nobject_outside = false");
    std::fs::write(&path, quick).unwrap();
    path
}

fn config(dir: &Path, data: &Path, preset: &Path, extra_param: &str) -> PathBuf {
    let path = dir.join("calibrate.toml");
    std::fs::write(
        &path,
        format!(
            r#"
data = "{}"
out_dir = "{}"

[sim]
preset = "{}"
between = 0
max_seconds = 0.05

[optimiser]
iterations = 1
batch_size = 2
initial_points = 1
seed = 5

[[param]]
name = "k_tri_e"
lower = 1.0e4
upper = 1.0e6
log = true
{extra_param}"#,
            data.display(),
            dir.join("out").display(),
            preset.display()
        ),
    )
    .unwrap();
    path
}

#[test]
fn help_lists_the_options() {
    let out = rlpkg(&["calibrate", "--help"]);
    assert!(out.status.success());
    let help = text(&out.stdout);
    for word in [
        "--out",
        "--iterations",
        "--trajectories",
        "--max-seconds",
        "--fresh",
        "--write-params",
    ] {
        assert!(help.contains(word), "help lacks {word}:\n{help}");
    }
}

#[test]
fn missing_config_exits_with_2_and_names_it() {
    let out = rlpkg(&["calibrate", "configs/does-not-exist-42.toml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("does-not-exist-42.toml"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn bad_config_values_exit_with_2_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "train");
    let preset = quick_preset(dir.path());
    let path = config(
        dir.path(),
        &data,
        &preset,
        "\n[[param]]\nname = \"k_nope\"\nlower = 1.0\nupper = 2.0\n",
    );
    let out = rlpkg(&["calibrate", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("calibrate.toml") && err.contains("param[1].name") && err.contains("k_tri_e"),
        "{err}"
    );

    // An unknown trajectory id names the manifest and the id.
    let path = config(dir.path(), &data, &preset, "");
    let out = rlpkg(&[
        "calibrate",
        path.to_str().unwrap(),
        "--trajectories",
        "HXXXX",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("manifest.toml") && err.contains("HXXXX"),
        "{err}"
    );
}

#[test]
fn calibrates_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "test");
    let preset = quick_preset(dir.path());
    let cfg = config(dir.path(), &data, &preset, "");
    let shipped = dir.path().join("calibrated.toml");
    let cfg_arg = cfg.to_str().unwrap();
    // The dataset's only trajectory is in the test split: fit it explicitly.
    let run = |extra: &[&str]| {
        let mut args = vec![
            "calibrate",
            cfg_arg,
            "--trajectories",
            "HHHHH",
            "--write-params",
            shipped.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        rlpkg(&args)
    };
    let out = run(&[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("k_tri_e") && stdout.contains("wall time"),
        "{stdout}"
    );
    let out_dir = dir.path().join("out");
    let log = std::fs::read_to_string(out_dir.join("evaluations.csv")).unwrap();
    // Header + 2 batches of 2 (the preset's value and one design point, then one model-based pair).
    assert_eq!(log.lines().count(), 1 + 4, "{log}");
    assert!(
        log.lines().nth(1).unwrap().starts_with("0,0,200000,"),
        "preset value first:\n{log}"
    );
    for line in log.lines().skip(1) {
        let loss: f64 = line.split(',').nth(4).unwrap().parse().unwrap();
        assert!(loss.is_finite() && loss > 0.0, "{line}");
    }
    let calibrated = std::fs::read_to_string(&shipped).unwrap();
    assert!(
        calibrated.starts_with("# Calibrated by `rlpkg calibrate"),
        "{calibrated}"
    );
    assert_eq!(
        calibrated,
        std::fs::read_to_string(out_dir.join("calibrated.toml")).unwrap()
    );
    let scene = rlpkg_sim::SceneConfig::from_toml_str(&calibrated, "calibrated.toml").unwrap();
    assert_eq!(scene.package.grid, [6, 7]);
    assert!((scene.cups.rest_time_s - 0.2).abs() < 1e-6);

    // What a second Ctrl-C (an immediate exit) can leave: temporary copies of the output files
    // and of the --write-params file. The rerun removes them and nothing else.
    let leftovers = [
        out_dir.join(".progress.csv.Ab12Cd"),
        out_dir.join(".best.toml.x9Y8z7"),
        out_dir.join(".calibrated.toml.QWERTY"),
        dir.path().join(".calibrated.toml.a1b2c3"),
    ];
    let kept = [
        out_dir.join("notes.txt"),
        out_dir.join(".best.toml.orig"),
        dir.path().join(".other.toml.a1b2c3"),
    ];
    for path in leftovers.iter().chain(&kept) {
        std::fs::write(path, "half").unwrap();
    }

    // Rerun: nothing left to do, same result. More iterations: only the new batch is evaluated.
    let out = run(&[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for path in &leftovers {
        assert!(!path.exists(), "{} left behind", path.display());
    }
    for path in &kept {
        assert!(path.exists(), "{} removed", path.display());
    }
    assert_eq!(
        std::fs::read_to_string(out_dir.join("evaluations.csv")).unwrap(),
        log
    );
    assert_eq!(std::fs::read_to_string(&shipped).unwrap(), calibrated);
    let out = run(&["--iterations", "2"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let longer = std::fs::read_to_string(out_dir.join("evaluations.csv")).unwrap();
    assert!(
        longer.starts_with(&log) && longer.lines().count() == 1 + 6,
        "{longer}"
    );
}

#[test]
fn evaluates_parameters_on_a_split() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "test");
    let shipped = quick_preset(dir.path());
    // `rlpkg eval --params` on a scene file: Table 1 for the test split, JSON and pictures.
    let eval_out = dir.path().join("eval");
    let out = rlpkg(&[
        "eval",
        "--params",
        shipped.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--split",
        "test",
        "--out",
        eval_out.to_str().unwrap(),
        "--perturb",
        "10,50",
        "--json",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let row = &summary["table1"][0];
    assert_eq!(row["split"], "test");
    assert_eq!(row["frames"], 30);
    let cd = row["chamfer_m"]["mean"].as_f64().unwrap();
    assert!(cd > 0.0 && cd < 0.2, "{row}");
    assert_eq!(summary["perturb"].as_array().unwrap().len(), 3);
    for picture in [
        "HHHHH_marker_error.png",
        "HHHHH_loss.png",
        "HHHHH_t00.00.png",
    ] {
        let bytes = std::fs::read(eval_out.join(picture)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{picture}");
    }
    assert!(eval_out.join("summary.json").exists());
}

/// A config that samples the posterior of `k_tri_e` with a small population.
fn posterior_config(dir: &Path, data: &Path, preset: &Path) -> PathBuf {
    let path = dir.join("posterior.toml");
    std::fs::write(
        &path,
        format!(
            r#"
data = "{}"
out_dir = "{}"

[sim]
preset = "{}"
between = 0
max_seconds = 0.05

[smc]
particles = 8
moves = 1
seed = 4
polish_iterations = 2
chaos_replays = 2

[smc.mode_search]
population = 4
generations = 3
first_horizon_s = 0.02

[loss]
object = 1.0
package = 1.0
kind = "labelled"

[[param]]
name = "k_tri_e"
lower = 1.0e4
upper = 1.0e6
log = true
"#,
            data.display(),
            dir.join("posterior").display(),
            preset.display()
        ),
    )
    .unwrap();
    path
}

#[test]
fn samples_a_posterior_on_the_simulator_and_resumes_it_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "train");
    let preset = quick_preset(dir.path());
    let cfg = posterior_config(dir.path(), &data, &preset);
    let out = rlpkg(&["calibrate", cfg.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("candidates simulated") && stdout.contains("eigen-directions"),
        "{stdout}"
    );
    // The likelihood's power, from the spread of the mode search's best point replayed twice.
    assert!(stdout.contains("sampled prior x L^"), "{stdout}");
    // HHHHH's markers are tracked through the 30 frames and tied to the simulated sites.
    assert!(
        stdout.contains("HHHHH: 26 markers tracked from the first frame")
            && stdout.contains("tied to a site"),
        "{stdout}"
    );
    let out_dir = dir.path().join("posterior");
    for file in [
        "objective.toml",
        "evaluations.csv",
        "search.csv",
        "stages.csv",
        "samples.csv",
        "posterior.toml",
        "best.toml",
        "fisher.toml",
        "calibrated.toml",
        "corner.png",
        "summary.json",
    ] {
        assert!(out_dir.join(file).is_file(), "{file} missing");
    }
    let search = std::fs::read_to_string(out_dir.join("search.csv")).unwrap();
    assert!(
        search.starts_with("generation,evaluations,horizon_s,best_log_likelihood")
            && search.lines().count() > 1,
        "{search}"
    );
    // The growing horizon: 0.02 s, 0.04 s, then the whole 0.05 s (an empty horizon).
    let horizons: Vec<&str> = search
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap())
        .collect();
    assert!(
        horizons[0] == "0.02" && horizons.contains(&"0.04") && horizons.last() == Some(&""),
        "{search}"
    );
    let samples = std::fs::read_to_string(out_dir.join("samples.csv")).unwrap();
    assert_eq!(samples.lines().count(), 1 + 8, "{samples}");
    for line in samples.lines().skip(1) {
        let value: f64 = line.parse().unwrap();
        assert!((1.0e4..=1.0e6).contains(&value), "{line}");
    }
    let log = std::fs::read_to_string(out_dir.join("evaluations.csv")).unwrap();
    assert!(
        log.starts_with("batch,candidate,k_tri_e,objective,loss,"),
        "{log}"
    );
    let posterior = std::fs::read_to_string(out_dir.join("posterior.toml")).unwrap();

    // Cut the log after its first two batches, as an interrupted run leaves it: the rerun serves
    // them again and ends where the whole run ended.
    let kept: Vec<&str> = log
        .lines()
        .filter(|l| {
            !l.starts_with("batch") && l.split(',').next().unwrap().parse::<usize>().unwrap() < 2
        })
        .collect();
    std::fs::write(
        out_dir.join("evaluations.csv"),
        format!("{}\n{}\n", log.lines().next().unwrap(), kept.join("\n")),
    )
    .unwrap();
    let again = rlpkg(&["calibrate", cfg.to_str().unwrap()]);
    assert!(again.status.success(), "{}", text(&again.stderr));
    assert_eq!(
        std::fs::read_to_string(out_dir.join("evaluations.csv")).unwrap(),
        log
    );
    assert_eq!(
        std::fs::read_to_string(out_dir.join("samples.csv")).unwrap(),
        samples
    );
    assert_eq!(
        std::fs::read_to_string(out_dir.join("posterior.toml")).unwrap(),
        posterior
    );

    // Another seed is another objective record: refused without --fresh.
    let other = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("seed = 4", "seed = 5");
    std::fs::write(&cfg, other).unwrap();
    let refused = rlpkg(&["calibrate", cfg.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused.stderr));
    assert!(
        text(&refused.stderr).contains("--fresh"),
        "{}",
        text(&refused.stderr)
    );
    let iterations = rlpkg(&[
        "calibrate",
        cfg.to_str().unwrap(),
        "--fresh",
        "--iterations",
        "3",
    ]);
    assert_eq!(iterations.status.code(), Some(2));
    assert!(text(&iterations.stderr).contains("smc.particles"));
}

#[test]
fn a_full_or_closed_stdout_neither_panics_nor_loses_the_posterior() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "train");
    let preset = quick_preset(dir.path());
    let cfg = posterior_config(dir.path(), &data, &preset);
    let out_dir = dir.path().join("posterior");
    // A full disk behind stdout: the work is done and written, then exit 2 naming stdout.
    let full = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(["calibrate", cfg.to_str().unwrap()])
        .stdout(std::fs::File::create("/dev/full").unwrap())
        .output()
        .unwrap();
    let stderr = text(&full.stderr);
    assert_eq!(full.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("standard output") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let samples = std::fs::read_to_string(out_dir.join("samples.csv")).unwrap();
    // A reader that went away (`| head`): the command finishes quietly with success.
    let mut child = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(["calibrate", cfg.to_str().unwrap(), "--fresh"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let closed = child.wait_with_output().unwrap();
    assert!(closed.status.success(), "{}", text(&closed.stderr));
    assert_eq!(
        std::fs::read_to_string(out_dir.join("samples.csv")).unwrap(),
        samples
    );
    // Help into a full stdout is an error too, not a silent success.
    let help = Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .arg("--help")
        .stdout(std::fs::File::create("/dev/full").unwrap())
        .output()
        .unwrap();
    assert_eq!(help.status.code(), Some(2), "{}", text(&help.stderr));
}

#[test]
fn a_calibration_folder_in_use_is_refused_and_a_stale_lock_taken_over() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 30, "train");
    let preset = quick_preset(dir.path());
    let cfg = config(dir.path(), &data, &preset, "");
    let out_dir = dir.path().join("out");
    let lock = out_dir.join(".lock");
    std::fs::create_dir(&out_dir).unwrap();
    // This test's own process holds the folder; a second command must leave it alone, `--fresh`
    // and leftovers included.
    let pid = std::process::id();
    std::fs::write(&lock, format!("{pid}\n")).unwrap();
    let writing = out_dir.join(".evaluations.csv.Ab12Cd");
    std::fs::write(&writing, "being written").unwrap();
    for fresh in [false, true] {
        let mut args = vec!["calibrate", cfg.to_str().unwrap()];
        if fresh {
            args.push("--fresh");
        }
        let refused = rlpkg(&args);
        let stderr = text(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains(&format!("{}: in use by process {pid}", out_dir.display())),
            "{stderr}"
        );
        assert_eq!(std::fs::read_to_string(&lock).unwrap(), format!("{pid}\n"));
        assert!(writing.exists());
        assert_eq!(std::fs::read_dir(&out_dir).unwrap().count(), 2);
    }

    // A process that has ended holds nothing: its lock is taken over with a notice.
    let mut child = Command::new("true").spawn().unwrap();
    let ended = child.id();
    child.wait().unwrap();
    std::fs::write(&lock, format!("{ended}\n")).unwrap();
    let out = rlpkg(&["calibrate", cfg.to_str().unwrap()]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "took over the stale lock {} of process {ended}, which no longer runs",
            lock.display()
        )),
        "{stderr}"
    );
    assert!(!writing.exists(), "a leftover of a command that has ended");
    assert!(!lock.exists(), "the lock outlived the command");
    assert!(out_dir.join("evaluations.csv").exists());
}
