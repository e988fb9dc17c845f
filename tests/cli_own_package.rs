//! End-to-end test of "bring your own package" on packages-v1 (docs/own-package.md) through the
//! binary: import two takes with the split of the collection's manifest.json (one train take, one
//! failure take), build the scene from the manifest, replay an imported take with it, calibrate
//! one small batch on the train split; and the bad manifests that must exit with code 2, name the
//! file and the key, and leave the output untouched.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use rlpkg_mocap::{Dataset, Split};
use rlpkg_sim::SceneConfig;
use serde_json::Value;

const TRAIN_TAKE: &str = "a30_m0.5_high";
const FAILURE_TAKE: &str = "a45_m1.0_high";

fn rlpkg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rlpkg"))
        .args(args)
        .output()
        .expect("run rlpkg")
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn package_file(name: &str) -> String {
    repo()
        .join("data/packages-v1")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn manifest_value() -> Value {
    serde_json::from_str(&fs::read_to_string(package_file("manifest.json")).unwrap()).unwrap()
}

fn number(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// Imports the two takes with the manifest's split into `out`.
fn import(out: &Path, manifest: &str) -> Output {
    rlpkg(&[
        "data",
        "import-motive",
        &package_file(&format!("{TRAIN_TAKE}.csv.gz")),
        &package_file(&format!("{FAILURE_TAKE}.csv.gz")),
        "--robot",
        &package_file(&format!("{TRAIN_TAKE}_robot.csv")),
        &package_file(&format!("{FAILURE_TAKE}_robot.csv")),
        "--manifest",
        manifest,
        "--config",
        repo()
            .join("configs/import/packages-v1.toml")
            .to_str()
            .unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

fn from_manifest(manifest: &Path, out: &Path) -> Output {
    rlpkg(&[
        "scene",
        "from-manifest",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--base",
        repo()
            .join("configs/scenes/calibrated-coarse-soft-film.toml")
            .to_str()
            .unwrap(),
    ])
}

fn check_import(dataset_dir: &Path) {
    let out = import(dataset_dir, &package_file("manifest.json"));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("split: 1 train, 0 test, 1 excluded")
            && stdout.contains(&format!("{FAILURE_TAKE}: frames kept"))
            && stdout.contains("[failure take: written with split \"excluded\""),
        "{stdout}"
    );
    let dataset = Dataset::open(dataset_dir).unwrap();
    assert_eq!(dataset.ids(Some(Split::Train)), vec![TRAIN_TAKE]);
    assert!(dataset.ids(Some(Split::Test)).is_empty());
    assert_eq!(dataset.ids(Some(Split::Excluded)), vec![FAILURE_TAKE]);
    let manifest = manifest_value();
    for entry in &dataset.entries {
        let listed = manifest["trajectories"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["id"] == entry.id.as_str())
            .unwrap();
        assert_eq!(entry.failure, listed["failure"].as_bool().unwrap());
        assert_eq!(
            entry.object_total_mass_kg,
            number(&listed["object_mass_kg"]),
            "{}",
            entry.id
        );
        // The manifest's masses in kg are its pounds converted.
        assert!(
            (entry.object_total_mass_kg - 0.45359237 * number(&listed["object_mass_lb"])).abs()
                < 1e-4
        );
        // Both takes load back whole (the loader checks frames and rows against the entry).
        let trajectory = dataset.load(&entry.id).unwrap();
        assert_eq!(trajectory.tool.t.len(), entry.frames);
        // The outermost sites' distance to the package's edges, along mocap x (robot x, the
        // 0.3048 m side) and mocap z (robot -y, the 0.254 m side), for the replay's placement.
        let layout = manifest["package"]["markers"]["layout"].as_array().unwrap();
        let min_x = layout
            .iter()
            .map(|s| number(&s["x"]))
            .fold(f64::MAX, f64::min);
        let max_y = layout
            .iter()
            .map(|s| number(&s["y"]))
            .fold(f64::MIN, f64::max);
        let inset = trajectory
            .meta
            .marker_inset_m
            .expect("marker_inset_m in meta.toml");
        assert!((inset[0] - (min_x + number(&manifest["package"]["size_x_m"]) / 2.0)).abs() < 1e-9);
        assert!((inset[1] - (number(&manifest["package"]["size_y_m"]) / 2.0 - max_y)).abs() < 1e-9);
    }
    let text = fs::read_to_string(dataset_dir.join("manifest.toml")).unwrap();
    assert!(
        text.contains("split = \"excluded\"") && text.contains("failure = true"),
        "{text}"
    );
}

fn check_scene(scene_path: &Path) -> SceneConfig {
    let out = from_manifest(Path::new(&package_file("manifest.json")), scene_path);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let written = fs::read_to_string(scene_path).unwrap();
    assert!(
        written.starts_with(
            "# Scene of the packages-v1 package, generated by `rlpkg scene from-manifest"
        ) && written.contains("# assumption: params.k_tri_e as in")
            && written.contains("# assumption: integrator.substep_rate_hz as in")
            && written.contains("[0.2268, 0.3402, 0.4536] kg"),
        "{written}"
    );
    let scene = SceneConfig::load(scene_path).unwrap();
    let m = manifest_value();
    let (size_x, size_y) = (
        number(&m["package"]["size_x_m"]),
        number(&m["package"]["size_y_m"]),
    );
    let p = &scene.package;
    assert_eq!(p.size_m, [size_y as f32, size_x as f32]);
    assert_eq!(p.thickness_m, number(&m["package"]["thickness_m"]) as f32);
    assert_eq!(
        p.film_mass_kg,
        Some(number(&m["package"]["film_mass_kg"]) as f32)
    );
    // Every marker site of the layout is a grid vertex (rows along y, columns along x).
    let [rows, cols] = p.grid;
    assert!(rows * cols <= 64 * 64, "{rows} x {cols}");
    let on_vertex = |s: f64, length: f64, n: usize| {
        let k = (s + length / 2.0) / (length / (n - 1) as f64);
        (k - k.round()).abs() * length / (n - 1) as f64 <= 1e-5
    };
    for site in m["package"]["markers"]["layout"].as_array().unwrap() {
        assert!(on_vertex(number(&site["x"]), size_x, cols), "{site}");
        assert!(on_vertex(number(&site["y"]), size_y, rows), "{site}");
    }
    // packages-v1's sites need the 0.4 in lattice: 26 x 31.
    assert_eq!(p.grid, [26, 31]);
    // Cups: the manifest's angles (from the tool's +x towards +y) turned by 90 degrees into the
    // simulator's (from mocap +z towards +x); same circle, ring and lip radii.
    let t = &m["tool"];
    assert_eq!(
        scene.cups.circle_radius_m,
        number(&t["cup_circle_radius_m"]) as f32
    );
    let angles: Vec<f32> = t["cup_angles_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| ((number(a) + 90.0) % 360.0) as f32)
        .collect();
    assert_eq!(scene.cups.angles_deg, angles);
    assert_eq!(
        scene.cups.inner_radius_m,
        number(&t["cup_inner_ring_radius_m"]) as f32
    );
    assert_eq!(
        scene.seal.lip_radius_m,
        number(&t["cup_lip_radius_m"]) as f32
    );
    let o = &m["object"];
    assert_eq!(scene.disc.radius_m, (number(&o["diameter_m"]) / 2.0) as f32);
    assert_eq!(scene.disc.thickness_m, number(&o["thickness_m"]) as f32);
    scene
}

fn check_simulate(dataset_dir: &Path, scene_path: &Path, out_dir: &Path) {
    let out = rlpkg(&[
        "simulate",
        dataset_dir.join(TRAIN_TAKE).to_str().unwrap(),
        "--params",
        scene_path.to_str().unwrap(),
        "--seconds",
        "0.5",
        "--no-gif",
        "--png-every",
        "10",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: Value =
        serde_json::from_str(&fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
    assert!(summary["health"].is_null(), "{summary}");
    assert_eq!(summary["package_particles"], 2 * 26 * 31);
    let chamfer = number(&summary["chamfer_mean_m"]);
    // The replay holds together: the simulated package stays within centimetres of the markers.
    assert!(chamfer > 0.0 && chamfer < 0.1, "{summary}");
}

/// One batch of the calibration on the imported train split, on a coarse grid with a short rest
/// (the machinery, not the fit), with the study's loss weights.
fn check_calibrate(dir: &Path, dataset_dir: &Path, scene_path: &Path) {
    let quick = dir.join("quick.toml");
    let scene = fs::read_to_string(scene_path).unwrap();
    assert!(scene.contains("rest_time_s = 1.0") && scene.contains("object_outside = true"));
    fs::write(
        &quick,
        scene
            .replace("rest_time_s = 1.0", "rest_time_s = 0.1")
            // The disc slips through the 6 x 7 sheet; this checks the calibration machinery.
            .replace("object_outside = true", "object_outside = false"),
    )
    .unwrap();
    let config = dir.join("calibrate.toml");
    let out_dir = dir.join("calibration");
    fs::write(
        &config,
        format!(
            "data = \"{}\"\nout_dir = \"{}\"\n\n[sim]\npreset = \"{}\"\nbetween = 0\nmax_seconds = 0.05\n\n\
             [optimiser]\niterations = 1\nbatch_size = 1\ninitial_points = 1\nseed = 1\n\n\
             [loss]\nobject = 1.0\npackage = 0.1\n\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 3.0e2\nupper = 5.0e3\nlog = true\n",
            dataset_dir.display(),
            out_dir.display(),
            quick.display()
        ),
    )
    .unwrap();
    let out = rlpkg(&["calibrate", config.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let log = fs::read_to_string(out_dir.join("evaluations.csv")).unwrap();
    assert!(log.lines().count() >= 2, "{log}");
    // The train split only: the failure take is not fitted.
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains(&format!("on 1 trajectory(ies) [{TRAIN_TAKE}]")),
        "{stdout}"
    );
}

#[test]
fn a_package_goes_from_takes_to_a_scene_a_replay_and_a_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let dataset_dir = dir.path().join("dataset");
    check_import(&dataset_dir);
    let scene_path = dir.path().join("packages-v1.toml");
    check_scene(&scene_path);
    check_simulate(&dataset_dir, &scene_path, &dir.path().join("simulate"));
    check_calibrate(dir.path(), &dataset_dir, &scene_path);
}

/// The shipped manifest with `edit` applied, written into `dir`.
fn edited_manifest(dir: &Path, name: &str, edit: impl FnOnce(&mut Value)) -> PathBuf {
    let mut value = manifest_value();
    edit(&mut value);
    let path = dir.join(name);
    fs::write(&path, serde_json::to_string_pretty(&value).unwrap()).unwrap();
    path
}

#[test]
fn bad_manifests_exit_2_naming_file_and_key_and_leave_the_output_alone() {
    let dir = tempfile::tempdir().unwrap();
    let scene_out = dir.path().join("scene.toml");
    fs::write(&scene_out, "sentinel").unwrap();
    type Edit = Box<dyn FnOnce(&mut Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "missing-key.json",
            Box::new(|v: &mut Value| {
                v["package"].as_object_mut().unwrap().remove("size_x_m");
            }),
            "package.size_x_m: missing",
        ),
        (
            "negative-size.json",
            Box::new(|v: &mut Value| v["package"]["size_y_m"] = (-0.254).into()),
            "package.size_y_m: -0.254",
        ),
        (
            "thick-disc.json",
            Box::new(|v: &mut Value| v["object"]["thickness_m"] = 0.05.into()),
            "object.thickness_m",
        ),
        (
            "cups-off-package.json",
            Box::new(|v: &mut Value| v["tool"]["cup_circle_radius_m"] = 0.5.into()),
            "tool.cup_circle_radius_m",
        ),
        (
            // Markers only at the corners: a 2 x 2 grid, no particle under any cup's lip.
            "corner-markers.json",
            Box::new(|v: &mut Value| {
                let corners: Vec<Value> = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                    .iter()
                    .map(|(sx, sy)| {
                        serde_json::json!({
                            "index": 0, "layer": "top", "x": sx * 0.1524, "y": sy * 0.127
                        })
                    })
                    .collect();
                v["package"]["markers"]["layout"] = Value::Array(corners);
            }),
            "has no particle of the 2 x 2 grid",
        ),
    ];
    for (name, edit, expected) in cases {
        let manifest = edited_manifest(dir.path(), name, edit);
        let out = from_manifest(&manifest, &scene_out);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains(name) && err.contains(expected),
            "{name}: {err}"
        );
        assert_eq!(
            fs::read_to_string(&scene_out).unwrap(),
            "sentinel",
            "{name}"
        );
    }

    // Import: a failure flag that contradicts the split names the manifest and the key; no
    // dataset folder appears.
    let manifest = edited_manifest(dir.path(), "bad-split.json", |v| {
        v["trajectories"][0]["failure"] = true.into();
    });
    let dataset_dir = dir.path().join("dataset");
    let out = import(&dataset_dir, manifest.to_str().unwrap());
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("bad-split.json") && err.contains("trajectories[0].failure"),
        "{err}"
    );
    assert!(!dataset_dir.exists());
    // A take the manifest does not list.
    let manifest = edited_manifest(dir.path(), "no-take.json", |v| {
        let takes = v["trajectories"].as_array_mut().unwrap();
        takes.retain(|t| t["id"] != FAILURE_TAKE);
        for list in ["train", "test", "excluded_failures"] {
            v["split"][list]
                .as_array_mut()
                .unwrap()
                .retain(|id| id != FAILURE_TAKE);
        }
    });
    let out = import(&dataset_dir, manifest.to_str().unwrap());
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no-take.json") && err.contains(&format!("no take \"{FAILURE_TAKE}\"")),
        "{err}"
    );
    assert!(!dataset_dir.exists());
}
