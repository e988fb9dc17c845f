//! A take collection's `manifest.json` (see `data/packages-v1/README.md`): the package's geometry,
//! marker layout, suction-tool layout, internal object, frames, and per-take metadata with the
//! train / test split. `rlpkg data import-motive --manifest` takes each take's split, failure flag
//! and masses from it; `rlpkg scene from-manifest` builds a scene from its geometry.
//!
//! Every value is checked when read; an error names the file, the key (a dotted path such as
//! `package.size_x_m` or `trajectories[3].failure`) and what was expected.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde_json::Value;

/// One pound in kilograms (exact by definition).
pub const KG_PER_LB: f64 = 0.453_592_37;

/// A manifest that cannot be read or holds a missing or unacceptable value.
#[derive(Debug, thiserror::Error)]
#[error("{}: {key}: {message}", path.display())]
pub struct DescriptionError {
    /// The manifest file.
    pub path: PathBuf,
    /// Dotted key of the offending value (`-` when the file itself is unreadable).
    pub key: String,
    /// What is wrong and what was expected.
    pub message: String,
}

/// Which film layer a marker sits on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layer {
    /// The layer the cups hold (outward normal +z of the package frame).
    Top,
    /// The layer resting on the conveyor.
    Bottom,
}

/// A marker's nominal (flat) site in the package frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerSite {
    /// Its film layer.
    pub layer: Layer,
    /// Along the package's x side (m), from the centre.
    pub x: f64,
    /// Along the package's y side (m), from the centre.
    pub y: f64,
}

/// The package: a closed two-layer pillow.
#[derive(Debug, Clone, PartialEq)]
pub struct PackageGeometry {
    /// Side along the package frame's x (m).
    pub size_x_m: f64,
    /// Side along the package frame's y (m).
    pub size_y_m: f64,
    /// Distance between the two layers (m).
    pub thickness_m: f64,
    /// Mass of the film (kg).
    pub film_mass_kg: f64,
    /// Nominal marker sites.
    pub markers: Vec<MarkerSite>,
}

/// The suction tool's cups, in the tool frame (tool z up at the first frame, cups facing -z).
#[derive(Debug, Clone, PartialEq)]
pub struct ToolLayout {
    /// Radius of the circle the cup centres sit on (m).
    pub cup_circle_radius_m: f64,
    /// Angle of each cup centre on that circle, from the tool's +x towards +y (degrees).
    pub cup_angles_deg: Vec<f64>,
    /// Radius of a cup's innermost ring (m).
    pub cup_inner_ring_radius_m: f64,
    /// Radius of a cup's lip (m).
    pub cup_lip_radius_m: f64,
}

/// The rigid disc inside the package.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectGeometry {
    /// Disc diameter (m).
    pub diameter_m: f64,
    /// Disc thickness (m).
    pub thickness_m: f64,
    /// The object masses of the takes (lb).
    pub masses_lb: Vec<f64>,
}

/// `frames.mocap_from_robot`: `p_mocap = R (p_robot - o)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MocapFromRobot {
    /// Rotation matrix, rows.
    pub rotation: [[f64; 3]; 3],
    /// Robot-frame origin of the mocap frame (m).
    pub origin_m: [f64; 3],
}

/// Where a take belongs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TakeRole {
    /// Listed in `split.train`.
    Train,
    /// Listed in `split.test`.
    Test,
    /// A failure take, listed in `split.excluded_failures`.
    Failure,
}

/// One entry of `trajectories`.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeDescription {
    /// Take id (the Motive file's name without `.csv.gz`).
    pub id: String,
    /// Train, test or failure, from `split` (checked against the take's `failure` flag).
    pub role: TakeRole,
    /// Object mass (kg).
    pub object_mass_kg: f64,
    /// Object mass (lb).
    pub object_mass_lb: f64,
    /// Speed class label.
    pub speed: String,
    /// Placement angle (degrees).
    pub placement_angle_deg: f64,
}

/// A whole `manifest.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct PackageDescription {
    /// The file it was read from.
    pub path: PathBuf,
    /// Collection name.
    pub name: String,
    /// The package.
    pub package: PackageGeometry,
    /// The suction tool.
    pub tool: ToolLayout,
    /// The internal object.
    pub object: ObjectGeometry,
    /// Robot-to-mocap transform.
    pub mocap_from_robot: MocapFromRobot,
    /// The takes, in file order.
    pub takes: Vec<TakeDescription>,
}

