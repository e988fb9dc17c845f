//! `rlpkg scene ...`: scene configs from a package's description.
//!
//! `from-manifest` turns a take collection's `manifest.json` (see `data/packages-v1/README.md`) into
//! a scene TOML ([`rlpkg_replay::package_scene`]): the geometry from the manifest, every other
//! value copied from a base scene and marked `# assumption:` in the file.

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use rlpkg_mocap::description::PackageDescription;
use rlpkg_replay::package_scene::{package_scene, PackageSceneError};
use rlpkg_sim::SceneConfig;

use crate::error::input_error;

/// Scene subcommands.
#[derive(Subcommand)]
pub enum SceneCommand {
    /// Write a scene config from a take collection's manifest.json: grid with a particle at every
    /// marker site, package size / thickness / film mass, cups, disc; everything the manifest does
    /// not give is copied from --base and marked `# assumption:`.
    FromManifest(FromManifestArgs),
}

/// Arguments of `rlpkg scene from-manifest`.
#[derive(Args)]
pub struct FromManifestArgs {
    /// The collection's manifest.json (e.g. data/packages-v1/manifest.json).
    pub manifest: PathBuf,
    /// Scene TOML to write (replaced whole if it exists).
    #[arg(long)]
    pub out: PathBuf,
    /// Scene whose values fill in what the manifest does not give (material parameters, contact,
    /// solver, substep rate, seal, health, tool limits, cup mesh resolution).
    #[arg(long, default_value = DEFAULT_BASE)]
    pub base: PathBuf,
    /// Largest grid (vertices along one side) tried when looking for a lattice through every
    /// marker site (2 to 1000: a search beyond would only take longer to say there is none).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u64).range(2..=1000))]
    pub max_vertices: u64,
}

/// The scene the transport task trains on: its calibrated soft-film parameters, block descent at
/// 300 substeps/s.
const DEFAULT_BASE: &str = "configs/scenes/calibrated-coarse-soft-film.toml";

/// Runs a scene subcommand.
pub fn run(command: SceneCommand) -> anyhow::Result<()> {
    match command {
        SceneCommand::FromManifest(args) => from_manifest(args),
    }
}

fn from_manifest(args: FromManifestArgs) -> anyhow::Result<()> {
    // The scene written must replace neither file it is built from.
    crate::files::check_not_input(
        "--out",
        &args.out,
        &[
            crate::files::Input::File(&args.manifest, "the manifest"),
            crate::files::Input::File(&args.base, "the base scene (--base)"),
        ],
    )?;
    if args.out.is_dir() {
        return Err(input_error(format!(
            "{}: is a folder; expected the path of the scene TOML to write (--out)",
            args.out.display()
        )));
    }
    let description = PackageDescription::load(&args.manifest).map_err(input_error)?;
    let base = SceneConfig::load(&args.base)
        .map_err(|e| input_error(format!("--base {}: {e}", args.base.display())))?;
    let base_name = args.base.display().to_string();
    let mut command = format!(
        "rlpkg scene from-manifest {} --out {}",
        args.manifest.display(),
        args.out.display()
    );
    if args.base != Path::new(DEFAULT_BASE) {
        command += &format!(" --base {base_name}");
    }
    let built = package_scene(
        &description,
        base,
        &base_name,
        args.max_vertices as usize,
        &command,
        &args.out.display().to_string(),
    )
    .map_err(|e| match e {
        PackageSceneError::Manifest(_) => input_error(e),
        PackageSceneError::Render(_) => anyhow::Error::new(e),
    })?;
    crate::files::write_atomic(&args.out, built.text.as_bytes()).map_err(input_error)?;
    println!(
        "wrote {}: grid {} x {} ({} particles per layer; marker sites on vertices within {:.3} mm), {} cups on a {} m circle, film {} kg, disc {} x {} m; {} values marked as assumptions (from {base_name})",
        args.out.display(),
        built.scene.package.grid[0],
        built.scene.package.grid[1],
        built.scene.package.grid[0] * built.scene.package.grid[1],
        1e3 * built.max_site_offset_m,
        built.scene.cups.angles_deg.len(),
        built.scene.cups.circle_radius_m,
        description.package.film_mass_kg,
        2.0 * built.scene.disc.radius_m,
        built.scene.disc.thickness_m,
        built.assumptions,
    );
    Ok(())
}
