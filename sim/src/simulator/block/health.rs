//! Health checks: lanes whose state is non-finite, exploding, or whose object left the package
//! are frozen and reported.

use crate::constants::StepConstants;
use crate::episode::{HealthEvent, HealthReason};
use crate::math::{get3, Lanes, V3};
use crate::model::Model;

use super::EnvBlock;

impl<const W: usize> EnvBlock<W> {
    /// Flags and freezes the lanes marked `due` (their clock is at a check) whose state is
    /// non-finite or exploding, or whose disc left the package.
    pub(super) fn check_health(&mut self, model: &Model, k: &StepConstants, due: &[bool; W]) {
        let max_v2 = k.max_speed * k.max_speed;
        let max_d2 = k.max_displacement * k.max_displacement;
        let mut reason: [Option<HealthReason>; W] = [None; W];
        let mut inspect = |x: &V3<Lanes<W>>, v: &V3<Lanes<W>>, x0: &V3<Lanes<W>>| {
            for (l, r) in reason.iter_mut().enumerate() {
                let (p, u, p0) = (get3(x, l), get3(v, l), get3(x0, l));
                let found = if p.iter().chain(&u).any(|c| !c.is_finite()) {
                    Some(HealthReason::NonFinite)
                } else if u.iter().map(|c| c * c).sum::<f32>() > max_v2 {
                    Some(HealthReason::TooFast)
                } else if (0..3).map(|c| (p[c] - p0[c]).powi(2)).sum::<f32>() > max_d2 {
                    Some(HealthReason::TooFar)
                } else {
                    None
                };
                if r.is_none() {
                    *r = found;
                }
            }
        };
        let (state, setup) = (&self.state, &self.setup);
        for i in 0..state.x.len() {
            inspect(&state.x[i], &state.v[i], &setup.x0[i]);
        }
        inspect(&state.disc.com, &state.disc.v, &setup.disc_x0);
        // The disc must stay within the box around the package's particles.
        let mut lo = [[f32::INFINITY; 3]; W];
        let mut hi = [[f32::NEG_INFINITY; 3]; W];
        for x in &state.x[..model.num_package] {
            for l in 0..W {
                let p = get3(x, l);
                for c in 0..3 {
                    lo[l][c] = lo[l][c].min(p[c]);
                    hi[l][c] = hi[l][c].max(p[c]);
                }
            }
        }
        for l in (0..W).filter(|_| k.object_outside) {
            let d = get3(&state.disc.com, l);
            let m = k.object_outside_margin;
            let outside = (0..3).any(|c| d[c] < lo[l][c] - m || d[c] > hi[l][c] + m);
            if reason[l].is_none() && outside {
                reason[l] = Some(HealthReason::ObjectOutside);
            }
        }
        for l in 0..W {
            let q = &self.state.disc.q;
            let quat_ok = q.w.0[l].is_finite() && get3(&q.v, l).iter().all(|c| c.is_finite());
            let r = reason[l].or(if quat_ok {
                None
            } else {
                Some(HealthReason::NonFinite)
            });
            if let (Some(reason), true, true) = (r, due[l], self.state.active.0[l] > 0.5) {
                self.state.active.0[l] = 0.0;
                if self.real[l] {
                    self.events.push(HealthEvent {
                        env: self.envs[l],
                        reason,
                        time: self.state.clock[l] as f64 * k.dt64,
                    });
                }
            }
        }
    }
}