/// Reads values by dotted key, naming the key in every error.
struct Reader<'a> {
    path: &'a Path,
}

impl Reader<'_> {
    fn err(&self, key: &str, message: impl Into<String>) -> DescriptionError {
        DescriptionError {
            path: self.path.to_path_buf(),
            key: key.to_string(),
            message: message.into(),
        }
    }

    fn get<'v>(
        &self,
        parent: &'v Value,
        parent_key: &str,
        name: &str,
    ) -> Result<&'v Value, DescriptionError> {
        let key = join(parent_key, name);
        parent
            .get(name)
            .ok_or_else(|| self.err(&key, "missing; expected it in the manifest"))
    }

    fn number(&self, value: &Value, key: &str) -> Result<f64, DescriptionError> {
        value.as_f64().filter(|v| v.is_finite()).ok_or_else(|| {
            self.err(
                key,
                format!("{value} is not a number; expected a finite number"),
            )
        })
    }

    fn field(&self, parent: &Value, parent_key: &str, name: &str) -> Result<f64, DescriptionError> {
        let value = self.get(parent, parent_key, name)?;
        self.number(value, &join(parent_key, name))
    }

    /// A number that must be > 0 (`strict`) or >= 0, and below `max`.
    fn positive(
        &self,
        parent: &Value,
        parent_key: &str,
        name: &str,
        strict: bool,
        max: f64,
    ) -> Result<f64, DescriptionError> {
        let v = self.field(parent, parent_key, name)?;
        let ok = if strict { v > 0.0 } else { v >= 0.0 } && v <= max;
        if ok {
            Ok(v)
        } else {
            let lower = if strict { "> 0" } else { ">= 0" };
            Err(self.err(
                &join(parent_key, name),
                format!("{v}: expected a number {lower} and at most {max}"),
            ))
        }
    }

    fn text(
        &self,
        parent: &Value,
        parent_key: &str,
        name: &str,
    ) -> Result<String, DescriptionError> {
        let value = self.get(parent, parent_key, name)?;
        value.as_str().map(str::to_string).ok_or_else(|| {
            self.err(
                &join(parent_key, name),
                format!("{value}: expected a string"),
            )
        })
    }

    fn array<'v>(
        &self,
        parent: &'v Value,
        parent_key: &str,
        name: &str,
    ) -> Result<&'v [Value], DescriptionError> {
        let value = self.get(parent, parent_key, name)?;
        value
            .as_array()
            .map(Vec::as_slice)
            .ok_or_else(|| self.err(&join(parent_key, name), "not an array; expected an array"))
    }

    fn numbers(
        &self,
        parent: &Value,
        parent_key: &str,
        name: &str,
    ) -> Result<Vec<f64>, DescriptionError> {
        let key = join(parent_key, name);
        self.array(parent, parent_key, name)?
            .iter()
            .enumerate()
            .map(|(i, v)| self.number(v, &format!("{key}[{i}]")))
            .collect()
    }

    fn numbers3(
        &self,
        parent: &Value,
        parent_key: &str,
        name: &str,
    ) -> Result<[f64; 3], DescriptionError> {
        let values = self.numbers(parent, parent_key, name)?;
        values.clone().try_into().map_err(|_| {
            self.err(
                &join(parent_key, name),
                format!("{} numbers; expected 3", values.len()),
            )
        })
    }
}

fn join(parent: &str, name: &str) -> String {
    if parent.is_empty() {
        name.to_string()
    } else {
        format!("{parent}.{name}")
    }
}

/// Largest package side accepted (m): anything larger is not a parcel.
const MAX_SIZE_M: f64 = 10.0;
/// Largest mass accepted (kg).
const MAX_MASS_KG: f64 = 1e3;

impl PackageDescription {
    /// Reads and checks a `manifest.json`.
    pub fn load(path: &Path) -> Result<Self, DescriptionError> {
        let r = Reader { path };
        let text = std::fs::read_to_string(path)
            .map_err(|e| r.err("-", format!("cannot read the file: {e}")))?;
        let root: Value = serde_json::from_str(&text).map_err(|e| {
            r.err(
                "-",
                format!("line {}: {e}; expected a JSON manifest", e.line()),
            )
        })?;
        Self::from_value(&root, path)
    }

