//! The dynamic object probability (DOP) model (Ai et al. 2021, written out in
//! `../shared/reference/dop-model.md`). It knows nothing of ORB or of the detector's
//! internals: it takes keypoint positions and depths, their matches, and boxes, and
//! returns moving probabilities and states.
//!
//! - Map-point update at a detected keyframe ([`update`]):
//!   \(P_t(X) = (1 - \alpha) P_{t-1}(X) + \alpha S_t(x)\).
//! - Propagation to every frame ([`propagate`]): map-point match first, then a
//!   last-frame match, else \(P_{init}\).
//! - Matching point expansion ([`expand`]):
//!   \(P(x) = \mathrm{clamp}(P_{init} + \sum_{h} \lambda(|x - h|)(P(h) - P_{init}), 0, 1)\)
//!   over high-confidence keypoints \(h\) within \(\gamma\) pixels,
//!   \(\lambda(d) = C e^{-d / C}\) (a reconstruction).
//! - Four states ([`State`]; thresholds are a reconstruction) and the removal rule.
//! - Box refinement by depth ([`boxes`], the paper's Algorithm 1, a reconstruction).

pub mod boxes;
pub mod consistency;
pub mod rigidity;
pub mod standing;
pub mod tracks;

use serde::{Deserialize, Serialize};

use crate::checks::{self, BadValue};

/// How detections are used against moving objects (`dopslam run --no-dop |
/// --mask-boxes | --dop`).
///
/// The one mode enum of the project: the tracking pass, the dense masks
/// (`Off`: fuse everything; `MaskBoxes`: whole dynamic boxes; `Dop`: the model's
/// objects and dynamic keypoints) and the batch's modes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// ORB-SLAM2 behaviour: detections are not used (`--no-dop`; batch manifests may
    /// say `no-dop`).
    #[serde(alias = "no-dop")]
    Off,
    /// The naive method: every map point seen inside a dynamic box of a detected
    /// keyframe is removed.
    MaskBoxes,
    /// The DOP model.
    Dop,
}

impl Mode {
    /// Every mode, in the batch's order.
    pub const ALL: [Mode; 3] = [Mode::Dop, Mode::Off, Mode::MaskBoxes];

    /// The name in batch manifests, folders and tables.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Dop => "dop",
            Mode::Off => "no-dop",
            Mode::MaskBoxes => "mask-boxes",
        }
    }

    /// The mode a report or manifest names: its serialised name (`off`, `mask-boxes`,
    /// `dop`) or [`Self::name`]; `None` for any other text.
    pub fn from_name(name: &str) -> Option<Mode> {
        match name {
            "off" | "no-dop" => Some(Mode::Off),
            "mask-boxes" => Some(Mode::MaskBoxes),
            "dop" => Some(Mode::Dop),
            _ => None,
        }
    }

    /// The moving probability above which a map point is dynamic and takes no part
    /// in new points, local BA or the global pass: the model's removal threshold with
    /// the DOP model, else 1 (none is).
    pub fn removal_threshold(self, dop: &DopConfig) -> f32 {
        match self {
            Mode::Dop => dop.removal_threshold,
            Mode::Off | Mode::MaskBoxes => 1.0,
        }
    }

    /// The `dopslam run` flag.
    pub fn flag(self) -> &'static str {
        match self {
            Mode::Dop => "--dop",
            Mode::Off => "--no-dop",
            Mode::MaskBoxes => "--mask-boxes",
        }
    }
}

