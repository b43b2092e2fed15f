//! Oracle detections with a real detector's habits: boxes a little larger than the
//! object, corners that jitter, missed objects, false positives and confidence scores.
//! With [`OracleConfig::exact`] the boxes are the masks' exact bounding boxes.

use serde::{Deserialize, Serialize};

use crate::checks::{self, BadValue};
use crate::detect::Detection;
use crate::random::Rng;

/// The oracle section of a synth config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OracleConfig {
    /// Each side moves out by this fraction of the box's width or height.
    pub margin: f64,
    /// Standard deviation of each corner coordinate's jitter, in pixels.
    pub jitter_px: f64,
    /// Probability that a visible object is not detected in a frame.
    pub miss_rate: f64,
    /// Probability of one false "person" box in a frame.
    pub false_positive_rate: f64,
    /// Scores of true detections are uniform in [score_min, score_max].
    pub score_min: f64,
    /// The highest score.
    pub score_max: f64,
}

impl Default for OracleConfig {
    fn default() -> Self {
        Self {
            margin: 0.05,
            jitter_px: 2.0,
            miss_rate: 0.0,
            false_positive_rate: 0.0,
            score_min: 0.7,
            score_max: 0.99,
        }
    }
}

impl OracleConfig {
    /// Exact boxes, every object found, score 1.
    pub fn exact() -> Self {
        Self {
            margin: 0.0,
            jitter_px: 0.0,
            miss_rate: 0.0,
            false_positive_rate: 0.0,
            score_min: 1.0,
            score_max: 1.0,
        }
    }

    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::unit_interval("oracle.miss_rate", self.miss_rate)?;
        checks::unit_interval("oracle.false_positive_rate", self.false_positive_rate)?;
        if !(0.0..=1.0).contains(&self.score_min)
            || !(self.score_min..=1.0).contains(&self.score_max)
        {
            return Err(BadValue::new(
                "oracle.score_min",
                format!(
                    "and score_max need 0 <= score_min <= score_max <= 1, got {} and {}",
                    self.score_min, self.score_max
                ),
            ));
        }
        checks::non_negative("oracle.margin", self.margin)?;
        checks::non_negative("oracle.jitter_px", self.jitter_px)
    }

    /// Turns exact boxes into detector-like ones, clamped to a `width` x `height` image.
    pub fn apply(
        &self,
        exact: &[Detection],
        width: u32,
        height: u32,
        rng: &mut Rng,
    ) -> Vec<Detection> {
        let (w, h) = (width as f64, height as f64);
        let clamp = |b: [f64; 4]| {
            [
                b[0].clamp(0.0, w),
                b[1].clamp(0.0, h),
                b[2].clamp(0.0, w),
                b[3].clamp(0.0, h),
            ]
            .map(|v| v as f32)
        };
        let mut out = Vec::new();
        for detection in exact {
            let (miss, score) = (rng.uniform(), rng.range(self.score_min, self.score_max));
            let jitter: [f64; 4] = std::array::from_fn(|_| self.jitter_px * rng.normal());
            if miss < self.miss_rate {
                continue;
            }
            let [x1, y1, x2, y2] = detection.bbox.map(f64::from);
            let (mx, my) = (self.margin * (x2 - x1), self.margin * (y2 - y1));
            let bbox = clamp([
                x1 - mx + jitter[0],
                y1 - my + jitter[1],
                x2 + mx + jitter[2],
                y2 + my + jitter[3],
            ]);
            out.push(Detection {
                score: score as f32,
                bbox,
                ..detection.clone()
            });
        }
        if rng.uniform() < self.false_positive_rate {
            let (cx, cy, bw, bh) = (
                rng.range(0.0, w),
                rng.range(0.0, h),
                rng.range(30.0, 150.0),
                rng.range(60.0, 300.0),
            );
            out.push(Detection {
                class: "person".into(),
                class_id: 0,
                score: rng.range(self.score_min.min(0.5), 0.6) as f32,
                bbox: clamp([cx - bw / 2.0, cy - bh / 2.0, cx + bw / 2.0, cy + bh / 2.0]),
                instance: None,
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn person(bbox: [f32; 4]) -> Detection {
        Detection {
            class: "person".into(),
            class_id: 0,
            score: 1.0,
            bbox,
            instance: Some(1),
        }
    }

    #[test]
    fn exact_keeps_boxes_and_margin_inflates() {
        let boxes = [person([100.0, 50.0, 200.0, 250.0])];
        let mut rng = Rng::new(1);
        assert_eq!(
            OracleConfig::exact().apply(&boxes, 640, 480, &mut rng),
            boxes.to_vec()
        );
        let inflated = OracleConfig {
            margin: 0.1,
            jitter_px: 0.0,
            ..OracleConfig::exact()
        }
        .apply(&boxes, 640, 480, &mut rng);
        assert_eq!(inflated[0].bbox, [90.0, 30.0, 210.0, 270.0]);
    }

    #[test]
    fn misses_and_false_positives_follow_their_rates() {
        let boxes = [person([10.0, 10.0, 50.0, 90.0])];
        let config = OracleConfig {
            miss_rate: 0.3,
            false_positive_rate: 0.2,
            ..OracleConfig::default()
        };
        let mut rng = Rng::new(5);
        let (mut found, mut false_positives) = (0, 0);
        for _ in 0..2000 {
            for d in config.apply(&boxes, 640, 480, &mut rng) {
                if d.instance.is_some() {
                    found += 1
                } else {
                    false_positives += 1
                }
            }
        }
        assert!((1300..1500).contains(&found), "{found}");
        assert!((320..480).contains(&false_positives), "{false_positives}");
    }
}