    /// Checks a parsed manifest; `path` names it in errors.
    pub fn from_value(root: &Value, path: &Path) -> Result<Self, DescriptionError> {
        let r = Reader { path };
        let name = r.text(root, "", "name")?;
        let package = read_package(&r, root)?;
        let tool = read_tool(&r, root)?;
        let object = read_object(&r, root, &package)?;
        let mocap_from_robot = read_frames(&r, root)?;
        let takes = read_takes(&r, root)?;
        Ok(PackageDescription {
            path: path.to_path_buf(),
            name,
            package,
            tool,
            object,
            mocap_from_robot,
            takes,
        })
    }

    /// The take `id`, if listed.
    pub fn take(&self, id: &str) -> Option<&TakeDescription> {
        self.takes.iter().find(|t| t.id == id)
    }

    /// The bottom layer's marker sites at the start of every take (m, mocap frame): the package
    /// lies flat on the conveyor (robot z = 0), centred at the robot's origin with its axes along
    /// the robot's (the manifest's `package.initial_pose`), so a site at (x, y) of the package frame
    /// is at robot (x, y, 0). Hidden by the conveyor, these cannot be read off the first frame.
    pub fn bottom_markers_at_start(&self) -> Vec<[f64; 3]> {
        let MocapFromRobot {
            rotation: r,
            origin_m: o,
        } = self.mocap_from_robot;
        self.package
            .markers
            .iter()
            .filter(|m| m.layer == Layer::Bottom)
            .map(|m| {
                let d = [m.x - o[0], m.y - o[1], -o[2]];
                std::array::from_fn(|i| r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2])
            })
            .collect()
    }

    /// How far the outermost marker sites lie inside the package's edges at the smallest mocap x
    /// and z (m), for a package lying flat with its axes along the robot's (its initial pose) and
    /// a transform that maps the robot's horizontal axes onto mocap x and z; none otherwise.
    pub fn marker_inset_m(&self) -> Option<[f64; 2]> {
        let p = &self.package;
        let inset = |row: [f64; 3]| {
            // Mocap coordinate = sign * robot coordinate along one horizontal robot axis.
            let axis = (0..2).find(|&a| row[a].abs() == 1.0)?;
            if row.iter().enumerate().any(|(b, v)| b != axis && *v != 0.0) {
                return None;
            }
            let (sign, half) = match axis {
                0 => (row[0], p.size_x_m / 2.0),
                _ => (row[1], p.size_y_m / 2.0),
            };
            let nearest = p
                .markers
                .iter()
                .map(|m| sign * if axis == 0 { m.x } else { m.y })
                .fold(f64::INFINITY, f64::min);
            Some(nearest + half)
        };
        let r = self.mocap_from_robot.rotation;
        Some([inset(r[0])?, inset(r[2])?])
    }

    /// Class label of an object mass: "low" / "medium" / "high" by rank among `object.masses_lb`
    /// when it lists three masses, none otherwise.
    pub fn mass_class(&self, mass_lb: f64) -> Option<String> {
        let mut sorted = self.object.masses_lb.clone();
        sorted.sort_by(f64::total_cmp);
        if sorted.len() != 3 {
            return None;
        }
        let rank = sorted.iter().position(|m| (m - mass_lb).abs() < 1e-9)?;
        Some(["low", "medium", "high"][rank].to_string())
    }
}

