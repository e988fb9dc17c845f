//! Helpers shared by the end-to-end tests on the packages-v1 takes (`data/packages-v1/`).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A take of the training split.
pub const TRAIN_TAKE: &str = "a30_m0.5_high";
/// A take the collection flags `failure: true` (a seal partly failed).
pub const FAILURE_TAKE: &str = "a45_m1.0_high";

/// Runs the binary with `args`.
pub fn rlpkg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

/// The repository (the binary crate's folder).
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A file of the packages-v1 collection, as a command-line argument.
pub fn package_file(name: &str) -> String {
    repo()
        .join("data/packages-v1")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

/// Command output as text.
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Imports the two takes ([`TRAIN_TAKE`], [`FAILURE_TAKE`]) with `manifest`'s split into `out`.
pub fn import(out: &Path, manifest: &str) -> Output {
    rlpkg(&[
        "data",
        "import-motive",
        &package_file(&format!("{TRAIN_TAKE}.csv.gz")),
        &package_file(&format!("{FAILURE_TAKE}.csv.gz")),
        "--robot",
        &package_file(&format!("{TRAIN_TAKE}_robot.csv")),
        &package_file(&format!("{FAILURE_TAKE}_robot.csv")),
        "--manifest",
        manifest,
        "--config",
        repo()
            .join("configs/import/packages-v1.toml")
            .to_str()
            .unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}
