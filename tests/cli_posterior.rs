//! End-to-end tests of `rlpkg posterior` through the binary, on a synthetic calibration folder: a
//! calibration config and an `evaluations.csv` in the exact format `rlpkg calibrate` writes, with a
//! loss that is sharp in `k_tri_e` (minimum at 1e4), does not depend on `k_edge_e`, and is mild in
//! `mu_con`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn rlpkg(args: &[&str], threads: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .env("RAYON_NUM_THREADS", threads)
        .output()
        .expect("run rlpkg")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The parameter box of the synthetic calibration: (name, lower, upper, log).
const BOX: [(&str, f64, f64, bool); 3] = [
    ("k_tri_e", 1e2, 1e6, true),
    ("k_edge_e", 1e-6, 1e-1, true),
    ("mu_con", 0.1, 2.0, false),
];

fn config(dir: &Path, params: &[(&str, f64, f64, bool)]) -> PathBuf {
    let mut body = format!(
        "data = \"data/deformable-sim-real\"\nout_dir = \"{}\"\n\n[sim]\npreset = \"reference\"\n\n\
         [optimiser]\niterations = 11\nbatch_size = 4\ninitial_points = 15\n",
        dir.join("calibration").display()
    );
    for (name, lower, upper, log) in params {
        body.push_str(&format!(
            "\n[[param]]\nname = \"{name}\"\nlower = {lower:e}\nupper = {upper:e}\nlog = {log}\n"
        ));
    }
    let path = dir.join("calibrate.toml");
    std::fs::write(&path, body).unwrap();
    path
}

/// A deterministic stream of numbers in [0, 1) (xorshift), so the test needs no random crate.
struct Stream(u64);

