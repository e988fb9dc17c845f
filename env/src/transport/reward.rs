//! The transport reward, term by term, from plain numbers (so each term can be checked on
//! hand-made states and logged separately).

use super::config::RewardWeights;

/// What one control step did, as the reward sees it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepOutcome {
    /// Control interval (s).
    pub dt_s: f64,
    /// Path length travelled in the step as a fraction of the whole path.
    pub progress_fraction: f64,
    /// How far the object moved relative to the tool during the step (m).
    pub object_motion_m: f64,
    /// Largest cup utilisation at the end of the step (1 = the seal's limit).
    pub peak_utilisation: f64,
    /// Change of the tool's linear acceleration from the previous step (m/s²).
    pub accel_change_m_s2: f64,
    /// Change of the tool's angular acceleration from the previous step (rad/s²).
    pub angular_accel_change_rad_s2: f64,
    /// The episode failed in this step.
    pub failed: bool,
    /// The package was placed in this step.
    pub succeeded: bool,
}

/// Reward terms of one step (signed: penalties are negative); their sum is the reward.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RewardTerms {
    /// `progress` x path fraction travelled.
    pub progress: f64,
    /// `-time` x interval.
    pub time: f64,
    /// `-object_motion` x object motion relative to the tool.
    pub object_motion: f64,
    /// `-seal` x max(0, peak utilisation - threshold) x interval.
    pub seal: f64,
    /// `-jerk` x change of linear acceleration `- angular_jerk` x change of angular acceleration.
    pub jerk: f64,
    /// `-failure` on the failing step.
    pub failure: f64,
    /// `success` on the placing step.
    pub success: f64,
}

/// Names of the terms, in [`RewardTerms::values`] order.
pub const REWARD_TERM_NAMES: [&str; 7] = [
    "progress",
    "time",
    "object_motion",
    "seal",
    "jerk",
    "failure",
    "success",
];

impl RewardTerms {
    /// The terms of `outcome` under `weights`.
    pub fn of(weights: &RewardWeights, outcome: &StepOutcome) -> Self {
        let w = weights;
        RewardTerms {
            progress: w.progress * outcome.progress_fraction,
            time: -w.time * outcome.dt_s,
            object_motion: -w.object_motion * outcome.object_motion_m,
            seal: -w.seal * (outcome.peak_utilisation - w.seal_threshold).max(0.0) * outcome.dt_s,
            jerk: -w.jerk * outcome.accel_change_m_s2
                - w.angular_jerk * outcome.angular_accel_change_rad_s2,
            failure: if outcome.failed { -w.failure } else { 0.0 },
            success: if outcome.succeeded { w.success } else { 0.0 },
        }
    }

    /// The terms in [`REWARD_TERM_NAMES`] order.
    pub fn values(&self) -> [f64; 7] {
        [
            self.progress,
            self.time,
            self.object_motion,
            self.seal,
            self.jerk,
            self.failure,
            self.success,
        ]
    }

    /// The reward: the sum of the terms.
    pub fn total(&self) -> f64 {
        self.values().iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weights() -> RewardWeights {
        RewardWeights {
            progress: 10.0,
            time: 0.5,
            object_motion: 20.0,
            seal: 4.0,
            seal_threshold: 0.5,
            jerk: 0.01,
            angular_jerk: 0.002,
            failure: 30.0,
            success: 15.0,
        }
    }

    #[test]
    fn each_term_follows_its_weight_on_a_hand_made_step() {
        let outcome = StepOutcome {
            dt_s: 0.05,
            progress_fraction: 0.02,
            object_motion_m: 0.003,
            peak_utilisation: 0.75,
            accel_change_m_s2: 2.0,
            angular_accel_change_rad_s2: 5.0,
            failed: false,
            succeeded: false,
        };
        let t = RewardTerms::of(&weights(), &outcome);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(t.progress, 0.2), "{t:?}");
        assert!(close(t.time, -0.025), "{t:?}");
        assert!(close(t.object_motion, -0.06), "{t:?}");
        // 4 x (0.75 - 0.5) x 0.05
        assert!(close(t.seal, -0.05), "{t:?}");
        // 0.01 x 2 + 0.002 x 5
        assert!(close(t.jerk, -0.03), "{t:?}");
        assert_eq!((t.failure, t.success), (0.0, 0.0));
        assert!(close(t.total(), 0.2 - 0.025 - 0.06 - 0.05 - 0.03));
    }

    #[test]
    fn seal_term_is_zero_below_the_threshold_and_outcomes_pay_once() {
        let calm = StepOutcome {
            dt_s: 0.05,
            peak_utilisation: 0.3,
            ..StepOutcome::default()
        };
        assert_eq!(RewardTerms::of(&weights(), &calm).seal, 0.0);
        let failed = RewardTerms::of(
            &weights(),
            &StepOutcome {
                failed: true,
                ..calm
            },
        );
        assert_eq!(failed.failure, -30.0);
        let placed = RewardTerms::of(
            &weights(),
            &StepOutcome {
                succeeded: true,
                ..calm
            },
        );
        assert_eq!((placed.success, placed.failure), (15.0, 0.0));
        // Standing still costs time and nothing else.
        assert!((RewardTerms::of(&weights(), &calm).total() + 0.025).abs() < 1e-12);
    }
}
