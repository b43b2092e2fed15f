//! Every frame's pose smoothed with a motion prior, after the frame refinement
//! (beyond ORB-SLAM2, whose frames are independent estimates).
//!
//! Each frame is estimated from the map points it saw alone, so its error is nearly
//! independent of its neighbours': one-frame jitter, which lengthens the path and the
//! one-frame relative error although the camera moves smoothly at 30 Hz. A
//! fixed-interval smoother takes the frames' poses as measurements and the camera's
//! acceleration as the process noise. For each run of consecutive frames (same map
//! segment, no gap over [`MAX_GAP`] frame intervals), with camera centres \(c_i\) and
//! measured centres \(m_i\),
//! \[ \min_c \sum_i w_i \rho_m\big(\lVert c_i - m_i \rVert^2\big) +
//!    \sum_k \rho\Big(\frac{\lVert a_k(c) \rVert^2}{\sigma_a^2}\Big), \qquad
//!    a_k = \frac{2}{\Delta_1 + \Delta_2}\Big(\frac{c_{k+1} - c_k}{\Delta_2} -
//!    \frac{c_k - c_{k-1}}{\Delta_1}\Big) \]
//! (\(a_k\): the acceleration at frame \(k\), \(\Delta\) the frame intervals,
//! \(\rho\) and \(\rho_m\) Huber, solved by reweighted least squares: a frame whose
//! pose jumped weighs little against its neighbours). Rotations likewise: with
//! \(R_i \leftarrow \exp(\delta_i) R_i\) and measured increments
//! \(\phi_k = \log(R_{k+1} R_k^\top)\), the angular increment is
//! \(\phi_k + \delta_{k+1} - \delta_k\) to first order, and its second difference
//! over \(\sigma_\alpha\) is the prior. The axes separate, so each is a pentadiagonal
//! system, solved by a banded Cholesky factorisation in \(O(n)\).
//!
//! The measurement weight is \(w_i = 1/\sigma_m^2\), with \(\sigma_m\) estimated from
//! the run itself: white noise of \(\sigma\) gives second differences of deviation
//! \(\sqrt 6 \sigma\), so \(\sigma_m\) is the median absolute deviation of the
//! measured second differences over \(\sqrt 6\) (a run with little jitter is smoothed
//! little). Keyframes keep their bundle-adjusted poses (weight \(10^6 w\)), so the map
//! and the keyframes stay as full BA left them.

use std::time::Instant;

use nalgebra::{Rotation3, Translation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::checks::{self, positive, BadValue};
use crate::eval::stats::median;
use crate::geometry::se3::Se3;
use crate::geometry::so3;
use crate::map::record::FrameRecord;
use crate::map::Map;
use crate::optim::robust::huber_weight;

/// A longer gap between frames (in median frame intervals) starts a new run.
pub const MAX_GAP: f64 = 2.5;
/// Huber threshold on the acceleration residual, in \(\sigma\).
const HUBER: f64 = 2.5;
/// Huber threshold on a frame's distance from its measurement, in \(\sigma_m\): a
/// frame whose pose jumped (a few bad matches) weighs little against its neighbours.
const HUBER_MEASUREMENT: f64 = 3.0;
/// Reweighting rounds.
const ROUNDS: usize = 6;
/// Keyframes' weight relative to frames'.
const KEYFRAME_WEIGHT: f64 = 1e6;

/// `[global.smoothing]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SmoothingConfig {
    /// Smooth the frames' poses after the global pass.
    pub enabled: bool,
    /// \(\sigma_a\): the camera's acceleration per axis, m/s². The real ground truths
    /// of TUM fr1_xyz, fr2_desk and a Bonn clip, at 30 Hz, have 0.09-0.46 m/s² (RMS
    /// per axis; 95th percentile of the magnitude 0.35-1.6).
    pub acceleration: f64,
    /// \(\sigma_\alpha\): its angular acceleration per axis, rad/s² (the same
    /// ground truths: 0.5-1.7 RMS, 95th percentile 1.7-3.3).
    pub angular_acceleration: f64,
}

impl Default for SmoothingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            acceleration: 1.0,
            angular_acceleration: 3.0,
        }
    }
}

