//! The decision variables of an open-loop command: [`KnotCurve`], smooth curves in time of the
//! three actions through knots evenly spaced over a horizon, and the actions they give at each
//! control step (uniform Catmull-Rom interpolation, held after the horizon); and
//! [`CommandLibrary`], the commands for known place poses.

/// Actions per control step: path speed (m/s), tilt offsets about x and z (rad).
pub const ACTIONS: usize = 3;

/// Smooth curves in time of the three actions, each given by `knots` values evenly spaced over
/// `[0, horizon_s]`. The decision vector holds the path speed's knots, then the tilt offset
/// about x's, then about z's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KnotCurve {
    /// Knots per action (at least 2).
    pub knots: usize,
    /// Time of the last knot (s); each action holds its last knot's value after it.
    pub horizon_s: f64,
}

impl KnotCurve {
    /// Length of a decision vector.
    pub fn dimension(&self) -> usize {
        ACTIONS * self.knots
    }

    /// The value at time `t` of the curve through `knots` (uniform Catmull-Rom: through every
    /// knot, continuous slope; the end tangents extrapolate linearly, so a linear sequence of
    /// knots gives that line exactly).
    pub fn value(&self, knots: &[f64], t: f64) -> f64 {
        let n = knots.len();
        let spacing = self.horizon_s / (n - 1) as f64;
        let x = (t / spacing).clamp(0.0, (n - 1) as f64);
        let i = (x.floor() as usize).min(n - 2);
        let u = x - i as f64;
        let p1 = knots[i];
        let p2 = knots[i + 1];
        let p0 = if i == 0 { 2.0 * p1 - p2 } else { knots[i - 1] };
        let p3 = if i + 2 < n {
            knots[i + 2]
        } else {
            2.0 * p2 - p1
        };
        let (u2, u3) = (u * u, u * u * u);
        0.5 * (2.0 * p1
            + (p2 - p0) * u
            + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u2
            + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u3)
    }

    /// The actions of decision vector `x` at time `t` (s from the episode's start).
    pub fn actions(&self, x: &[f64], t: f64) -> [f64; ACTIONS] {
        std::array::from_fn(|a| self.value(&x[a * self.knots..(a + 1) * self.knots], t))
    }
}

/// Open-loop commands for known place poses: each optimised for the nominal package at one
/// target tilt; an episode plays the command of the tilt nearest its own. One command is a
/// library of one, played whatever the tilt.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandLibrary {
    /// The curve every command's knots describe.
    pub curve: KnotCurve,
    /// `(target tilt (rad), knots)` of each command.
    pub commands: Vec<(f64, Vec<f64>)>,
}

impl CommandLibrary {
    /// The knots of the command whose tilt is nearest `target_tilt_rad` (the first on a tie).
    pub fn knots_for(&self, target_tilt_rad: f64) -> &[f64] {
        let distance = |(tilt, _): &&(f64, Vec<f64>)| (tilt - target_tilt_rad).abs();
        let nearest = self
            .commands
            .iter()
            .min_by(|a, b| distance(a).total_cmp(&distance(b)))
            .expect("a library holds at least one command");
        &nearest.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_knot_curve_passes_through_its_knots_reproduces_lines_and_holds_after_the_horizon() {
        let curve = KnotCurve {
            knots: 5,
            horizon_s: 2.0,
        };
        let knots = [0.1, 0.7, -0.3, 0.4, 0.2];
        for (i, k) in knots.iter().enumerate() {
            assert!((curve.value(&knots, 0.5 * i as f64) - k).abs() < 1e-12);
        }
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(curve.value(&knots, 5.0), 0.2));
        assert!(close(curve.value(&knots, -1.0), 0.1));
        let line = [1.0, 1.5, 2.0, 2.5, 3.0];
        for j in 0..=40 {
            let t = 0.05 * j as f64;
            assert!((curve.value(&line, t) - (1.0 + t)).abs() < 1e-12, "{t}");
        }
        // Continuous slope at an interior knot.
        let h = 1e-6;
        let left = (curve.value(&knots, 1.0) - curve.value(&knots, 1.0 - h)) / h;
        let right = (curve.value(&knots, 1.0 + h) - curve.value(&knots, 1.0)) / h;
        assert!((left - right).abs() < 1e-4, "{left} {right}");
        // The decision vector's three blocks are the three actions.
        let x: Vec<f64> = [[0.5; 5], [0.1; 5], [-0.2; 5]].concat();
        let actions = curve.actions(&x, 0.7);
        assert!(close(actions[0], 0.5) && close(actions[1], 0.1) && close(actions[2], -0.2));
        assert_eq!(curve.dimension(), 15);
    }

    #[test]
    fn a_library_plays_the_command_of_the_nearest_tilt() {
        let curve = KnotCurve {
            knots: 2,
            horizon_s: 1.0,
        };
        let command = |v: f64| vec![v, v, 0.0, 0.0, 0.0, 0.0];
        let library = CommandLibrary {
            curve,
            commands: vec![
                (35f64.to_radians(), command(0.3)),
                (45f64.to_radians(), command(0.5)),
                (55f64.to_radians(), command(0.7)),
            ],
        };
        for (tilt, speed) in [
            (30.0, 0.3),
            (39.9, 0.3),
            (40.1, 0.5),
            (49.0, 0.5),
            (60.0, 0.7),
        ] {
            let tilt: f64 = tilt;
            assert_eq!(library.knots_for(tilt.to_radians())[0], speed, "{tilt}");
        }
    }
}