fn read_package(r: &Reader, root: &Value) -> Result<PackageGeometry, DescriptionError> {
    let p = r.get(root, "", "package")?;
    let key = "package";
    let size_x_m = r.positive(p, key, "size_x_m", true, MAX_SIZE_M)?;
    let size_y_m = r.positive(p, key, "size_y_m", true, MAX_SIZE_M)?;
    let thickness_m = r.positive(p, key, "thickness_m", true, MAX_SIZE_M)?;
    if thickness_m >= size_x_m.min(size_y_m) / 2.0 {
        return Err(r.err(
            "package.thickness_m",
            format!(
                "{thickness_m} m: expected less than half the smaller side ({} m) for a flat package",
                size_x_m.min(size_y_m)
            ),
        ));
    }
    let film_mass_kg = r.positive(p, key, "film_mass_kg", true, MAX_MASS_KG)?;
    let markers_value = r.get(p, key, "markers")?;
    let layout = r.array(markers_value, "package.markers", "layout")?;
    if layout.is_empty() {
        return Err(r.err(
            "package.markers.layout",
            "empty; expected the nominal site of every marker",
        ));
    }
    let mut markers = Vec::with_capacity(layout.len());
    for (i, m) in layout.iter().enumerate() {
        let mk = format!("package.markers.layout[{i}]");
        let layer = match r.text(m, &mk, "layer")?.as_str() {
            "top" => Layer::Top,
            "bottom" => Layer::Bottom,
            other => {
                return Err(r.err(
                    &format!("{mk}.layer"),
                    format!("{other:?}: expected \"top\" or \"bottom\""),
                ))
            }
        };
        let x = r.field(m, &mk, "x")?;
        let y = r.field(m, &mk, "y")?;
        if x.abs() > size_x_m / 2.0 + 1e-9 || y.abs() > size_y_m / 2.0 + 1e-9 {
            return Err(r.err(
                &mk,
                format!(
                    "site ({x}, {y}) m lies outside the {size_x_m} x {size_y_m} m package; expected a site on the package"
                ),
            ));
        }
        markers.push(MarkerSite { layer, x, y });
    }
    Ok(PackageGeometry {
        size_x_m,
        size_y_m,
        thickness_m,
        film_mass_kg,
        markers,
    })
}

fn read_tool(r: &Reader, root: &Value) -> Result<ToolLayout, DescriptionError> {
    let t = r.get(root, "", "tool")?;
    let key = "tool";
    let cup_circle_radius_m = r.positive(t, key, "cup_circle_radius_m", false, MAX_SIZE_M)?;
    let cup_angles_deg = r.numbers(t, key, "cup_angles_deg")?;
    if cup_angles_deg.is_empty() {
        return Err(r.err("tool.cup_angles_deg", "empty; expected one angle per cup"));
    }
    if let Some(n) = t.get("n_cups") {
        let n = r.number(n, "tool.n_cups")?;
        if n != cup_angles_deg.len() as f64 {
            return Err(r.err(
                "tool.n_cups",
                format!(
                    "{n}, but tool.cup_angles_deg lists {} angle(s); expected one angle per cup",
                    cup_angles_deg.len()
                ),
            ));
        }
    }
    let cup_inner_ring_radius_m = r.positive(t, key, "cup_inner_ring_radius_m", true, 1.0)?;
    let cup_lip_radius_m = r.positive(t, key, "cup_lip_radius_m", true, 1.0)?;
    if cup_lip_radius_m <= cup_inner_ring_radius_m {
        return Err(r.err(
            "tool.cup_lip_radius_m",
            format!(
                "{cup_lip_radius_m} m: expected more than tool.cup_inner_ring_radius_m ({cup_inner_ring_radius_m} m)"
            ),
        ));
    }
    Ok(ToolLayout {
        cup_circle_radius_m,
        cup_angles_deg,
        cup_inner_ring_radius_m,
        cup_lip_radius_m,
    })
}

fn read_object(
    r: &Reader,
    root: &Value,
    package: &PackageGeometry,
) -> Result<ObjectGeometry, DescriptionError> {
    let o = r.get(root, "", "object")?;
    let key = "object";
    let diameter_m = r.positive(o, key, "diameter_m", true, MAX_SIZE_M)?;
    if diameter_m > package.size_x_m.min(package.size_y_m) {
        return Err(r.err(
            "object.diameter_m",
            format!(
                "{diameter_m} m: expected at most the package's smaller side ({} m), the disc lies inside it",
                package.size_x_m.min(package.size_y_m)
            ),
        ));
    }
    let thickness_m = r.positive(o, key, "thickness_m", true, MAX_SIZE_M)?;
    if thickness_m > package.thickness_m {
        return Err(r.err(
            "object.thickness_m",
            format!(
                "{thickness_m} m: expected at most package.thickness_m ({} m), the disc lies between the layers",
                package.thickness_m
            ),
        ));
    }
    let masses_lb = r.numbers(o, key, "masses_lb")?;
    for (i, m) in masses_lb.iter().enumerate() {
        if !(*m > 0.0 && *m * KG_PER_LB <= MAX_MASS_KG) {
            return Err(r.err(
                &format!("object.masses_lb[{i}]"),
                format!("{m}: expected a mass > 0 lb"),
            ));
        }
    }
    Ok(ObjectGeometry {
        diameter_m,
        thickness_m,
        masses_lb,
    })
}

