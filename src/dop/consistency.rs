//! The geometric check's memory of one map point (beyond the paper; see the
//! `[dop] geometric` and `static_check` parameters of [`DopConfig`]).
//!
//! After each tracked frame whose pose is trusted, every map point matched in it is
//! *consistent* (it reprojects within the \(\chi^2_{0.95}\) gate of the pose estimated
//! from the static points: 2 degrees of freedom, 3 with depth), *inconsistent* (its
//! error exceeds `geometric_gate` times that gate, or the rigidity test finds it moved)
//! or *unclear* (in between: it breaks both runs below). Points in a dynamic state took
//! no part in that pose, so for them the test is independent evidence.
//!
//! The unclear band exists for real images: a static point whose stereo depth is a
//! little off (at 20-40 m a disparity error of half a pixel is 0.5-2 m) leaves the
//! \(\chi^2_{0.95}\) gate of later frames for frames in a row, on KITTI 15-19 % of the
//! static matches, but only 2-3 % leave four times the gate. A fast mover leaves it by
//! far, but a band also lets some movers through (the synthetic street_kitti00, whose
//! cars no detector finds, was worse with 4), so `geometric_gate` is 1 by default.
//!
//! - **Outliers raise** \(P\): `geometric_frames` inconsistent frames in a row give
//!   \(P \leftarrow (1 - \alpha_g) P + \alpha_g\) (points in a static state only: the
//!   others are already out of the pose).
//! - **Verified static lowers** \(P\): a run of consistent frames spanning at least
//!   `static_seconds` makes the point *verified static*; from then on every
//!   `geometric_frames` consistent frames give \(P \leftarrow (1 - \alpha_g) P\), and a
//!   keyframe's detection that puts it on a dynamic object counts as \(S_t = 0\) (a
//!   parked car: a dynamic class that does not move; people are never verified static,
//!   `never_static_classes`). One frame that is not consistent (unclear or
//!   inconsistent) ends the run.
//! - **Never on a moving object**: while the latest keyframe that saw the point put it
//!   on an object followed moving (`track_moved_metres`, [`super::tracks`]) or of a
//!   class that moves on its own (`never_static_classes`), it is not
//!   verified static, however long its run: a walker who stops for a second is
//!   consistent all that time, and verifying them took them into the pose when they
//!   walked on.

use super::DopConfig;

/// Consistency runs of one map point.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Consistency {
    /// Tracked frames in a row where the point was inconsistent.
    pub outlier_run: u32,
    /// Consistent frames in the current run, and the times of its first and last.
    pub inlier_run: u32,
    /// The time of the run's first consistent frame.
    pub since: f64,
    /// The time of its last.
    pub until: f64,
    /// The latest keyframe that saw the point put it on an object followed moving.
    pub on_moving_object: bool,
    /// Trusted frames in which the point was judged, consistent or not.
    pub tested: u32,
    /// Judged frames in a row in which the point was not inconsistent (consistent or
    /// unclear): it held still as far as the check can tell.
    pub steady_run: u32,
}

/// What one observation did to \(P\).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The geometric check raised the probability.
    Raised,
    /// It lowered it.
    Lowered,
    /// It left it as it was.
    Unchanged,
}

/// The geometric check's verdict on one map point in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Judgement {
    /// Within the pose's gate.
    Consistent,
    /// Outside it, but within `geometric_gate` times it.
    Unclear,
    /// Beyond that, or moved by the rigidity test.
    Inconsistent,
}

impl Consistency {
    /// Whether the current consistent run spans `static_seconds`.
    pub fn verified_static(&self, config: &DopConfig) -> bool {
        config.static_check
            && !self.on_moving_object
            && self.inlier_run > 0
            && self.until - self.since >= f64::from(config.static_seconds)
    }

    /// Records one trusted frame at `time` and updates `moving` (\(P\)); `dynamic` says
    /// whether the point was left out of the pose. An unclear frame ends both runs and
    /// changes nothing else.
    pub fn judge(
        &mut self,
        judgement: Judgement,
        time: f64,
        dynamic: bool,
        moving: &mut f32,
        config: &DopConfig,
    ) -> Verdict {
        match judgement {
            Judgement::Consistent => self.observe(true, time, dynamic, moving, config),
            Judgement::Inconsistent => self.observe(false, time, dynamic, moving, config),
            Judgement::Unclear => {
                self.tested = self.tested.saturating_add(1);
                self.steady_run = self.steady_run.saturating_add(1);
                (self.inlier_run, self.outlier_run) = (0, 0);
                Verdict::Unchanged
            }
        }
    }

