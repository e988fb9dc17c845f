//! A scene from a take collection's `manifest.json` (see `data/packages-v1/README.md`,
//! [`rlpkg_mocap::description`]), as `rlpkg scene from-manifest` writes it: the grid is the
//! smallest regular lattice with a vertex at every marker site, the package size, thickness and
//! film mass, the cup circle and angles, the cup ring and lip radii and the disc size come from the
//! manifest; every other value (stiffness parameters, contact, solver, substep rate, seal, ...) is
//! copied from a base scene and marked `# assumption:` in the text.
//!
//! It lives beside the replay set-up because it maps the recording's frames (robot, mocap, tool)
//! onto the simulator's, as [`crate::seal::cup_centres_in_tool_frame`] maps them back.

use std::collections::BTreeMap;

use rlpkg_mocap::description::{PackageDescription, KG_PER_LB};
use rlpkg_sim::SceneConfig;

/// What stops a scene being built from a manifest.
#[derive(Debug, thiserror::Error)]
pub enum PackageSceneError {
    /// The manifest's values make no scene on the base (the message names the file and keys).
    #[error("{0}")]
    Manifest(String),
    /// The scene could not be written as TOML.
    #[error("{0}")]
    Render(String),
}

/// A scene built from a manifest, as text and as loaded back.
#[derive(Debug, Clone)]
pub struct PackageScene {
    /// The scene (what [`PackageScene::text`] loads as).
    pub scene: SceneConfig,
    /// The TOML: a header, then every key preceded by where it came from.
    pub text: String,
    /// Keys copied from the base scene.
    pub assumptions: usize,
    /// Largest distance of a marker site to its grid vertex (m).
    pub max_site_offset_m: f64,
}

/// A marker site counts as on a vertex within this distance (m): the manifest gives sites to 10 um.
const SITE_TOLERANCE_M: f64 = 1e-5;

/// The scene of `description` on `base` (named `base_name` in the text and in messages), on a
/// lattice of at most `max_vertices` per side; `command` is named in the header as what generated
/// it and `destination` names the file in a message when the text does not load back.
pub fn package_scene(
    description: &PackageDescription,
    base: SceneConfig,
    base_name: &str,
    max_vertices: usize,
    command: &str,
    destination: &str,
) -> Result<PackageScene, PackageSceneError> {
    let built = build_scene(description, base, max_vertices)?;
    let (text, assumptions) = render(description, &built, base_name, command)?;
    // The file must load as it is written: check the text itself.
    SceneConfig::from_toml_str(&text, destination).map_err(|e| {
        PackageSceneError::Manifest(format!(
            "{}: the scene built from it and --base {base_name} does not load ({e}); expected manifest values that fit the base scene's",
            description.path.display()
        ))
    })?;
    Ok(PackageScene {
        scene: built.scene,
        text,
        assumptions,
        max_site_offset_m: built.max_site_offset_m,
    })
}

/// A scene built from a description, with where each manifest-derived value came from.
struct BuiltScene {
    scene: SceneConfig,
    /// `section.key` -> the manifest keys (and conversion) it came from.
    from_manifest: BTreeMap<&'static str, String>,
    /// Largest distance of a marker site to its grid vertex (m).
    max_site_offset_m: f64,
}

/// The smallest vertex count `n` in `2..=max` of a regular lattice over `[-length/2, length/2]`
/// with a vertex within [`SITE_TOLERANCE_M`] of every coordinate in `sites`, and the largest
/// offset.
fn lattice_through(sites: &[f64], length: f64, max: usize) -> Option<(usize, f64)> {
    (2..=max).find_map(|n| {
        let cell = length / (n - 1) as f64;
        let offset = sites
            .iter()
            .map(|s| {
                let k = (s + length / 2.0) / cell;
                (k - k.round()).abs() * cell
            })
            .fold(0.0, f64::max);
        (offset <= SITE_TOLERANCE_M).then_some((n, offset))
    })
}