fn read_frames(r: &Reader, root: &Value) -> Result<MocapFromRobot, DescriptionError> {
    let frames = r.get(root, "", "frames")?;
    let m = r.get(frames, "frames", "mocap_from_robot")?;
    let key = "frames.mocap_from_robot";
    let rows = r.array(m, key, "R")?;
    if rows.len() != 3 {
        return Err(r.err(
            &format!("{key}.R"),
            format!("{} rows; expected a 3 x 3 matrix", rows.len()),
        ));
    }
    let mut rotation = [[0.0; 3]; 3];
    for (i, row) in rows.iter().enumerate() {
        let row_key = format!("{key}.R[{i}]");
        let values = row
            .as_array()
            .ok_or_else(|| r.err(&row_key, "not an array; expected 3 numbers"))?;
        if values.len() != 3 {
            return Err(r.err(&row_key, format!("{} numbers; expected 3", values.len())));
        }
        for (j, v) in values.iter().enumerate() {
            rotation[i][j] = r.number(v, &format!("{row_key}[{j}]"))?;
        }
    }
    // A proper rotation: orthonormal rows and determinant +1.
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let orthonormal = (0..3).all(|i| {
        (0..3).all(|j| (dot(rotation[i], rotation[j]) - f64::from(u8::from(i == j))).abs() < 1e-6)
    });
    let [a, b, c] = rotation;
    let det = dot(
        a,
        [
            b[1] * c[2] - b[2] * c[1],
            b[2] * c[0] - b[0] * c[2],
            b[0] * c[1] - b[1] * c[0],
        ],
    );
    if !orthonormal || (det - 1.0).abs() > 1e-6 {
        return Err(r.err(
            &format!("{key}.R"),
            format!("{rotation:?}: expected a rotation matrix (orthonormal rows, determinant +1)"),
        ));
    }
    let origin_m = r.numbers3(m, key, "o")?;
    Ok(MocapFromRobot { rotation, origin_m })
}

