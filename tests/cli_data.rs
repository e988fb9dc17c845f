//! End-to-end tests of `rlpkg data import-motive` through the binary.

use std::path::{Path, PathBuf};
use std::process::Command;

use rlpkg_mocap::{Dataset, Split};

fn rlpkg(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn fixture(name: &str) -> String {
    root()
        .join("mocap/tests/fixtures")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn config() -> String {
    root()
        .join("configs/import.toml")
        .to_string_lossy()
        .into_owned()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn importing_a_take_writes_a_loadable_dataset_and_reports_retention() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("takes");
    let out_arg = out.to_str().unwrap();
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        out_arg,
        "--config",
        &config(),
    ]);
    let stdout = text(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", text(&run.stderr));
    assert!(
        stdout.contains("a30_m0.5_high_excerpt: frames kept 250 of 250 (100.0 %) at 250 Hz"),
        "{stdout}"
    );
    assert!(stdout.contains("marker samples kept"), "{stdout}");
    for file in ["tool.csv", "object.csv", "markers.csv", "meta.toml"] {
        assert!(
            out.join("a30_m0.5_high_excerpt").join(file).is_file(),
            "{file} missing"
        );
    }
    let dataset = Dataset::open(&out).unwrap();
    assert_eq!(dataset.ids(None), vec!["a30_m0.5_high_excerpt"]);
    assert_eq!(dataset.entries[0].split, Split::Train);
    assert_eq!(dataset.entries[0].frames, 250);
    let trajectory = dataset.load("a30_m0.5_high_excerpt").unwrap();
    assert_eq!(trajectory.tool.t.len(), 250);
    assert_eq!(trajectory.markers.len(), 250);
    assert!(trajectory.meta.initial_marker_positions_m.len() >= 20);

    // A second import into the same folder keeps the first entry.
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt_mm.csv.gz"),
        "--out",
        out_arg,
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let dataset = Dataset::open(&out).unwrap();
    assert_eq!(
        dataset.ids(None),
        vec!["a30_m0.5_high_excerpt", "a30_m0.5_high_excerpt_mm"]
    );
}

#[test]
fn a_malformed_take_exits_with_2_naming_file_and_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad_take.csv");
    // A small take whose line 9 (frame 1) has a garbled time cell.
    let take = "Format Version,1.23,Take Name,bad,Capture Frame Rate,100,Export Frame Rate,100,Rotation Type,Quaternion,Length Units,Meters\n\n\
,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker\n\
,Name,Tool,Tool,Tool,Tool,Tool,Tool,Tool,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000\n\
,ID,1,1,1,1,1,1,1,1000,1000,1000\n\
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Position,Position,Position\n\
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,X,Y,Z\n\
0,0.00,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n\
1,0.0o4,0,0,0,1,0.1,0.2,0.3,0.4,0.5,0.6\n";
    std::fs::write(&bad, take).unwrap();
    let out = dir.path().join("out");
    let run = rlpkg(&[
        "data",
        "import-motive",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(2));
    let stderr = text(&run.stderr);
    assert!(
        stderr.contains("bad_take.csv: line 9, column 2: expected a number, found '0.0o4'"),
        "{stderr}"
    );
    assert!(!out.exists());
}

#[test]
fn a_bad_config_exits_with_2_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("import.toml");
    std::fs::write(&config, "[cleaning]\nfilter_order = 40\n").unwrap();
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        dir.path().join("out").to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(2));
    let stderr = text(&run.stderr);
    assert!(
        stderr.contains("import.toml")
            && stderr.contains("cleaning.filter_order = 40: expected 1..=10"),
        "{stderr}"
    );
}

#[test]
fn excluded_takes_are_reported_but_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("import.toml");
    std::fs::write(
        &config,
        "[takes]\n\"a30_m0.5_high_excerpt\" = { exclude = true }\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let run = rlpkg(&[
        "data",
        "import-motive",
        &fixture("a30_m0.5_high_excerpt.csv.gz"),
        "--out",
        out.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    assert!(text(&run.stdout).contains("[excluded by config, not written]"));
    assert!(!Path::new(&out.join("a30_m0.5_high_excerpt")).exists());
    assert!(Dataset::open(&out).unwrap().entries.is_empty());
}