impl SmoothingConfig {
    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::each(
            "global.smoothing",
            positive,
            &[
                ("acceleration", self.acceleration),
                ("angular_acceleration", self.angular_acceleration),
            ],
        )
    }
}

/// What the smoothing did (in `report.json`, under `global`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct SmoothingReport {
    /// Frames smoothed.
    pub frames: usize,
    /// Runs of consecutive tracked frames smoothed apart.
    pub runs: usize,
    /// The estimated measurement noise: centre (mm) and rotation (degrees).
    pub centre_noise_mm: f64,
    /// The rotation noise, degrees.
    pub rotation_noise_deg: f64,
    /// How far the frames' centres moved, millimetres.
    pub median_shift_mm: f64,
    /// The largest shift, millimetres.
    pub max_shift_mm: f64,
    /// The smoothing's time.
    pub milliseconds: f64,
}

/// Smooths the poses of the tracked `frames` (in sequence order) in place.
pub fn smooth_frames(
    map: &Map,
    config: &SmoothingConfig,
    frames: &mut [FrameRecord],
) -> SmoothingReport {
    let start = Instant::now();
    // Frames with a pose, their world_from_camera and their reference's
    // reference_from_world.
    let mut frames: Vec<(&mut FrameRecord, Se3, Se3)> = frames
        .iter_mut()
        .filter_map(|f| {
            let (key, camera_from_reference) = f.reference?;
            let reference_from_world = map.keyframe_pose(key)?;
            let pose = camera_from_reference * reference_from_world;
            Some((f, pose.inverse(), reference_from_world))
        })
        .collect();
    let runs = runs_of(&frames);
    let times: Vec<f64> = frames.iter().map(|f| f.0.timestamp).collect();
    let anchors: Vec<bool> = frames.iter().map(|f| f.0.is_keyframe()).collect();
    let centres: Vec<Vector3<f64>> = frames.iter().map(|f| f.1.translation.vector).collect();
    let rotations: Vec<Rotation3<f64>> = frames.iter().map(|f| f.1.rotation).collect();
    // Measured rotation increments, world frame.
    let increments: Vec<Vector3<f64>> = rotations
        .windows(2)
        .map(|w| so3::log(&(w[1] * w[0].inverse())))
        .collect();
    let centre_noise = noise(&runs, |k| {
        centres[k - 1] - 2.0 * centres[k] + centres[k + 1]
    });
    let rotation_noise = noise(&runs, |k| increments[k] - increments[k - 1]);
    let mut report = SmoothingReport {
        runs: runs.len(),
        centre_noise_mm: centre_noise * 1e3,
        rotation_noise_deg: rotation_noise.to_degrees(),
        ..SmoothingReport::default()
    };
    let mut shifts = Vec::new();
    for run in runs {
        let t = &times[run.clone()];
        let fixed = &anchors[run.clone()];
        let new_centres = smooth_axes(
            t,
            fixed,
            centre_noise,
            config.acceleration,
            |i| centres[run.start + i],
            |_| Vector3::zeros(),
        );
        let corrections = smooth_axes(
            t,
            fixed,
            rotation_noise,
            config.angular_acceleration,
            |_| Vector3::zeros(),
            |k| increments[run.start + k],
        );
        for (i, (centre, delta)) in new_centres.iter().zip(&corrections).enumerate() {
            let (frame, before, reference_from_world) = &mut frames[run.start + i];
            let Some((key, _)) = frame.reference.filter(|_| !frame.is_keyframe()) else {
                continue;
            };
            let rotation = so3::exp(delta) * rotations[run.start + i];
            let world_from_camera = Se3::from_parts(Translation3::from(*centre), rotation);
            let camera_from_world = world_from_camera.inverse();
            frame.reference = Some((key, camera_from_world * reference_from_world.inverse()));
            frame.camera_from_world = Some(camera_from_world);
            shifts.push((centre - before.translation.vector).norm() * 1e3);
            report.frames += 1;
        }
    }
    report.max_shift_mm = shifts.iter().copied().fold(0.0, f64::max);
    report.median_shift_mm = median(&mut shifts);
    report.milliseconds = start.elapsed().as_secs_f64() * 1e3;
    report
}

