//! Conversions from the simulator's `f32` arrays to `f64` glam types, the rotation between two
//! orientations (shared by the controller, the observations and the success check), and the serde
//! form of a vector in saved episodes.

use glam::{DQuat, DVec3};

/// A simulator vector as `f64`.
pub(super) fn v3(a: [f32; 3]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

/// A simulator quaternion (x, y, z, w) as a normalised `f64` quaternion.
pub(super) fn quat(q: [f32; 4]) -> DQuat {
    DQuat::from_xyzw(q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64).normalize()
}

/// Rotation vector taking `from` to `to` (world frame, shortest way).
pub(super) fn rotation_between(from: DQuat, to: DQuat) -> DVec3 {
    let mut d = to * from.inverse();
    if d.w < 0.0 {
        d = -d;
    }
    d.to_scaled_axis()
}

/// Serde of a [`DVec3`] as `[x, y, z]`.
pub(super) mod vec3_as_array {
    use glam::DVec3;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// Writes `v` as `[x, y, z]`.
    pub fn serialize<S: Serializer>(v: &DVec3, serializer: S) -> Result<S::Ok, S::Error> {
        v.to_array().serialize(serializer)
    }

    /// Reads `[x, y, z]`.
    pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<DVec3, D::Error> {
        <[f64; 3]>::deserialize(deserializer).map(DVec3::from_array)
    }
}