/// The model's parameters; every step can be switched off for ablations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DopConfig {
    /// Which method runs (with no detections every mode behaves as `off`).
    pub mode: Mode,
    /// Smoothing weight of the latest detection: 0.3 RGB-D, 0.5 stereo (paper).
    pub alpha_rgbd: f32,
    /// The same weight for a stereo sensor.
    pub alpha_stereo: f32,
    /// Probability of anything unknown (paper: 0.5).
    pub p_init: f32,
    /// Expansion radius in pixels (reconstruction).
    pub gamma: f32,
    /// Expansion weight scale \(C\) of \(\lambda(d) = C e^{-d/C}\), pixels (reconstruction).
    pub c: f32,
    /// State thresholds: high-confidence static below the first, low-confidence static
    /// below the second, low-confidence dynamic below the third (reconstruction).
    pub thresholds: [f32; 3],
    /// Keypoints and map points with \(P\) above this are removed before pose
    /// estimation. Strictly above: \(P_{init}\) itself (nothing known) is kept.
    pub removal_threshold: f32,
    /// Map points at or above this after a keyframe update are culled: they "stay
    /// dynamic". From \(P_{init}\) with \(\alpha = 0.3\), 0.9 takes five detections in
    /// a row (0.65, 0.755, 0.83, 0.88, 0.92). Culling earlier (at 0.75, two detections)
    /// leaves propagation and expansion no high-confidence dynamic points to spread
    /// from (reconstruction; measured in the README).
    pub cull_threshold: f32,
    /// Depth tolerance of box refinement, metres (reconstruction).
    pub delta_z: f32,
    /// Central part of a box (fraction of width and height) whose depths give the
    /// object's depth.
    pub central_fraction: f32,
    /// Propagation: new map points take the moving probability of the keypoints they come from.
    pub propagation: bool,
    /// Expansion: keypoints near dynamic ones in image and depth share their probability.
    pub expansion: bool,
    /// Detected boxes are refined to the object's depth segment.
    pub refine_boxes: bool,
    /// Follow dynamic objects across keyframes ([`tracks`]): a late detection reaches
    /// the keyframes made since, and a person the detector misses on one keyframe keeps
    /// their (predicted) box for `track_seconds` (an extension of the paper).
    pub track_boxes: bool,
    /// With `track_boxes`: every tracked frame sees the boxes of the followed objects
    /// whose class moves on its own (`never_static_classes`: people), predicted to its
    /// time and projected with its pose; keypoints nothing else knows about (no map
    /// point and no last-frame match, or a new map point no detection has touched) that
    /// fall on a person take one detection's update ([`raise_unknown_in_boxes`]). So a late detection reaches
    /// the frames tracked since, and a person's new keypoints between keyframes are
    /// dynamic before any keyframe sees them.
    pub track_frames: bool,
    /// The dynamic classes (COCO names) followed across keyframes: those whose speed
    /// `track_max_speed` and `track_gate` bound (people). Objects of the other dynamic
    /// classes act on the keyframe they were detected in only, as in the paper: a car
    /// at 25 m/s leaves `track_gate` between two keyframes, so each detection started
    /// a new track whose box, predicted at walking speed, stayed for `track_seconds`
    /// on the road it had left (real KITTI 01; docs/design.md).
    pub track_classes: Vec<String>,
    /// How long a followed object is predicted without a new detection, seconds.
    pub track_seconds: f32,
    /// Association distance of a predicted object and a detected one, metres.
    pub track_gate: f32,
    /// Fastest motion assumed for a dynamic object, m/s (velocity clamp and the growth
    /// of a predicted box's margin).
    pub track_max_speed: f32,
    /// A followed object whose centre has been this far (metres) from where it was
    /// first seen has *moved*: its points are never verified static while it is
    /// followed, so a person who stops for a moment stays dynamic (without this, their
    /// consistent points were verified static after `static_seconds` and took the pose
    /// with them when they walked on). Objects that never move this far (a parked car,
    /// a detector's false box on a wall) keep the static check; people never do
    /// (`never_static_classes`).
    pub track_moved_metres: f32,
    /// Dynamic classes (COCO names) that move on their own: their objects count as
    /// moved from the first detection, so their points are never verified static. A
    /// person sitting still for a minute may stand up at any moment, and a person
    /// verified static while still takes the pose with them when they go (measured in
    /// the README); a parked car stays parked.
    pub never_static_classes: Vec<String>,
    /// The geometric check (beyond the paper, needs no detector): a map point that is
    /// inconsistent (`geometric_gate`) in `geometric_frames` tracked frames in a row
    /// gets the update \(P \leftarrow (1 - \alpha_g) P + \alpha_g\) with
    /// `alpha_geometric`; frames where more than `geometric_max_outliers` of the
    /// matches are outside the pose's gate are not used (the pose itself may be wrong
    /// there).
    pub geometric: bool,
    /// Frames over which a point's inconsistency is counted.
    pub geometric_frames: u32,
    /// The smoothing weight of the geometric check's evidence.
    pub alpha_geometric: f32,
    /// The share of outliers in those frames above which a point counts as moving.
    pub geometric_max_outliers: f32,
    /// How far outside the pose's gate a point must reproject to count as inconsistent
    /// (an outlier that raises \(P\)): its error \(e^\top \Omega e\) above this many
    /// times the gate \(\chi^2_{0.95}\). A point between the gate and this is neither
    /// consistent nor inconsistent: it breaks both runs. On real images a static point
    /// whose stereo depth is a little off leaves the gate for frames in a row (15-19 %
    /// of the static matches on KITTI) but rarely 4 times as wide. 1 (the default):
    /// the pose's own gate, no band. 4 took 40 % of the false dynamic keypoints out on
    /// real KITTI 06 but made the synthetic street_kitti00, whose cars no detector
    /// finds, worse in 2 of 2 runs (`docs/dop-model.md`, "The unclear band").
    pub geometric_gate: f32,
    /// The rigidity test of the geometric check ([`rigidity`]): a matched point that
    /// keeps its distances (within `rigidity_sigmas` standard deviations of the
    /// sensor's depth noise) to fewer than `rigidity_agreement` of the others counts
    /// as a pose outlier whatever the pose says. 0 sigmas: off.
    pub rigidity_sigmas: f32,
    /// The share of a point's partners that must agree before the rigidity test calls it moved.
    pub rigidity_agreement: f32,
    /// The other half of the geometric check ([`consistency`]): a point that stays
    /// consistent with the static points' pose for `static_seconds` is verified static;
    /// its \(P\) then falls as outliers make it rise, and a detection counts as
    /// \(S_t = 0\) on it (parked cars, seated people).
    pub static_check: bool,
    /// How long a box must stay still to count as static, seconds.
    pub static_seconds: f32,
    /// Standing objects ([`standing`]): a detected box of a dynamic class that may stand
    /// (not `never_static_classes`) whose points the geometric check finds holding still
    /// counts as a static object on that keyframe: its points take \(S_t = 0\) and it is
    /// no wait zone. A parked car is judged by the frames that saw it, not only by its
    /// class. Off without the geometric check (`geometric`), which does the judging.
    pub standing_boxes: bool,
    /// The points holding still (judged in the last `geometric_frames` frames,
    /// consistent or unclear in each) a box needs before it can stand.
    pub standing_min_points: u32,
    /// The share of its judged points that must hold still.
    pub standing_share: f32,
}