    /// [`Self::judge`] of a consistent or inconsistent frame.
    pub fn observe(
        &mut self,
        consistent: bool,
        time: f64,
        dynamic: bool,
        moving: &mut f32,
        config: &DopConfig,
    ) -> Verdict {
        self.tested = self.tested.saturating_add(1);
        if !consistent {
            (self.inlier_run, self.steady_run) = (0, 0);
            if dynamic {
                return Verdict::Unchanged;
            }
            self.outlier_run += 1;
            if self.outlier_run < config.geometric_frames {
                return Verdict::Unchanged;
            }
            self.outlier_run = 0;
            *moving = super::update(*moving, true, config.alpha_geometric);
            return Verdict::Raised;
        }
        self.outlier_run = 0;
        self.steady_run = self.steady_run.saturating_add(1);
        if self.inlier_run == 0 {
            self.since = time;
        }
        self.inlier_run += 1;
        self.until = time;
        if self.verified_static(config) && self.inlier_run.is_multiple_of(config.geometric_frames) {
            *moving = super::update(*moving, false, config.alpha_geometric);
            return Verdict::Lowered;
        }
        Verdict::Unchanged
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outliers_in_a_row_raise_a_static_point_and_an_inlier_breaks_the_row() {
        let config = DopConfig::default();
        let (mut c, mut p) = (Consistency::default(), 0.5);
        // (consistent, verdict): two outliers raise; a third starts a new row, which an
        // inlier breaks.
        let frames = [
            (false, Verdict::Unchanged),
            (false, Verdict::Raised),
            (false, Verdict::Unchanged),
            (true, Verdict::Unchanged),
            (false, Verdict::Unchanged),
        ];
        for (n, (consistent, verdict)) in frames.into_iter().enumerate() {
            let t = n as f64 * 0.1;
            assert_eq!(
                c.observe(consistent, t, false, &mut p, &config),
                verdict,
                "frame {n}"
            );
        }
        assert!((p - 0.65).abs() < 1e-6);
        // A dynamic point is not raised further.
        let (mut c, mut p) = (Consistency::default(), 0.8);
        for t in 0..4 {
            c.observe(false, f64::from(t), true, &mut p, &config);
        }
        assert_eq!(p, 0.8);
    }

    #[test]
    fn a_point_consistent_for_static_seconds_is_verified_and_lowered() {
        let config = DopConfig::default();
        let (mut c, mut p) = (Consistency::default(), 0.9);
        let frames = (config.static_seconds * 10.0).round() as u32;
        // 10 Hz: consistent from 0 s; verified once the run spans static_seconds.
        for n in 0..frames {
            let v = c.observe(true, f64::from(n) * 0.1, true, &mut p, &config);
            assert_eq!(v, Verdict::Unchanged, "frame {n}");
            assert!(!c.verified_static(&config));
        }
        let mut lowered = 0;
        for n in frames..frames + 4 {
            if c.observe(true, f64::from(n) * 0.1, true, &mut p, &config) == Verdict::Lowered {
                lowered += 1;
            }
            assert!(c.verified_static(&config));
        }
        assert_eq!(lowered, 4 / config.geometric_frames as usize);
        assert!((p - 0.9 * 0.7f32.powi(lowered as i32)).abs() < 1e-5);
        // One inconsistent frame ends the run.
        c.observe(false, 2.0, true, &mut p, &config);
        assert!(!c.verified_static(&config));
        // Off: never verified.
        let off = DopConfig {
            static_check: false,
            ..config
        };
        let (mut c, mut p) = (Consistency::default(), 0.9);
        for n in 0..40 {
            assert_eq!(
                c.observe(true, f64::from(n) * 0.1, true, &mut p, &off),
                Verdict::Unchanged
            );
        }
        assert_eq!(p, 0.9);
    }
}
