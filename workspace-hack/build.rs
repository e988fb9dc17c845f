//! Empty: without a build script Cargo ignores the build-dependencies in Cargo.toml.

fn main() {}