/// The runs of consecutive frames, as `[start, end)` ranges of at least 3 frames: a run
/// breaks at a new map segment or a gap over [`MAX_GAP`] typical intervals.
fn runs_of(frames: &[(&mut FrameRecord, Se3, Se3)]) -> Vec<std::ops::Range<usize>> {
    let mut intervals: Vec<f64> = frames
        .windows(2)
        .map(|w| w[1].0.timestamp - w[0].0.timestamp)
        .filter(|&dt| dt > 0.0)
        .collect();
    let typical = median(&mut intervals);
    let mut runs = Vec::new();
    let mut first = 0;
    for i in 1..=frames.len() {
        let breaks = i == frames.len() || {
            let (a, b) = (&frames[i - 1].0, &frames[i].0);
            let dt = b.timestamp - a.timestamp;
            a.segment != b.segment || !(dt > 0.0 && dt <= MAX_GAP * typical)
        };
        if breaks {
            if i - first >= 3 {
                runs.push(first..i);
            }
            first = i;
        }
    }
    runs
}

/// \(\sigma_m\) of white noise from the second differences `second(k)` at the inner
/// frames of the runs (median absolute deviation, scaled to a standard deviation per
/// axis, over \(\sqrt 6\)).
fn noise(runs: &[std::ops::Range<usize>], second: impl Fn(usize) -> Vector3<f64>) -> f64 {
    let mut deviations: Vec<f64> = runs
        .iter()
        .flat_map(|r| r.start + 1..r.end - 1)
        .flat_map(|k| <[f64; 3]>::from(second(k)))
        .map(f64::abs)
        .collect();
    1.4826 * median(&mut deviations) / 6f64.sqrt()
}

/// The three axes of one run smoothed: minimises
/// \(\sum_i w_i \rho_m(\lVert x_i - m_i \rVert^2) + \sum_k \rho(\lVert D_k x + b_k \rVert^2/\sigma^2)\)
/// with \(D_k x\) the acceleration of \(x\) at inner frame \(k\) and \(b_k\) that of
/// the `offset` increments (`offset(k)`: between frames k and k+1, a second
/// difference of increments).
fn smooth_axes(
    times: &[f64],
    anchors: &[bool],
    noise: f64,
    sigma: f64,
    measured: impl Fn(usize) -> Vector3<f64>,
    offset: impl Fn(usize) -> Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let n = times.len();
    let m: Vec<Vector3<f64>> = (0..n).map(&measured).collect();
    if noise <= 0.0 {
        return m;
    }
    let w: Vec<f64> = anchors
        .iter()
        .map(|&a| if a { KEYFRAME_WEIGHT } else { 1.0 } / (noise * noise))
        .collect();
    // Inner frame k: coefficients of x_{k-1}, x_k, x_{k+1} and the offset's part.
    let rows: Vec<([f64; 3], Vector3<f64>)> = (1..n - 1)
        .map(|k| {
            let (d1, d2) = (times[k] - times[k - 1], times[k + 1] - times[k]);
            let s = 2.0 / (d1 + d2);
            let coefficients = [s / d1, -s / d1 - s / d2, s / d2];
            // Offsets are increments: (x_{k+1} - x_k) gains offset(k), (x_k - x_{k-1})
            // gains offset(k-1).
            let b = offset(k) * (s / d2) - offset(k - 1) * (s / d1);
            (coefficients, b)
        })
        .collect();
    let mut x = m.clone();
    let mut robust = vec![1.0; rows.len()];
    let mut trusted = vec![1.0; n];
    for round in 0..ROUNDS {
        if round > 0 {
            // Huber weights from the current accelerations and distances from the
            // measurements (keyframes stay anchored).
            for (r, ((c, b), weight)) in rows.iter().zip(robust.iter_mut()).enumerate() {
                let a = x[r] * c[0] + x[r + 1] * c[1] + x[r + 2] * c[2] + b;
                *weight = huber_weight(a.norm_squared() / (sigma * sigma), HUBER);
            }
            for (i, weight) in trusted.iter_mut().enumerate() {
                if !anchors[i] {
                    *weight = huber_weight(
                        (x[i] - m[i]).norm_squared() / (noise * noise),
                        HUBER_MEASUREMENT,
                    );
                }
            }
        }
        let mut band = Band::new(n);
        let mut rhs: Vec<Vector3<f64>> = (0..n).map(|i| m[i] * (w[i] * trusted[i])).collect();
        for (i, (&weight, &trust)) in w.iter().zip(&trusted).enumerate() {
            band.add(i, i, weight * trust);
        }
        for (r, ((c, b), weight)) in rows.iter().zip(&robust).enumerate() {
            let scale = weight / (sigma * sigma);
            for p in 0..3 {
                rhs[r + p] -= b * (scale * c[p]);
                for q in p..3 {
                    band.add(r + p, r + q, scale * c[p] * c[q]);
                }
            }
        }
        x = band.solve(rhs);
    }
    x
}