impl Stream {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `rows` evaluations in the log's format (batches of 4): half spread over the box, half crowded
/// near the optimum, as an optimiser's; the last one a diverged rollout (NaN).
fn evaluations(rows: usize) -> String {
    let mut stream = Stream(0x9e37_79b9_7f4a_7c15);
    let mut csv = String::from(
        "batch,candidate,k_tri_e,k_edge_e,mu_con,objective,loss,chamfer_m,object_mse_m2\n",
    );
    for i in 0..rows {
        let u0 = if i % 2 == 0 {
            stream.next()
        } else {
            0.4 + 0.2 * stream.next()
        };
        let unit = [u0, stream.next(), stream.next()];
        let values: Vec<f64> = BOX
            .iter()
            .zip(unit)
            .map(|(&(_, lower, upper, log), u)| {
                if log {
                    lower * (upper / lower).powf(u)
                } else {
                    lower + u * (upper - lower)
                }
            })
            .collect();
        let (objective, loss) = if i + 1 == rows {
            (f64::NAN, f64::NAN)
        } else {
            let loss = 0.01 * (1.0 + ((u0 - 0.5) / 0.05).powi(2) + 0.5 * (unit[2] - 0.3).powi(2));
            (loss.ln(), loss)
        };
        csv.push_str(&format!(
            "{},{},{},{},{},{objective},{loss},{},{}\n",
            i / 4,
            i % 4,
            values[0],
            values[1],
            values[2],
            loss / 2.0,
            loss / 20.0
        ));
    }
    csv
}

fn calibration(dir: &Path, rows: usize) -> PathBuf {
    let folder = dir.join("calibration");
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(folder.join("evaluations.csv"), evaluations(rows)).unwrap();
    folder
}

const QUICK: [&str; 4] = ["--samples", "1000", "--burn-in", "300"];

#[test]
fn help_lists_the_options() {
    let out = rlpkg(&["posterior", "--help"], "1");
    assert!(out.status.success());
    let help = text(&out.stdout);
    for word in [
        "--from",
        "--out",
        "--seed",
        "--samples",
        "--epsilon-quantile",
        "--epsilon-loss",
        "--burn-in",
        "--thin",
    ] {
        assert!(help.contains(word), "help lacks {word}:\n{help}");
    }
}

#[test]
fn writes_the_posterior_and_prints_the_identifiability_table() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), &BOX);
    let folder = calibration(dir.path(), 48);
    let mut args = vec!["posterior", cfg.to_str().unwrap()];
    args.extend(QUICK);
    let out = rlpkg(&args, "2");
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let row = |name: &str| {
        stdout
            .lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("no row for {name}:\n{stdout}"))
            .to_string()
    };
    assert!(row("k_tri_e").ends_with("yes"), "{stdout}");
    assert!(row("k_edge_e").ends_with("no"), "{stdout}");
    assert!(
        stdout.contains("48 evaluations (1 failed)") && stdout.contains("identified: "),
        "{stdout}"
    );

    // Default output folder: `posterior` in the calibration folder.
    let posterior = folder.join("posterior");
    let samples = std::fs::read_to_string(posterior.join("samples.csv")).unwrap();
    assert_eq!(samples.lines().next(), Some("k_tri_e,k_edge_e,mu_con"));
    assert_eq!(samples.lines().count(), 1 + 1000);
    for line in samples.lines().skip(1) {
        let values: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        for (v, (_, lower, upper, _)) in values.iter().zip(BOX) {
            assert!(*v >= lower && *v <= upper * (1.0 + 1e-12), "{line}");
        }
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(posterior.join("summary.json")).unwrap())
            .unwrap();
    let sharp = &summary["parameters"][0];
    assert_eq!(sharp["name"], "k_tri_e");
    assert_eq!(sharp["identified"], true);
    let interval: Vec<f64> = sharp["interval"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(interval[0] < 1e4 && 1e4 < interval[1], "{sharp}");
    assert_eq!(summary["parameters"][1]["identified"], false);
    assert!(summary["parameters"][2]["interval_decades"].is_null());
    assert_eq!(summary["evaluations"], 48);
    assert_eq!(summary["failed"], 1);
    let profiles = std::fs::read_to_string(posterior.join("profiles.csv")).unwrap();
    assert_eq!(
        profiles.lines().next(),
        Some("parameter,value,surrogate_loss")
    );
    assert_eq!(profiles.lines().count(), 1 + 3 * 21);

    // Same seed, one thread, another folder: the same draws.
    let elsewhere = dir.path().join("elsewhere");
    let mut args = vec![
        "posterior",
        cfg.to_str().unwrap(),
        "--from",
        folder.to_str().unwrap(),
        "--out",
        elsewhere.to_str().unwrap(),
    ];
    args.extend(QUICK);
    let out = rlpkg(&args, "1");
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        std::fs::read_to_string(elsewhere.join("samples.csv")).unwrap(),
        samples
    );
}