fn build_scene(
    d: &PackageDescription,
    mut scene: SceneConfig,
    max_vertices: usize,
) -> Result<BuiltScene, PackageSceneError> {
    let file = d.path.display();
    let p = &d.package;
    let mut from_manifest = BTreeMap::new();
    // Frames: the simulator's world is the mocap frame (Y up) with the ground plane y = 0; the
    // manifest's conveyor is the robot-frame plane z = 0.
    let m = d.mocap_from_robot;
    if m.rotation[1] != [0.0, 0.0, 1.0] {
        return Err(PackageSceneError::Manifest(format!(
            "{file}: frames.mocap_from_robot.R: row 2 is {:?}; expected [0, 0, 1] (robot z, up, as mocap y, the simulator's up axis)",
            m.rotation[1]
        )));
    }
    if m.origin_m[2] != 0.0 {
        return Err(PackageSceneError::Manifest(format!(
            "{file}: frames.mocap_from_robot.o[2] = {} m puts the conveyor (robot z = 0) at mocap y = {} m; expected 0 (the simulator's ground is the plane y = 0)",
            m.origin_m[2], -m.origin_m[2]
        )));
    }
    // The package frame's x runs along mocap x, its y along mocap -z: the simulator's grid rows
    // run along z (size_m[0], grid[0]) and its columns along x (size_m[1], grid[1]).
    let xs: Vec<f64> = p.markers.iter().map(|s| s.x).collect();
    let ys: Vec<f64> = p.markers.iter().map(|s| s.y).collect();
    let no_lattice = |axis: &str, length: f64| {
        PackageSceneError::Manifest(format!(
            "{file}: package.markers.layout: no regular grid of at most {max_vertices} vertices along the package's {axis} side ({length} m) has a vertex at every marker site (within {} mm); expected marker sites on a regular lattice, or a larger --max-vertices",
            1e3 * SITE_TOLERANCE_M
        ))
    };
    let (cols, offset_x) = lattice_through(&xs, p.size_x_m, max_vertices)
        .ok_or_else(|| no_lattice("x", p.size_x_m))?;
    let (rows, offset_y) = lattice_through(&ys, p.size_y_m, max_vertices)
        .ok_or_else(|| no_lattice("y", p.size_y_m))?;
    scene.package.grid = [rows, cols];
    from_manifest.insert(
        "package.grid",
        format!(
            "the smallest regular lattice with a vertex at every package.markers.layout site: {} sites, cells {:.2} mm (y) x {:.2} mm (x)",
            p.markers.len(),
            1e3 * p.size_y_m / (rows - 1) as f64,
            1e3 * p.size_x_m / (cols - 1) as f64
        ),
    );
    scene.package.size_m = [p.size_y_m as f32, p.size_x_m as f32];
    from_manifest.insert(
        "package.size_m",
        "[package.size_y_m, package.size_x_m] (along mocap z, along mocap x)".into(),
    );
    scene.package.thickness_m = p.thickness_m as f32;
    from_manifest.insert("package.thickness_m", "package.thickness_m".into());
    scene.package.film_mass_kg = Some(p.film_mass_kg as f32);
    scene.package.particle_mass_kg = None;
    from_manifest.insert("package.film_mass_kg", "package.film_mass_kg".into());

    // Cups: the manifest's angle a runs from the tool's +x towards +y (robot frame); the
    // simulator puts a cup at r (sin b, 0, cos b) in mocap axes, where robot (cos a, sin a) is
    // mocap (cos a, ., -sin a): b = a + 90 degrees.
    let t = &d.tool;
    let cup_angles: Vec<f32> = t
        .cup_angles_deg
        .iter()
        .map(|a| (a + 90.0).rem_euclid(360.0) as f32)
        .collect();
    for (i, a) in t.cup_angles_deg.iter().enumerate() {
        let (sin, cos) = a.to_radians().sin_cos();
        let centre = [t.cup_circle_radius_m * cos, t.cup_circle_radius_m * sin];
        check_cup_on_package(d, i, centre, rows, cols)?;
    }
    scene.cups.circle_radius_m = t.cup_circle_radius_m as f32;
    from_manifest.insert("cups.circle_radius_m", "tool.cup_circle_radius_m".into());
    scene.cups.angles_deg = cup_angles;
    from_manifest.insert(
        "cups.angles_deg",
        format!(
            "tool.cup_angles_deg {:?} + 90 (from the tool's +x towards +y, turned into the simulator's angle from mocap +z towards +x)",
            t.cup_angles_deg
        ),
    );
    scene.cups.inner_radius_m = t.cup_inner_ring_radius_m as f32;
    from_manifest.insert("cups.inner_radius_m", "tool.cup_inner_ring_radius_m".into());
    scene.seal.lip_radius_m = t.cup_lip_radius_m as f32;
    from_manifest.insert("seal.lip_radius_m", "tool.cup_lip_radius_m".into());

    let o = &d.object;
    scene.disc.radius_m = (o.diameter_m / 2.0) as f32;
    from_manifest.insert("disc.radius_m", "object.diameter_m / 2".into());
    scene.disc.thickness_m = o.thickness_m as f32;
    from_manifest.insert("disc.thickness_m", "object.thickness_m".into());
    Ok(BuiltScene {
        scene,
        from_manifest,
        max_site_offset_m: offset_x.max(offset_y),
    })
}

