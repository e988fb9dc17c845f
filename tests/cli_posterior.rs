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
}