impl Default for DopConfig {
    fn default() -> Self {
        Self {
            mode: Mode::Dop,
            alpha_rgbd: 0.3,
            alpha_stereo: 0.5,
            p_init: 0.5,
            gamma: 15.0,
            c: 5.0,
            thresholds: [0.25, 0.5, 0.75],
            removal_threshold: 0.5,
            cull_threshold: 0.9,
            delta_z: 0.4,
            central_fraction: 0.5,
            propagation: true,
            expansion: true,
            refine_boxes: true,
            track_boxes: true,
            track_frames: true,
            track_classes: vec!["person".into()],
            track_seconds: 1.0,
            track_gate: 0.7,
            track_max_speed: 1.5,
            track_moved_metres: 0.5,
            never_static_classes: vec!["person".into()],
            geometric: true,
            geometric_frames: 2,
            alpha_geometric: 0.3,
            geometric_max_outliers: 0.35,
            geometric_gate: 1.0,
            rigidity_sigmas: 3.0,
            rigidity_agreement: 0.5,
            static_check: true,
            static_seconds: 1.0,
            standing_boxes: true,
            standing_min_points: 10,
            standing_share: 0.8,
        }
    }
}

impl DopConfig {
    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::each(
            "dop",
            checks::unit_interval,
            &[
                ("alpha_rgbd", self.alpha_rgbd),
                ("alpha_stereo", self.alpha_stereo),
                ("p_init", self.p_init),
                ("removal_threshold", self.removal_threshold),
                ("cull_threshold", self.cull_threshold),
                ("central_fraction", self.central_fraction),
                ("alpha_geometric", self.alpha_geometric),
                ("geometric_max_outliers", self.geometric_max_outliers),
                ("rigidity_agreement", self.rigidity_agreement),
                ("standing_share", self.standing_share),
            ],
        )?;
        checks::each(
            "dop",
            checks::non_negative,
            &[
                ("rigidity_sigmas", self.rigidity_sigmas),
                ("track_seconds", self.track_seconds),
                ("track_gate", self.track_gate),
                ("track_max_speed", self.track_max_speed),
                ("track_moved_metres", self.track_moved_metres),
                ("static_seconds", self.static_seconds),
                ("gamma", self.gamma),
            ],
        )?;
        checks::positive("dop.c", self.c)?;
        checks::positive("dop.delta_z", self.delta_z)?;
        checks::at_least_one("dop.geometric_frames", self.geometric_frames)?;
        if self.geometric_gate.is_nan() || self.geometric_gate < 1.0 {
            return Err(BadValue::new(
                "dop.geometric_gate",
                format!(
                    "must be at least 1 (the pose's own gate), got {}",
                    self.geometric_gate
                ),
            ));
        }
        // 0 would let a box with no judged point stand: every car static.
        checks::at_least_one("dop.standing_min_points", self.standing_min_points)?;
        let t = self.thresholds;
        if !(t[0] <= t[1] && t[1] <= t[2]) {
            return Err(BadValue::new(
                "dop.thresholds",
                format!("must increase, got {t:?}"),
            ));
        }
        Ok(())
    }

    /// The state of probability `p`.
    pub fn state(&self, p: f32) -> State {
        let t = self.thresholds;
        if p < t[0] {
            State::StaticHigh
        } else if p < t[1] {
            State::StaticLow
        } else if p < t[2] {
            State::DynamicLow
        } else {
            State::DynamicHigh
        }
    }

    /// Whether objects of `class` are followed across keyframes (`track_boxes` and
    /// `track_classes`).
    pub fn follows(&self, class: &str) -> bool {
        self.track_boxes && self.track_classes.iter().any(|c| c == class)
    }

    /// Whether objects of `class` move on their own (`never_static_classes`: people).
    pub fn moves_on_its_own(&self, class: &str) -> bool {
        self.never_static_classes.iter().any(|c| c == class)
    }

    /// Whether `p` is removed before pose estimation.
    pub fn removed(&self, p: f32) -> bool {
        p > self.removal_threshold
    }
}