/// A symmetric positive definite matrix of half-bandwidth 2 (pentadiagonal): entry
/// \((i, i + d)\) at `rows[i][d]`.
struct Band {
    rows: Vec<[f64; 3]>,
}

impl Band {
    fn new(n: usize) -> Self {
        Self {
            rows: vec![[0.0; 3]; n],
        }
    }

    fn add(&mut self, i: usize, j: usize, value: f64) {
        self.rows[i][j - i] += value;
    }

    /// Solves \(A x = b\) for three right-hand sides at once by the banded Cholesky
    /// factorisation \(A = L L^\top\).
    fn solve(mut self, mut b: Vec<Vector3<f64>>) -> Vec<Vector3<f64>> {
        let n = self.rows.len();
        // In place: rows[i][0] = L_ii, rows[i][d] = L_{i+d,i}.
        for i in 0..n {
            let mut diagonal = self.rows[i][0];
            for d in 1..=2.min(i) {
                diagonal -= self.rows[i - d][d].powi(2);
            }
            let l = diagonal.max(1e-300).sqrt();
            self.rows[i][0] = l;
            for d in 1..=2 {
                if i + d >= n {
                    break;
                }
                // A_{i+d,i} - sum_k L_{i+d,k} L_{i,k}, k = i+d-2 .. i-1.
                let mut value = self.rows[i][d];
                if d == 1 && i >= 1 {
                    value -= self.rows[i - 1][2] * self.rows[i - 1][1];
                }
                self.rows[i][d] = value / l;
            }
        }
        // Forward: L y = b.
        for i in 0..n {
            for d in 1..=2.min(i) {
                let l = self.rows[i - d][d];
                let prior = b[i - d];
                b[i] -= prior * l;
            }
            b[i] /= self.rows[i][0];
        }
        // Back: Lᵀ x = y.
        for i in (0..n).rev() {
            for d in 1..=2 {
                if i + d < n {
                    let l = self.rows[i][d];
                    let later = b[i + d];
                    b[i] -= later * l;
                }
            }
            b[i] /= self.rows[i][0];
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    #[test]
    fn the_band_solver_agrees_with_a_dense_solve() {
        let n = 9;
        let mut rng = Rng::new(3);
        let mut band = Band::new(n);
        let mut dense = nalgebra::DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            for d in 0..3 {
                if i + d < n {
                    let v = if d == 0 {
                        4.0 + rng.uniform()
                    } else {
                        rng.uniform() - 0.5
                    };
                    band.add(i, i + d, v);
                    dense[(i, i + d)] += v;
                    if d > 0 {
                        dense[(i + d, i)] += v;
                    }
                }
            }
        }
        let b: Vec<Vector3<f64>> = (0..n)
            .map(|_| Vector3::new(rng.normal(), rng.normal(), rng.normal()))
            .collect();
        let x = band.solve(b.clone());
        for axis in 0..3 {
            let rhs = nalgebra::DVector::from_iterator(n, b.iter().map(|v| v[axis]));
            let expected = dense.clone().lu().solve(&rhs).unwrap();
            for i in 0..n {
                assert!((x[i][axis] - expected[i]).abs() < 1e-10, "{i} {axis}");
            }
        }
    }

    /// A smooth path measured with 3 mm white noise at 30 Hz.
    fn noisy_path(seed: u64) -> (Vec<f64>, Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut rng = Rng::new(seed);
        let times: Vec<f64> = (0..300).map(|i| i as f64 / 30.0).collect();
        let truth: Vec<Vector3<f64>> = times
            .iter()
            .map(|t| Vector3::new(0.2 * (1.5 * t).sin(), 0.1 * (0.9 * t).cos(), 0.05 * t))
            .collect();
        let measured = truth
            .iter()
            .map(|p| p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.003)
            .collect();
        (times, truth, measured)
    }

    fn rmse(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        (a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).norm_squared())
            .sum::<f64>()
            / a.len() as f64)
            .sqrt()
    }

    #[test]
    fn smoothing_a_noisy_smooth_path_brings_it_closer_to_the_truth_and_keeps_anchors() {
        let (times, truth, measured) = noisy_path(5);
        let runs = [std::ops::Range {
            start: 0,
            end: times.len(),
        }];
        let sigma = noise(&runs, |k| {
            measured[k - 1] - 2.0 * measured[k] + measured[k + 1]
        });
        assert!((sigma - 0.003).abs() < 0.0006, "estimated noise {sigma}");
        let anchors: Vec<bool> = (0..times.len()).map(|i| i % 20 == 0).collect();
        let smoothed = smooth_axes(
            &times,
            &anchors,
            sigma,
            2.0,
            |i| measured[i],
            |_| Vector3::zeros(),
        );
        let (before, after) = (rmse(&measured, &truth), rmse(&smoothed, &truth));
        assert!(after < 0.7 * before, "{before} -> {after}");
        for (i, _) in anchors.iter().enumerate().filter(|(_, &a)| a) {
            assert!(
                (smoothed[i] - measured[i]).norm() < 1e-6,
                "anchor {i} moved"
            );
        }
    }

    /// One frame whose pose jumped 10 cm (a few bad matches) is pulled back to its
    /// neighbours' path, and does not drag them along.
    #[test]
    fn a_single_frame_jump_is_pulled_back_to_the_path() {
        let (times, truth, mut measured) = noisy_path(7);
        measured[150] += Vector3::new(0.1, 0.0, 0.0);
        let anchors = vec![false; times.len()];
        let smoothed = smooth_axes(
            &times,
            &anchors,
            0.003,
            1.0,
            |i| measured[i],
            |_| Vector3::zeros(),
        );
        let jumped = (smoothed[150] - truth[150]).norm();
        assert!(jumped < 0.01, "the jumped frame is {jumped} m off");
        for i in [148, 149, 151, 152] {
            let error = (smoothed[i] - truth[i]).norm();
            assert!(error < 0.005, "frame {i} is {error} m off");
        }
    }

    #[test]
    fn rotation_increments_are_smoothed_as_their_second_differences() {
        // A steady turn about z, its increments measured with noise: the corrections
        // make the corrected increments steadier.
        let mut rng = Rng::new(9);
        let n = 200;
        let times: Vec<f64> = (0..n).map(|i| i as f64 / 30.0).collect();
        let noise_angle = 0.002;
        let rotations: Vec<Rotation3<f64>> = (0..n)
            .map(|i| {
                let wobble = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise_angle;
                so3::exp(&wobble) * so3::exp(&Vector3::new(0.0, 0.0, 0.02 * i as f64))
            })
            .collect();
        let increments: Vec<Vector3<f64>> = rotations
            .windows(2)
            .map(|w| so3::log(&(w[1] * w[0].inverse())))
            .collect();
        let anchors = vec![false; n];
        let deltas = smooth_axes(
            &times,
            &anchors,
            noise_angle,
            5.0,
            |_| Vector3::zeros(),
            |k| increments[k],
        );
        let error = |r: &Rotation3<f64>, i: usize| {
            so3::log(&(r * so3::exp(&Vector3::new(0.0, 0.0, 0.02 * i as f64)).inverse())).norm()
        };
        let before: f64 = (0..n).map(|i| error(&rotations[i], i)).sum::<f64>() / n as f64;
        let after: f64 = (0..n)
            .map(|i| error(&(so3::exp(&deltas[i]) * rotations[i]), i))
            .sum::<f64>()
            / n as f64;
        assert!(after < 0.8 * before, "{before} -> {after}");
    }
}
