//! The posterior draws of `randomization.package.posterior`: read from its files, split by
//! `held_out_draws`, and refused unless its calibration simulated the transport scene's grid and
//! integrator.

use std::path::Path;
use std::sync::Arc;

use rlpkg_calib::posterior_files::{self, Samples};

use super::scene::load_scene;
use super::table::TransportConfig;
use super::validation::bad;
use crate::EnvError;

/// Refuses the posterior of `summary` unless the calibration it records simulated the grid and
/// the integrator (solver, substep rate, sweeps) of `config.scene`
/// ([`posterior_files::calibrated_scene`]): its draws are parameters of that film at that step.
/// The scenes may differ otherwise (a calibrated scene is its calibration's preset with the
/// fitted values, and a transport scene may change the seal or the disc's hold).
fn check_posterior_scene(
    config: &TransportConfig,
    summary: &Path,
    source: &str,
) -> Result<(), EnvError> {
    let key = "randomization.package.posterior";
    let calibrated = posterior_files::calibrated_scene(summary)
        .map_err(|e| bad(source, key, summary.display(), &e.to_string()))?;
    let fail = |expected: String| bad(source, key, summary.display(), &expected);
    let scene = load_scene(config, source)?;
    // The draws are film and contact parameters of that grid at that step: the same values on
    // another grid or integrator are another material, and may not even be stable there.
    let differs = if calibrated.package.grid != scene.package.grid {
        Some(format!(
            "grid {:?} (transport: {:?})",
            calibrated.package.grid, scene.package.grid
        ))
    } else if calibrated.integrator != scene.integrator {
        Some(format!(
            "[integrator] {:?} (transport: {:?})",
            calibrated.integrator, scene.integrator
        ))
    } else {
        None
    };
    if let Some(what) = differs {
        return Err(fail(format!(
            "a posterior of a calibration on the grid and integrator of transport.scene {:?}; its \
             calibration simulated {what}",
            config.scene,
        )));
    }
    Ok(())
}