/// The four confidence states (paper's Fig. 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// \(P < t_0\): static, high confidence.
    StaticHigh,
    /// \(t_0 \le P < t_1\): static, low confidence.
    StaticLow,
    /// \(t_1 \le P < t_2\): dynamic, low confidence.
    DynamicLow,
    /// \(P \ge t_2\): dynamic, high confidence.
    DynamicHigh,
}

impl State {
    /// Whether the state is one of the two high-confidence ones.
    pub fn high_confidence(self) -> bool {
        matches!(self, State::StaticHigh | State::DynamicHigh)
    }
}

/// The keyframe update of one map point (paper's Eq. 2).
pub fn update(previous: f32, on_dynamic_object: bool, alpha: f32) -> f32 {
    (1.0 - alpha) * previous + alpha * if on_dynamic_object { 1.0 } else { 0.0 }
}

/// Where a keypoint's probability came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// From the map point the keypoint matched.
    MapPoint,
    /// From the keypoint it matched in the last frame.
    LastFrame,
    /// The initial value, \(P_{init}\).
    Initial,
}

/// Propagation (step 2): per keypoint, the probability of its matched map point, else of
/// its matched last-frame keypoint, else \(P_{init}\).
pub fn propagate(
    map_point: &[Option<f32>],
    last_frame: &[Option<f32>],
    p_init: f32,
) -> (Vec<f32>, Vec<Origin>) {
    map_point
        .iter()
        .zip(last_frame)
        .map(|(m, l)| match (m, l) {
            (Some(p), _) => (*p, Origin::MapPoint),
            (None, Some(p)) => (*p, Origin::LastFrame),
            (None, None) => (p_init, Origin::Initial),
        })
        .unzip()
}

/// Matching point expansion (step 3): keypoints that got \(P_{init}\) take the summed,
/// distance-weighted influence of the high-confidence keypoints within \(\gamma\).
/// `positions` are pixels; `probabilities` and `origins` come from [`propagate`].
pub fn expand(
    config: &DopConfig,
    positions: &[(f32, f32)],
    probabilities: &[f32],
    origins: &[Origin],
) -> Vec<f32> {
    let high: Vec<usize> = (0..positions.len())
        .filter(|&i| {
            origins[i] != Origin::Initial && config.state(probabilities[i]).high_confidence()
        })
        .collect();
    let mut out = probabilities.to_vec();
    for i in 0..positions.len() {
        if origins[i] != Origin::Initial {
            continue;
        }
        let (x, y) = positions[i];
        let mut sum = 0.0;
        for &h in &high {
            let (hx, hy) = positions[h];
            let d = ((x - hx).powi(2) + (y - hy).powi(2)).sqrt();
            if d < config.gamma {
                sum += config.c * (-d / config.c).exp() * (probabilities[h] - config.p_init);
            }
        }
        out[i] = (config.p_init + sum).clamp(0.0, 1.0);
    }
    out
}