/// A cup must sit on the package with at least one grid vertex (a particle it attaches to) inside
/// its lip. `centre` is the cup centre in the package frame at the first frame (the tool point
/// above the package centre, as the manifest's `tool.tool_point` states).
fn check_cup_on_package(
    d: &PackageDescription,
    cup: usize,
    centre: [f64; 2],
    rows: usize,
    cols: usize,
) -> Result<(), PackageSceneError> {
    let p = &d.package;
    let lip = d.tool.cup_lip_radius_m;
    let bad = |what: String| {
        PackageSceneError::Manifest(format!(
            "{}: tool.cup_angles_deg[{cup}] / tool.cup_circle_radius_m: cup {cup} at ({:.4}, {:.4}) m in the package frame {what}; expected every cup on the package with a particle under its lip",
            d.path.display(),
            centre[0],
            centre[1]
        ))
    };
    if centre[0].abs() + lip > p.size_x_m / 2.0 || centre[1].abs() + lip > p.size_y_m / 2.0 {
        return Err(bad(format!(
            "reaches past the edge of the {} x {} m package (lip radius {lip} m)",
            p.size_x_m, p.size_y_m
        )));
    }
    let (cell_x, cell_y) = (
        p.size_x_m / (cols - 1) as f64,
        p.size_y_m / (rows - 1) as f64,
    );
    let under = (0..rows).any(|r| {
        (0..cols).any(|c| {
            let x = -p.size_x_m / 2.0 + c as f64 * cell_x;
            let y = -p.size_y_m / 2.0 + r as f64 * cell_y;
            (x - centre[0]).hypot(y - centre[1]) <= lip
        })
    });
    if !under {
        return Err(bad(format!(
            "has no particle of the {rows} x {cols} grid within its lip radius {lip} m"
        )));
    }
    Ok(())
}

