//! `rlpkg simulate` (being written).

use clap::Args;

#[derive(Args)]
pub struct SimulateArgs {}

pub fn run(_args: SimulateArgs) -> anyhow::Result<()> {
    anyhow::bail!("rlpkg simulate is not available yet")
}
