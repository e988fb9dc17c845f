//! End-to-end test of `rlpkg seal fit` through the binary: two imported packages-v1 takes (one
//! failure take, one not), a two-capacity grid on a short replay; and a bad key that must exit
//! with code 2 naming it.

use std::fs;
use std::path::Path;

mod packages_v1;

use packages_v1::{import, package_file, repo, rlpkg, text, FAILURE_TAKE, TRAIN_TAKE};

/// A seal fit config on `dataset` writing to `out`: two vacuum values, the first 0.6 s of each take (the lift starts at 0.3 s).
fn config(dataset: &Path, out: &Path) -> String {
    format!(
        "dataset = {:?}\nscene = {:?}\nout = {:?}\nmax_seconds = 0.6\n\n[grid]\n\
         vacuum_kpa = {{ min = 0.05, max = 30.0, steps = 2 }}\n\n[detachment]\nthreshold_m = 0.01\n",
        dataset.to_string_lossy(),
        repo()
            .join("configs/scenes/packages-v1.toml")
            .to_string_lossy(),
        out.to_string_lossy()
    )
}

#[test]
fn seal_fit_runs_on_two_takes_and_writes_the_table() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("dataset");
    let imported = import(&dataset, &package_file("manifest.json"));
    assert!(imported.status.success(), "{}", text(&imported.stderr));
    let out = dir.path().join("seal");
    let path = dir.path().join("seal.toml");
    fs::write(&path, config(&dataset, &out)).unwrap();
    let scene = dir.path().join("fitted.toml");
    let result = rlpkg(&[
        "seal",
        "fit",
        &path.to_string_lossy(),
        "--write-params",
        &scene.to_string_lossy(),
    ]);
    let stdout = text(&result.stdout);
    assert!(
        result.status.success(),
        "{stdout}\n{}",
        text(&result.stderr)
    );
    assert!(stdout.contains("flagged failure"), "{stdout}");

    let candidates = fs::read_to_string(out.join("candidates.csv")).unwrap();
    let rows: Vec<&str> = candidates.lines().collect();
    assert_eq!(rows.len(), 3, "header and two capacities: {candidates}");
    assert!(rows[0].starts_with("vacuum_kpa,lip_strength_ratio,balanced_agreement,agreement"));
    // 0.05 kPa holds 0.06 N per cup: the package cannot be lifted, a cup fails on both takes.
    let weak: Vec<&str> = rows[1].split(',').collect();
    assert_eq!(weak[0], "0.05");
    assert_eq!(weak[3], "1", "agrees on the failure take only: {}", rows[1]);
    // Every flagged take failed, no unflagged one held: (1 + 0) / 2.
    assert_eq!(weak[2], "0.5000", "{}", rows[1]);
    assert_eq!(weak[4..8], ["1", "0", "1", "0"]);

    let takes = fs::read_to_string(out.join("takes.csv")).unwrap();
    assert_eq!(takes.lines().count(), 3, "{takes}");
    assert!(
        takes.contains(&format!("{FAILURE_TAKE},excluded,true")),
        "{takes}"
    );
    assert!(
        takes.contains(&format!("{TRAIN_TAKE},train,false")),
        "{takes}"
    );

    let fit = fs::read_to_string(out.join("fit.toml")).unwrap();
    let fit: toml::Table = toml::from_str(&fit).unwrap();
    let confusion = fit["confusion"].as_table().unwrap();
    let cells: i64 = [
        "flagged_failed",
        "flagged_held",
        "unflagged_failed",
        "unflagged_held",
    ]
    .iter()
    .map(|k| confusion[*k].as_integer().unwrap())
    .sum();
    assert_eq!(cells + fit["diverged"].as_integer().unwrap(), 2);
    // The fitted scene loads and carries the fitted vacuum.
    let fitted = rlpkg_sim::SceneConfig::load(&scene).unwrap();
    assert_eq!(
        fitted.seal.vacuum_kpa,
        fit["vacuum_kpa"].as_float().unwrap() as f32
    );
    assert_eq!(
        fs::read_to_string(&scene).unwrap(),
        fs::read_to_string(out.join("scene.toml")).unwrap()
    );
}

#[test]
fn a_bad_key_exits_2_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("dataset");
    let out = dir.path().join("seal");
    let good = config(&dataset, &out);
    for (bad, key) in [
        (
            good.replace("steps = 2", "steps = 0"),
            "grid.vacuum_kpa.steps",
        ),
        (
            good.replace("min = 0.05", "min = -1.0"),
            "grid.vacuum_kpa.min",
        ),
        (
            good.replace("threshold_m = 0.01", "threshold_m = 0.0"),
            "detachment.threshold_m",
        ),
        (good.replace("max_seconds", "max_second"), "max_second"),
        (good.replace("threshold_m", "treshold_m"), "treshold_m"),
    ] {
        let path = dir.path().join("seal.toml");
        fs::write(&path, &bad).unwrap();
        let result = rlpkg(&["seal", "fit", &path.to_string_lossy()]);
        let stderr = text(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{key}: {stderr}");
        assert!(stderr.contains(key), "{key}: {stderr}");
        assert!(!out.exists(), "nothing written for {key}");
    }
}
