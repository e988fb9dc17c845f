//! `rlpkg export` (being written).

use clap::Args;

#[derive(Args)]
pub struct ExportArgs {}

pub fn run(_args: ExportArgs) -> anyhow::Result<()> {
    anyhow::bail!("rlpkg export is not available yet")
}