#[test]
fn bad_inputs_exit_with_2_naming_the_file_and_what_was_expected() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), &BOX);
    let log = dir.path().join("calibration").join("evaluations.csv");
    let fails_with = |args: &[&str], words: &[&str]| {
        let mut all = vec!["posterior", cfg.to_str().unwrap()];
        all.extend_from_slice(args);
        all.extend(QUICK);
        let out = rlpkg(&all, "1");
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        for word in words {
            assert!(err.contains(word), "`{word}` missing from: {err}");
        }
    };

    // No calibration yet.
    fails_with(&[], &["evaluations.csv", "not found", "rlpkg calibrate"]);
    assert!(!log.exists(), "the log is not created");

    // Too few evaluations for 3 parameters.
    calibration(dir.path(), 8);
    fails_with(&[], &["evaluations.csv", "expected at least 10"]);

    // A config whose box differs from the log's: other bounds, other parameters.
    calibration(dir.path(), 48);
    let mut narrow = BOX;
    narrow[0].2 = 1e5;
    config(dir.path(), &narrow);
    fails_with(&[], &["evaluations.csv", "k_tri_e", "outside its bounds"]);
    config(dir.path(), &BOX[..2]);
    fails_with(&[], &["evaluations.csv", "header", "expected"]);
    config(dir.path(), &BOX);

    // A finite loss logged with a non-finite objective.
    let edited = evaluations(48);
    let mut lines: Vec<String> = edited.lines().map(str::to_string).collect();
    let mut cells: Vec<String> = lines[3].split(',').map(str::to_string).collect();
    cells[5] = "inf".into();
    lines[3] = cells.join(",");
    std::fs::write(&log, lines.join("\n") + "\n").unwrap();
    fails_with(
        &[],
        &["evaluations.csv", "candidate 2", "`objective` = inf"],
    );

    // Out-of-range options.
    calibration(dir.path(), 48);
    fails_with(
        &["--epsilon-quantile", "1.5"],
        &["--epsilon-quantile", "(0, 1)"],
    );
    fails_with(&["--epsilon-loss=-1"], &["--epsilon-loss", "> 0"]);
    // A threshold no evaluation meets would leave only the surrogate's extrapolation.
    fails_with(
        &["--epsilon-loss", "1e-30"],
        &[
            "evaluations.csv",
            "below the best loss",
            "expected a loss >=",
        ],
    );
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
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

/// The study's scene on the coarsest grid (6 x 7) with a 0.2 s rest period instead of 2 s.
fn quick_preset(dir: &Path) -> PathBuf {
    let reference = std::fs::read_to_string(repo().join("configs/scenes/study.toml")).unwrap();
    let path = dir.join("quick.toml");
    let quick = reference
        .replace("rest_time_s = 2.0", "rest_time_s = 0.2")
        .replace("grid = [21, 25]", "grid = [6, 7]")
        // The disc slips through the 6 x 7 sheet; these tests are about the machinery.
        .replace("[health]", "[health]\nobject_outside = false");
    assert_ne!(quick, reference);
    std::fs::write(&path, quick).unwrap();
    path
}

/// A calibration config of the box `params` on the quick scene and a dataset of `frames` frames
/// of HHHHH in split `split`: (dataset, preset, config).
fn quick_config(
    dir: &Path,
    frames: usize,
    split: &str,
    params: &[(&str, f64, f64, bool)],
) -> (PathBuf, PathBuf, PathBuf) {
    let data = small_dataset(dir, frames, split);
    let preset = quick_preset(dir);
    let cfg = config(dir, params);
    let body = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("data/deformable-sim-real", data.to_str().unwrap())
        .replace(
            "preset = \"reference\"",
            &format!("preset = {:?}\nbetween = 0", preset.to_str().unwrap()),
        );
    std::fs::write(&cfg, body).unwrap();
    (data, preset, cfg)
}

/// The synthetic calibration's box on the quick scene and a 30-frame dataset in split `split`, with
/// its posterior made: (dataset, preset, calibration config, calibration folder).
fn quick_posterior(dir: &Path, split: &str) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let (data, preset, cfg) = quick_config(dir, 30, split, &BOX);
    let folder = calibration(dir, 48);
    let mut args = vec!["posterior", cfg.to_str().unwrap()];
    args.extend(QUICK);
    let out = rlpkg(&args, "2");
    assert!(out.status.success(), "{}", text(&out.stderr));
    (data, preset, cfg, folder)
}

