//! Set-ups the crate's tests share.

use rlpkg_mocap::Trajectory;

/// The study's recording `id` from the repository's `data/deformable-sim-real`.
pub(crate) fn recorded(id: &str) -> Trajectory {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
    rlpkg_mocap::Dataset::open(&root).unwrap().load(id).unwrap()
}