impl TransportConfig {
    /// Reads the draws of `randomization.package.posterior` (if set) into
    /// `posterior_draws`: the `samples.csv` of the folder (or of the folder of the
    /// `summary.json` or `samples.csv`) it names, relative paths from the working directory as
    /// `scene` and `recordings`. With a `summary.json` beside it, the calibration it records must
    /// have calibrated this config's `scene` at its step ([`check_posterior_scene`]); a bare
    /// `samples.csv` cannot be checked.
    pub fn load_posterior(&mut self, source: &str) -> Result<(), EnvError> {
        let Some(given) = self.randomization.package.posterior.clone() else {
            return Ok(());
        };
        let key = "randomization.package.posterior";
        let files = posterior_files::locate(&given).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("transport.{key}: {e}"),
        })?;
        let samples = Samples::read(&files.samples).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("transport.{key}: {e}"),
        })?;
        if let Some(summary) = files.summary {
            check_posterior_scene(self, &summary, source)?;
        }
        let mut draws = samples.to_draws();
        if let Some(split) = &self.randomization.held_out_draws {
            draws.rows = split.select(&draws.rows);
            if draws.rows.is_empty() {
                return Err(bad(
                    source,
                    "randomization.held_out_draws",
                    format!("{{ every = {}, rows = {:?} }}", split.every, split.rows),
                    "a split that leaves the task at least one of the posterior's draws",
                ));
            }
        }
        self.randomization.package.posterior_draws = Some(Arc::new(draws));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::transport::test_support::{config, test_table};

    /// A fresh folder under the system's temporary folder for test `name`.
    fn temp_folder(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rlpkg-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// A posterior folder in `dir`: `samples` as its samples.csv and a summary.json naming a
    /// calibration config of scene `preset` with the further `[sim]` lines `sim`.
    fn posterior_folder(dir: &Path, samples: &str, preset: &str, sim: &str) -> PathBuf {
        let folder = dir.join("posterior");
        std::fs::create_dir_all(&folder).unwrap();
        let calibration = dir.join("calibrate.toml");
        let config = format!(
            "data = \"data\"\nout_dir = \"out\"\n[sim]\npreset = {preset:?}\n{sim}\n\
             [smc]\nparticles = 8\nmoves = 1\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 1e3\nupper = 1e5\n"
        );
        std::fs::write(&calibration, config).unwrap();
        std::fs::write(folder.join("samples.csv"), samples).unwrap();
        let summary = serde_json::json!({ "config": calibration.display().to_string() });
        std::fs::write(folder.join("summary.json"), summary.to_string()).unwrap();
        folder
    }

    fn with_posterior(path: &Path) -> String {
        test_table().replace(
            "param_scale = { k_tri_e = [0.8, 1.25] }",
            &format!(
                "param_scale = {{ k_tri_e = [0.8, 1.25] }}\nposterior = {:?}",
                path.display().to_string()
            ),
        )
    }

    const SAMPLES: &str = "k_tri_e,k_spr_e,mu_con\n1000,20,0.5\n2000,30,0.6\n";

    #[test]
    fn held_out_draws_are_never_among_the_training_draws() {
        let dir = temp_folder("posterior-held-out");
        let rows: String = (1..=10).map(|k| format!("{},20,0.5\n", 1000 * k)).collect();
        let folder = posterior_folder(
            &dir,
            &format!("k_tri_e,k_spr_e,mu_con\n{rows}"),
            "physical",
            "",
        );
        let split = |rows: &str| {
            let text = with_posterior(&folder).replace(
                "[transport.randomization.package]",
                &format!(
                    "[transport.randomization.held_out_draws]\nevery = 3\nrows = {rows:?}\n\n\
                     [transport.randomization.package]"
                ),
            );
            let config = config(&text);
            let draws = config.randomization.package.posterior_draws.unwrap();
            draws
                .rows
                .iter()
                .map(|r| r[0] as usize / 1000)
                .collect::<Vec<_>>()
        };
        assert_eq!(split("training"), [1, 2, 4, 5, 7, 8, 10]);
        assert_eq!(split("held_out"), [3, 6, 9]);
        assert_eq!(split("test"), [3, 9]);
        assert_eq!(split("validation"), [6]);
        let text = test_table().replace(
            "[transport.randomization.package]",
            "[transport.randomization.held_out_draws]\nevery = 3\nrows = \"training\"\n\n\
             [transport.randomization.package]",
        );
        let err = TransportConfig::from_toml_str(&text, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("randomization.held_out_draws") && err.contains("posterior"),
            "{err}"
        );
    }

    #[test]
    fn a_posterior_of_the_scene_s_calibration_is_loaded_from_its_folder_or_files() {
        let dir = temp_folder("posterior-loads");
        let folder = posterior_folder(&dir, SAMPLES, "physical", "between = 1");
        for given in [
            folder.clone(),
            folder.join("summary.json"),
            folder.join("samples.csv"),
        ] {
            let config = config(&with_posterior(&given));
            let draws = config
                .randomization
                .package
                .posterior_draws
                .clone()
                .unwrap();
            assert_eq!(draws.names, ["k_tri_e", "k_spr_e", "mu_con"]);
            assert_eq!(
                draws.rows,
                [vec![1000.0, 20.0, 0.5], vec![2000.0, 30.0, 0.6]]
            );
            // The critic sees the log of every drawn or scaled parameter over the scene's.
            assert_eq!(
                crate::transport::observe::randomised_materials(&config),
                ["k_spr_e", "k_tri_e", "mu_con"]
            );
            // The nominal task is the scene's own parameters.
            assert!(config
                .nominal(45.0)
                .randomization
                .package
                .posterior_draws
                .is_none());
        }
        // A bare samples.csv (no summary beside it) cannot be checked and is taken as it is.
        let bare = dir.join("bare.csv");
        std::fs::write(&bare, SAMPLES).unwrap();
        let config = config(&with_posterior(&bare));
        assert_eq!(
            config
                .randomization
                .package
                .posterior_draws
                .unwrap()
                .rows
                .len(),
            2
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_posteriors_are_refused_naming_the_file_line_and_column() {
        let dir = temp_folder("posterior-bad");
        let samples = dir.join("posterior").join("samples.csv");
        let shown = samples.display().to_string();
        for (text, needles) in [
            (
                "k_tri_e,k_sprung\n1,2\n",
                vec![shown.clone(), "line 1 column 2".into(), "k_sprung".into()],
            ),
            (
                "k_tri_e,mu_con\n1,0.5\n1,x\n",
                vec![shown.clone(), "line 3 column 2".into()],
            ),
            (
                "k_tri_e,mu_con\n-5,0.5\n",
                vec![shown.clone(), "line 2 column 1".into(), "-5".into()],
            ),
        ] {
            posterior_folder(&dir, text, "physical", "between = 1");
            let err = TransportConfig::from_toml_str(&with_posterior(&samples), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(err.contains("t.toml") && err.contains("posterior"), "{err}");
            for needle in needles {
                assert!(err.contains(&needle), "{text:?}: {err}");
            }
        }
        let missing = dir.join("nowhere");
        let err = TransportConfig::from_toml_str(&with_posterior(&missing), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains(&missing.display().to_string())
                && err.contains("not found"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_posterior_of_another_grid_or_step_is_refused_naming_both() {
        let dir = temp_folder("posterior-scene");
        let refusal = |preset: &str, sim: &str| {
            let folder = posterior_folder(&dir, SAMPLES, preset, sim);
            TransportConfig::from_toml_str(&with_posterior(&folder), "t.toml")
                .unwrap_err()
                .to_string()
        };
        // The test table trains on the physical scene at 11 x 13 (`between = 1`).
        for (sim, differs) in [
            ("between = 2", "grid [16, 19]"),
            ("between = 1\ndt = 0.001", "[integrator]"),
            ("between = 1\niterations = 48", "iterations: 48"),
        ] {
            let err = refusal("physical", sim);
            assert!(
                err.contains("t.toml")
                    && err.contains("summary.json")
                    && err.contains("transport.scene \"physical\"")
                    && err.contains(differs),
                "{err}"
            );
        }
        let err = refusal("configs/scenes/missing.toml", "between = 1");
        assert!(err.contains("configs/scenes/missing.toml"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