/// The scene as TOML (a header, then every key preceded by where it came from) and the number of
/// keys copied from the base scene.
fn render(
    d: &PackageDescription,
    built: &BuiltScene,
    base: &str,
    command: &str,
) -> Result<(String, usize), PackageSceneError> {
    let body =
        toml::to_string(&built.scene).map_err(|e| PackageSceneError::Render(e.to_string()))?;
    let masses_kg: Vec<String> = d
        .object
        .masses_lb
        .iter()
        .map(|lb| format!("{:.4}", lb * KG_PER_LB))
        .collect();
    let mut out = format!(
        "# Scene of the {name} package, generated by `{command}` from {manifest}.\n\
         # Keys marked `# from manifest:` come from it; keys marked `# assumption:` are copied from {base}.\n\
         # Frames: the simulator's world is the mocap frame (Y up); the conveyor (robot z = 0, frames.mocap_from_robot)\n\
         # is the simulator's ground plane y = 0; gravity as integrator.gravity_m_s2 below.\n\
         # Object masses: per take from the imported dataset's object_total_mass_kg (manifest object.masses_lb\n\
         # {lb:?} lb = [{kg}] kg), with disc.mass_scale and disc.extra_mass_kg below.\n\
         # Check: `rlpkg simulate <dataset>/<take id> --params <this file> --seconds 2` (docs/own-package.md).\n\n",
        name = d.name,
        manifest = d.path.display(),
        lb = d.object.masses_lb,
        kg = masses_kg.join(", "),
    );
    let mut section = String::new();
    let mut assumptions = 0;
    for line in body.lines() {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.to_string();
        } else if let Some((key, _)) = line.split_once(" = ") {
            if !key.starts_with(' ') && !key.is_empty() {
                let full = format!("{section}.{key}");
                match built.from_manifest.get(full.as_str()) {
                    Some(source) => out += &format!("# from manifest: {source}\n"),
                    None => {
                        assumptions += 1;
                        out += &format!("# assumption: {full} as in {base}\n");
                    }
                }
            }
        }
        out += line;
        out.push('\n');
    }
    // Every manifest-derived key must have been written.
    for key in built.from_manifest.keys() {
        let (section, name) = key.split_once('.').unwrap_or(("", key));
        if !body.contains(&format!("[{section}]")) || !body.contains(&format!("\n{name} = ")) {
            return Err(PackageSceneError::Render(format!(
                "the generated scene lacks {key}"
            )));
        }
    }
    Ok((out, assumptions))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lattice_is_the_smallest_through_every_site() {
        // packages-v1: sites at +-5.2, +-2.4, 0 in along the 12 in side need a 0.4 in lattice.
        let xs = [-0.13208, -0.06096, 0.0, 0.06096, 0.13208];
        assert_eq!(lattice_through(&xs, 0.3048, 64).map(|r| r.0), Some(31));
        let ys = [-0.10668, -0.03556, 0.03556, 0.10668];
        assert_eq!(lattice_through(&ys, 0.254, 64).map(|r| r.0), Some(26));
        // Corners only: two vertices suffice.
        assert_eq!(lattice_through(&[-0.1, 0.1], 0.2, 64).map(|r| r.0), Some(2));
        // Too fine for the limit.
        assert_eq!(lattice_through(&[0.0123457], 0.3, 64), None);
    }

    fn packages_v1() -> (PackageDescription, SceneConfig) {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let description =
            PackageDescription::load(&root.join("data/packages-v1/manifest.json")).unwrap();
        let base = SceneConfig::load(&root.join("configs/scenes/calibrated-coarse-soft-film.toml"))
            .unwrap();
        (description, base)
    }

    #[test]
    fn the_manifest_gives_the_geometry_and_the_base_the_rest() {
        let (description, base) = packages_v1();
        let built = package_scene(
            &description,
            base.clone(),
            "base.toml",
            64,
            "make it",
            "out.toml",
        )
        .unwrap();
        assert_eq!(built.scene.package.grid, [26, 31]);
        assert_eq!(built.scene.params, base.params);
        assert_eq!(
            built.scene.cups.angles_deg.len(),
            description.tool.cup_angles_deg.len()
        );
        assert!(built.max_site_offset_m <= SITE_TOLERANCE_M);
        assert!(built
            .text
            .starts_with("# Scene of the packages-v1 package, generated by `make it`"));
        assert!(built
            .text
            .contains("# assumption: params.k_tri_e as in base.toml\n"));
        assert_eq!(
            built.text.matches("# assumption: ").count(),
            built.assumptions
        );
        let back = SceneConfig::from_toml_str(&built.text, "out.toml").unwrap();
        assert_eq!(back.package.grid, built.scene.package.grid);
    }

    #[test]
    fn a_layout_off_every_small_lattice_and_a_cup_off_the_package_are_refused() {
        let (description, base) = packages_v1();
        let err = package_scene(&description, base.clone(), "b", 8, "c", "o")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("package.markers.layout") && err.contains("at most 8 vertices"),
            "{err}"
        );
        let mut wide = description;
        wide.tool.cup_circle_radius_m = 1.0;
        let err = package_scene(&wide, base, "b", 64, "c", "o")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("tool.cup_angles_deg[0]") && err.contains("past the edge"),
            "{err}"
        );
    }
}