/// Keypoints that nothing knows about and that `boxes` call dynamic
/// ([`boxes::verdicts`], each box with its object depth) take one detection's update
/// from \(P_{init}\), \(P = (1 - \alpha) P_{init} + \alpha\), unless they already have
/// more (expansion). Unknown: matched to nothing ([`Origin::Initial`]), or still at
/// exactly \(P_{init}\) (a new map point whose keyframe's detection has not come back).
/// Returns how many were raised.
pub fn raise_unknown_in_boxes(
    config: &DopConfig,
    keypoints: &[boxes::Keypoint],
    origins: &[Origin],
    probabilities: &mut [f32],
    boxes: &[boxes::ObjectBox],
    alpha: f32,
) -> usize {
    let raised = update(config.p_init, true, alpha);
    let verdict = boxes::verdicts(config, keypoints, boxes);
    let mut count = 0;
    for ((p, origin), s) in probabilities.iter_mut().zip(origins).zip(verdict) {
        let unknown = *origin == Origin::Initial || *p == config.p_init;
        if unknown && s == Some(true) && *p < raised {
            *p = raised;
            count += 1;
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mode_is_found_by_each_of_its_names_and_nothing_else() {
        for mode in Mode::ALL {
            assert_eq!(Mode::from_name(mode.name()), Some(mode));
            let serialised = serde_json::to_string(&mode).unwrap();
            assert_eq!(Mode::from_name(serialised.trim_matches('"')), Some(mode));
        }
        assert_eq!(Mode::from_name(""), None);
        assert_eq!(Mode::from_name("DOP"), None);
    }

    #[test]
    fn unknown_keypoints_on_a_followed_object_are_raised() {
        let config = DopConfig::default();
        let person = boxes::ObjectBox {
            bbox: [100.0, 100.0, 200.0, 300.0],
            dynamic: true,
            depth: Some(2.0),
            moved: true,
        };
        let kp = |x, y, depth| boxes::Keypoint { x, y, depth };
        // On the person and unknown; on the person but matched to a static map point;
        // the wall behind, inside the box; outside the box; on the person, matched to
        // a map point no detection has touched yet.
        let keypoints = [
            kp(150.0, 200.0, 2.1),
            kp(160.0, 210.0, 2.0),
            kp(120.0, 150.0, 4.0),
            kp(300.0, 200.0, 2.0),
            kp(170.0, 220.0, 1.9),
        ];
        let origins = [
            Origin::Initial,
            Origin::MapPoint,
            Origin::Initial,
            Origin::Initial,
            Origin::MapPoint,
        ];
        let mut p = vec![0.5, 0.1, 0.5, 0.5, 0.5];
        let raised = raise_unknown_in_boxes(&config, &keypoints, &origins, &mut p, &[person], 0.3);
        assert_eq!(raised, 2);
        assert!((p[0] - 0.65).abs() < 1e-6 && (p[4] - 0.65).abs() < 1e-6);
        assert_eq!(&p[1..4], &[0.1, 0.5, 0.5]);
        assert!(config.removed(p[0]) && !config.removed(p[2]));
        // A static box raises nothing.
        let chair = boxes::ObjectBox {
            dynamic: false,
            ..person
        };
        let mut q = vec![0.5; 5];
        assert_eq!(
            raise_unknown_in_boxes(&config, &keypoints, &origins, &mut q, &[chair], 0.3),
            0
        );
    }

    #[test]
    fn update_rule_by_hand() {
        // 0.7 * 0.5 + 0.3 * 1 = 0.65; then 0.7 * 0.65 + 0 = 0.455.
        let p = update(0.5, true, 0.3);
        assert!((p - 0.65).abs() < 1e-6);
        assert!((update(p, false, 0.3) - 0.455).abs() < 1e-6);
        // Stereo alpha 0.5: 0.5 * 0.5 + 0.5 = 0.75.
        assert!((update(0.5, true, 0.5) - 0.75).abs() < 1e-6);
    }

    #[test]
    fn propagation_prefers_the_map_point_then_the_last_frame() {
        let (p, origin) = propagate(
            &[Some(0.9), None, None, Some(0.1)],
            &[Some(0.2), Some(0.8), None, None],
            0.5,
        );
        assert_eq!(p, vec![0.9, 0.8, 0.5, 0.1]);
        assert_eq!(
            origin,
            vec![
                Origin::MapPoint,
                Origin::LastFrame,
                Origin::Initial,
                Origin::MapPoint
            ]
        );
    }

    #[test]
    fn expansion_with_one_and_two_high_confidence_neighbours() {
        let config = DopConfig {
            gamma: 15.0,
            c: 5.0,
            ..DopConfig::default()
        };
        // Keypoint 0 (dynamic, 0.9) at the origin; keypoint 2 unknown 10 px away:
        // lambda(10) = 5 e^-2 = 0.67668; P = 0.5 + 0.67668 * 0.4 = 0.77067.
        let positions = [(0.0, 0.0), (100.0, 0.0), (10.0, 0.0), (40.0, 0.0)];
        let probabilities = [0.9, 0.3, 0.5, 0.5];
        let origins = [
            Origin::MapPoint,
            Origin::MapPoint,
            Origin::Initial,
            Origin::Initial,
        ];
        let p = expand(&config, &positions, &probabilities, &origins);
        assert!((p[2] - 0.770_67).abs() < 1e-4, "{}", p[2]);
        // Keypoint 3 is beyond gamma of everything: stays P_init; others unchanged.
        assert_eq!((p[0], p[1], p[3]), (0.9, 0.3, 0.5));
        // Two neighbours add up: a static one (0.1) 12 px away on the other side,
        // lambda(12) = 5 e^-2.4 = 0.45359; sum = 0.27067 - 0.18144 = 0.08924.
        let positions = [(0.0, 0.0), (22.0, 0.0), (10.0, 0.0)];
        let p = expand(
            &config,
            &positions,
            &[0.9, 0.1, 0.5],
            &[Origin::MapPoint, Origin::LastFrame, Origin::Initial],
        );
        assert!((p[2] - 0.589_24).abs() < 1e-4, "{}", p[2]);
    }

    #[test]
    fn expansion_clamps_and_ignores_low_confidence_neighbours() {
        let config = DopConfig::default();
        // Two dynamic neighbours 1 px away: 0.5 + 2 * 5 e^-0.2 * 0.45 > 1 -> 1.
        let p = expand(
            &config,
            &[(0.0, 0.0), (2.0, 0.0), (1.0, 0.0), (1.0, 1.0)],
            &[0.95, 0.95, 0.5, 0.6],
            &[
                Origin::MapPoint,
                Origin::MapPoint,
                Origin::Initial,
                Origin::LastFrame,
            ],
        );
        assert_eq!(p[2], 1.0);
        // 0.6 is low-confidence dynamic: it spreads nothing, and keeps its value.
        assert_eq!(p[3], 0.6);
        let lonely = expand(
            &config,
            &[(0.0, 0.0), (3.0, 0.0)],
            &[0.6, 0.5],
            &[Origin::MapPoint, Origin::Initial],
        );
        assert_eq!(lonely[1], 0.5);
    }

    #[test]
    fn states_and_removal() {
        let config = DopConfig::default();
        assert_eq!(config.state(0.1), State::StaticHigh);
        assert_eq!(config.state(0.3), State::StaticLow);
        assert_eq!(config.state(0.5), State::DynamicLow);
        assert_eq!(config.state(0.75), State::DynamicHigh);
        assert!(!config.removed(0.5), "P_init is kept");
        assert!(config.removed(0.51));
        assert!(DopConfig {
            thresholds: [0.5, 0.4, 0.9],
            ..DopConfig::default()
        }
        .validate()
        .is_err());
        let none_needed = DopConfig {
            standing_min_points: 0,
            ..DopConfig::default()
        };
        let error = none_needed.validate().unwrap_err().to_string();
        assert!(error.contains("dop.standing_min_points"), "{error}");
        let share = DopConfig {
            standing_share: 1.5,
            ..DopConfig::default()
        };
        let error = share.validate().unwrap_err().to_string();
        assert!(error.contains("standing_share"), "{error}");
        for gate in [0.5, f32::NAN] {
            let narrow = DopConfig {
                geometric_gate: gate,
                ..DopConfig::default()
            };
            let error = narrow.validate().unwrap_err().to_string();
            assert!(error.contains("dop.geometric_gate"), "{error}");
        }
    }
}
