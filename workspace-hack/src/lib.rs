//! No code. A dependency of the `rlpkg` binary whose Cargo.toml enables the dependency features
//! that only the rest of the workspace (the Python module, dev-dependencies) would, so that
//! `cargo build --release` and `cargo test --release --workspace` resolve every shared crate with
//! the same features and compile it once for both.

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;
    use std::path::Path;
    use std::process::Command;

    /// The packages `cargo tree` resolves for this machine's target, one
    /// `name version [(path)] features` line each, for a package selection and dependency kinds.
    fn resolved_packages(selection_and_edges: &[&str]) -> BTreeSet<String> {
        let workspace_root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .expect("the workspace-hack folder is in the workspace root");
        let output = Command::new(env!("CARGO"))
            .current_dir(workspace_root)
            .args([
                "tree", "--locked", "--prefix", "none", "--format", "{p} {f}",
            ])
            .args(selection_and_edges)
            .output()
            .expect("cargo runs");
        assert!(
            output.status.success(),
            "cargo tree {selection_and_edges:?} failed:\n{}",
            String::from_utf8_lossy(&output.stderr)
        );
        String::from_utf8(output.stdout)
            .expect("cargo tree prints UTF-8")
            .lines()
            .map(|line| line.trim_end_matches(" (*)").to_owned())
            .collect()
    }

    #[test]
    fn the_binary_alone_resolves_the_features_of_the_workspace_test_build() {
        let binary = resolved_packages(&["--package", "rlpkg", "--edges", "normal,build"]);
        let workspace_tests = resolved_packages(&["--workspace", "--edges", "normal,build,dev"]);
        let differing: Vec<String> = binary
            .difference(&workspace_tests)
            .map(|line| {
                let name_and_version: String =
                    line.split(' ').take(2).collect::<Vec<_>>().join(" ") + " ";
                let in_tests: Vec<&String> = workspace_tests
                    .iter()
                    .filter(|test_line| test_line.starts_with(&name_and_version))
                    .collect();
                format!("binary: {line}\n  tests: {in_tests:?}")
            })
            .collect();
        assert!(
            differing.is_empty(),
            "these crates would compile twice; enable the test build's features of them in \
             workspace-hack/Cargo.toml:\n{}",
            differing.join("\n")
        );
    }
}
