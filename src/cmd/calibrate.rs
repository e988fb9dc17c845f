//! `rlpkg calibrate` (being written).

use clap::Args;

#[derive(Args)]
pub struct CalibrateArgs {}

pub fn run(_args: CalibrateArgs) -> anyhow::Result<()> {
    anyhow::bail!("rlpkg calibrate is not available yet")
}