fn read_takes(r: &Reader, root: &Value) -> Result<Vec<TakeDescription>, DescriptionError> {
    let split = r.get(root, "", "split")?;
    let list = |name: &str| -> Result<Vec<String>, DescriptionError> {
        let key = format!("split.{name}");
        r.array(split, "split", name)?
            .iter()
            .enumerate()
            .map(|(i, v)| {
                v.as_str().map(str::to_string).ok_or_else(|| {
                    r.err(&format!("{key}[{i}]"), format!("{v}: expected a take id"))
                })
            })
            .collect()
    };
    let lists = [
        ("train", list("train")?, TakeRole::Train),
        ("test", list("test")?, TakeRole::Test),
        (
            "excluded_failures",
            list("excluded_failures")?,
            TakeRole::Failure,
        ),
    ];
    let entries = r.array(root, "", "trajectories")?;
    let mut takes = Vec::with_capacity(entries.len());
    let mut seen = BTreeSet::new();
    for (i, t) in entries.iter().enumerate() {
        let key = format!("trajectories[{i}]");
        let id = r.text(t, &key, "id")?;
        if !seen.insert(id.clone()) {
            return Err(r.err(
                &format!("{key}.id"),
                format!("{id:?} is listed twice; expected unique ids"),
            ));
        }
        let failure_value = r.get(t, &key, "failure")?;
        let failure = failure_value.as_bool().ok_or_else(|| {
            r.err(
                &format!("{key}.failure"),
                format!("{failure_value}: expected true or false"),
            )
        })?;
        let mut roles = lists.iter().filter(|(_, ids, _)| ids.contains(&id));
        let Some((list_name, _, role)) = roles.next() else {
            return Err(r.err(
                "split",
                format!("take {id:?} ({key}) is in none of split.train, split.test, split.excluded_failures; expected it in one"),
            ));
        };
        if let Some((other, _, _)) = roles.next() {
            return Err(r.err(
                "split",
                format!("take {id:?} is in both split.{list_name} and split.{other}; expected it in one"),
            ));
        }
        if failure != (*role == TakeRole::Failure) {
            return Err(r.err(
                &format!("{key}.failure"),
                format!(
                    "{failure} for take {id:?}, which is in split.{list_name}; expected failure takes exactly in split.excluded_failures"
                ),
            ));
        }
        takes.push(TakeDescription {
            id,
            role: *role,
            object_mass_kg: r.positive(t, &key, "object_mass_kg", true, MAX_MASS_KG)?,
            object_mass_lb: r.positive(t, &key, "object_mass_lb", true, MAX_MASS_KG / KG_PER_LB)?,
            speed: r.text(t, &key, "speed")?,
            placement_angle_deg: r.field(t, &key, "placement_angle_deg")?,
        });
    }
    for (name, ids, _) in &lists {
        if let Some((i, id)) = ids.iter().enumerate().find(|(_, id)| !seen.contains(*id)) {
            return Err(r.err(
                &format!("split.{name}[{i}]"),
                format!("{id:?} is not among the trajectories; expected the id of a listed take"),
            ));
        }
    }
    Ok(takes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/packages-v1/manifest.json")
    }

    fn shipped_value() -> Value {
        serde_json::from_str(&std::fs::read_to_string(shipped()).unwrap()).unwrap()
    }

    #[test]
    fn the_shipped_manifest_reads_with_its_split() {
        let d = PackageDescription::load(&shipped()).unwrap();
        assert_eq!(d.name, "packages-v1");
        assert_eq!(d.takes.len(), 27);
        let count = |role| d.takes.iter().filter(|t| t.role == role).count();
        assert_eq!(
            (
                count(TakeRole::Train),
                count(TakeRole::Test),
                count(TakeRole::Failure)
            ),
            (18, 4, 5)
        );
        assert_eq!(d.take("a45_m1.0_high").unwrap().role, TakeRole::Failure);
        assert_eq!(d.package.markers.len(), 40);
        assert_eq!(d.tool.cup_angles_deg, vec![45.0, 135.0, 225.0, 315.0]);
        assert_eq!(d.mass_class(0.75).as_deref(), Some("medium"));
        // Sites at x = -5.2 in of a 12 in side, y = +4.2 in of a 10 in side (robot y = mocap -z).
        let inset = d.marker_inset_m().unwrap();
        assert!((inset[0] - 0.8 * 0.0254).abs() < 1e-9 && (inset[1] - 0.8 * 0.0254).abs() < 1e-9);
        assert!((d.take("a30_m1.0_low").unwrap().object_mass_kg - KG_PER_LB).abs() < 1e-5);
        // The bottom layer's 20 sites on the conveyor (mocap y = robot z = 0), the first at
        // robot (-5.2 in, -4.2 in): mocap x = -0.13208 - 0.40, z = -(-0.10668 - 0.15).
        let bottom = d.bottom_markers_at_start();
        assert_eq!(bottom.len(), 20);
        assert!(bottom.iter().all(|p| p[1].abs() < 1e-12));
        let first = bottom[0];
        assert!((first[0] + 0.53208).abs() < 1e-9 && (first[2] - 0.25668).abs() < 1e-9);
    }

    #[test]
    fn errors_name_the_key() {
        let path = Path::new("m.json");
        type Edit = fn(&mut Value);
        let cases: [(&str, Edit); 5] = [
            ("package.size_x_m: missing", |v| {
                v["package"].as_object_mut().unwrap().remove("size_x_m");
            }),
            ("package.size_y_m: -0.2", |v| {
                v["package"]["size_y_m"] = (-0.2).into()
            }),
            ("object.thickness_m: 0.05 m", |v| {
                v["object"]["thickness_m"] = 0.05.into()
            }),
            ("trajectories[0].failure: true", |v| {
                v["trajectories"][0]["failure"] = true.into()
            }),
            ("frames.mocap_from_robot.R", |v| {
                v["frames"]["mocap_from_robot"]["R"][0][0] = 2.0.into()
            }),
        ];
        for (expected, edit) in cases {
            let mut value = shipped_value();
            edit(&mut value);
            let msg = PackageDescription::from_value(&value, path)
                .unwrap_err()
                .to_string();
            assert!(
                msg.starts_with("m.json: ") && msg.contains(expected),
                "{msg}"
            );
        }
    }
}