#[test]
fn eval_of_a_posterior_gives_the_posterior_predictive_table_1() {
    let dir = tempfile::tempdir().unwrap();
    let (data, preset, cfg, folder) = quick_posterior(dir.path(), "test");
    let summary_path = folder.join("posterior").join("summary.json");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary_path).unwrap()).unwrap();
    assert_eq!(summary["config"], cfg.to_str().unwrap());

    let eval = |params: &Path, draws: &str, out: &Path| {
        let output = rlpkg(
            &[
                "eval",
                "--params",
                params.to_str().unwrap(),
                "--draws",
                draws,
                "--data",
                data.to_str().unwrap(),
                "--split",
                "test",
                "--out",
                out.to_str().unwrap(),
                "--json",
            ],
            "2",
        );
        assert!(output.status.success(), "{}", text(&output.stderr));
        serde_json::from_slice::<serde_json::Value>(&output.stdout).unwrap()
    };
    let four = eval(&summary_path, "4", &dir.path().join("eval4"));
    let row = &four["table1"][0];
    assert_eq!(row["split"], "test");
    assert_eq!(
        row["draws"].as_u64().unwrap() + row["diverged_draws"].as_u64().unwrap(),
        4
    );
    assert!(row["draws"].as_u64().unwrap() >= 2, "{row}");
    for column in ["chamfer_mean_m", "chamfer_max_m", "object_mse_mean_m2"] {
        let band = &row[column];
        let [low, median, high] = ["low", "median", "high"].map(|k| band[k].as_f64().unwrap());
        assert!(
            low <= median && median <= high && low > 0.0,
            "{column}: {band}"
        );
    }
    let per_draw = four["per_draw"].as_array().unwrap();
    assert_eq!(per_draw.len(), 4);
    assert_eq!(per_draw[0][0]["frames"], 30);
    let means: Vec<f64> = per_draw
        .iter()
        .map(|d| d[0]["chamfer_m"]["mean"].as_f64().unwrap())
        .collect();
    assert!(
        means.iter().any(|m| *m != means[0]),
        "the draws differ: {means:?}"
    );
    assert_eq!(four["draw_rows"], serde_json::json!([0, 250, 500, 750]));
    // The samples file names the same posterior; one draw alone replays as in the batch.
    let samples_path = folder.join("posterior").join("samples.csv");
    let one = eval(&samples_path, "1", &dir.path().join("eval1"));
    assert_eq!(one["per_draw"][0], per_draw[0]);

    // A scene file still gives the plain Table 1 and refuses --draws.
    let refused = rlpkg(
        &[
            "eval",
            "--params",
            preset.to_str().unwrap(),
            "--draws",
            "4",
            "--data",
            data.to_str().unwrap(),
        ],
        "1",
    );
    assert_eq!(refused.status.code(), Some(2));
    assert!(text(&refused.stderr).contains("--draws"));
    // A posterior folder without its summary names what is missing.
    std::fs::remove_file(&summary_path).unwrap();
    let missing = rlpkg(
        &[
            "eval",
            "--params",
            samples_path.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
        ],
        "1",
    );
    assert_eq!(missing.status.code(), Some(2));
    assert!(
        text(&missing.stderr).contains("summary.json"),
        "{}",
        text(&missing.stderr)
    );
}

#[test]
fn recover_prints_the_recovery_table() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_dataset(dir.path(), 48, "train");
    let preset = quick_preset(dir.path());
    // The membrane stiffness acts on the package; the cup damping does not act within 0.2 s.
    let cfg = config(
        dir.path(),
        &[("k_tri_e", 1e3, 1e6, true), ("k_cup_d", 1e-3, 1e1, true)],
    );
    let body = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("data/deformable-sim-real", data.to_str().unwrap())
        .replace(
            "preset = \"reference\"",
            &format!("preset = {:?}\nbetween = 0", preset.to_str().unwrap()),
        )
        .replace("initial_points = 15", "initial_points = 8");
    std::fs::write(&cfg, body).unwrap();
    let out_dir = dir.path().join("recovery");
    let mut args = vec![
        "posterior",
        cfg.to_str().unwrap(),
        "--recover",
        "1",
        "--iterations",
        "3",
        "--out",
        out_dir.to_str().unwrap(),
    ];
    args.extend(QUICK);
    let out = rlpkg(&args, "2");
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let row = |name: &str| {
        stdout
            .lines()
            .find(|l| l.starts_with(&format!("0      {name}")))
            .unwrap_or_else(|| panic!("no row for {name}:\n{stdout}"))
            .to_string()
    };
    assert!(row("k_tri_e").ends_with("yes"), "{stdout}");
    assert!(row("k_cup_d").contains("not determined"), "{stdout}");
    assert!(stdout.contains("marker noise"), "{stdout}");
    let recovery: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("recovery.json")).unwrap())
            .unwrap();
    let truth = &recovery["truths"][0];
    assert_eq!(truth["parameters"][1]["identified"], false);
    assert!(truth["parameters"][1]["relative_error"].is_null());
    assert!(out_dir.join("truth-0").join("evaluations.csv").exists());
}

