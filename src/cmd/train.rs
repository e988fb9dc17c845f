//! `rlpkg train` (being written).

use clap::Args;

#[derive(Args)]
pub struct TrainArgs {}

pub fn run(_args: TrainArgs) -> anyhow::Result<()> {
    anyhow::bail!("rlpkg train is not available yet")
}