#[test]
fn validate_replays_draws_and_keeps_those_within_the_threshold() {
    let dir = tempfile::tempdir().unwrap();
    let (data, _, cfg, _) = quick_posterior(dir.path(), "train");

    let validate = |epsilon: &str, out: &Path, threads: &str| {
        let output = rlpkg(
            &[
                "posterior",
                cfg.to_str().unwrap(),
                "--validate",
                "6",
                "--epsilon-loss",
                epsilon,
                "--out",
                out.to_str().unwrap(),
            ],
            threads,
        );
        assert!(output.status.success(), "{}", text(&output.stderr));
        text(&output.stdout)
    };
    // A threshold no replay reaches keeps every draw that did not diverge.
    let all = dir.path().join("all");
    let printed = validate("1e9", &all, "1");
    assert!(printed.contains("replayed draws"), "{printed}");
    let replayed = std::fs::read_to_string(all.join("replayed.csv")).unwrap();
    let rows: Vec<Vec<&str>> = replayed
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 6);
    // Rows of the posterior's 1000 draws, evenly spaced; the loss is the 5th column after the row.
    let draw_rows: Vec<&str> = rows.iter().map(|r| r[0]).collect();
    assert_eq!(draw_rows, ["0", "166", "333", "500", "666", "833"]);
    let losses: Vec<f64> = rows.iter().map(|r| r[4].parse().unwrap()).collect();
    let finite: Vec<f64> = losses.iter().copied().filter(|l| l.is_finite()).collect();
    assert!(finite.len() >= 4, "{losses:?}");
    assert!(finite.iter().all(|l| *l > 0.0));
    assert!(
        finite.iter().any(|l| *l != finite[0]),
        "the draws differ: {losses:?}"
    );

    // The median as the threshold keeps exactly the draws at or below it, with their values, and
    // the replay does not depend on the number of threads.
    let mut sorted = finite.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[(sorted.len() - 1) / 2];
    let half = dir.path().join("half");
    validate(&format!("{median:e}"), &half, "2");
    let again = std::fs::read_to_string(half.join("replayed.csv")).unwrap();
    let again_losses: Vec<&str> = again
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(4).unwrap())
        .collect();
    let first_losses: Vec<&str> = rows.iter().map(|r| r[4]).collect();
    assert_eq!(again_losses, first_losses);
    let kept_values: Vec<String> = rows
        .iter()
        .zip(&losses)
        .filter(|(_, l)| **l <= median)
        .map(|(r, _)| r[1..4].join(","))
        .collect();
    let samples = std::fs::read_to_string(half.join("samples.csv")).unwrap();
    let mut lines = samples.lines();
    assert_eq!(lines.next(), Some("k_tri_e,k_edge_e,mu_con"));
    assert_eq!(lines.collect::<Vec<_>>(), kept_values);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(half.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["config"], cfg.to_str().unwrap());
    assert_eq!(summary["validation"]["replayed"], 6);
    assert_eq!(summary["validation"]["kept"], kept_values.len());
    assert_eq!(
        summary["validation"]["parameters"]
            .as_array()
            .unwrap()
            .len(),
        3
    );
    // The kept draws are a posterior `eval --params` takes.
    let eval = rlpkg(
        &[
            "eval",
            "--params",
            half.join("samples.csv").to_str().unwrap(),
            "--draws",
            "1",
            "--data",
            data.to_str().unwrap(),
            "--split",
            "train",
            "--out",
            dir.path().join("eval").to_str().unwrap(),
            "--json",
        ],
        "2",
    );
    assert!(eval.status.success(), "{}", text(&eval.stderr));

    // The replays join the calibration's evaluations in a refitted posterior.
    let replayed_csv = all.join("replayed.csv");
    let refit = dir.path().join("refit");
    let mut args = vec![
        "posterior",
        cfg.to_str().unwrap(),
        "--replays",
        replayed_csv.to_str().unwrap(),
        "--out",
        refit.to_str().unwrap(),
    ];
    args.extend(QUICK);
    let out = rlpkg(&args, "2");
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("with 6 replayed draws"),
        "{}",
        text(&out.stdout)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(refit.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["evaluations"], 48 + 6);
    assert_eq!(summary["replays"][0], replayed_csv.to_str().unwrap());
    // Bad input exits with 2 naming the file and what was expected.
    let refused = |args: &[&str], expected: &[&str]| {
        let mut all = vec!["posterior", cfg.to_str().unwrap()];
        all.extend_from_slice(args);
        let out = rlpkg(&all, "1");
        assert_eq!(out.status.code(), Some(2));
        for e in expected {
            assert!(text(&out.stderr).contains(e), "{e}: {}", text(&out.stderr));
        }
    };
    // A replay file of other parameters, or with a value outside the box, is refused by line.
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "row,k_tri_e,loss\n0,1e3,0.1\n").unwrap();
    refused(
        &["--replays", bad.to_str().unwrap()],
        &["bad.csv", "header"],
    );
    let header = replayed.lines().next().unwrap();
    std::fs::write(
        &bad,
        format!(
            "{header}\n0,1e3,1e-3,0.5,0.1,0.05,0.001,true\n0,1e9,1e-3,0.5,0.1,0.05,0.001,true\n"
        ),
    )
    .unwrap();
    refused(
        &["--replays", bad.to_str().unwrap()],
        &["bad.csv: line 3", "k_tri_e"],
    );
    // A folder without a posterior is named, and nothing is written.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let empty_path = empty.to_str().unwrap();
    refused(
        &["--validate", "2", "--posterior", empty_path],
        &["summary.json"],
    );
    assert!(!empty.join("validated").exists());
    // More draws than the posterior holds.
    refused(
        &["--validate", "1001", "--out", empty_path],
        &["--validate 1001"],
    );
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);
}

#[test]
fn spread_prints_how_far_nudged_replays_move_beside_the_noise() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, cfg) = quick_config(dir.path(), 48, "train", &[("k_tri_e", 1e3, 1e6, true)]);
    let out = rlpkg(
        &["posterior", cfg.to_str().unwrap(), "--spread", "1e-3"],
        "2",
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let mm = |name: &str| -> Vec<f64> {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no row for {name}:\n{stdout}"));
        line.split_whitespace()
            .skip(1)
            .map(|v| v.parse().unwrap())
            .collect()
    };
    // One parameter: nudging it alone and nudging all of them are the same replays.
    let alone = mm("k_tri_e");
    assert_eq!(alone, mm("all"), "{stdout}");
    assert!(
        alone[0] <= alone[1] && alone[1] <= alone[2] && alone[2] > 0.0,
        "{stdout}"
    );
    assert!(
        stdout.contains("marker noise of the recordings"),
        "{stdout}"
    );

    let bad = rlpkg(&["posterior", cfg.to_str().unwrap(), "--spread", "0"], "2");
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad.stderr));
    assert!(
        text(&bad.stderr).contains("--spread 0"),
        "{}",
        text(&bad.stderr)
    );
}
