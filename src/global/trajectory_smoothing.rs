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
use crate::eval::stats::MedianSample;
use crate::geometry::se3::Se3;
use crate::geometry::so3;
use crate::io::IoError;
use crate::map::record::{FrameRecord, FrameRecords};
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

/// How many records one solve reads into memory ([`smooth_records`]).
#[derive(Debug, Clone, Copy)]
struct Windows {
    /// A run spanning no more records is smoothed whole, as one system; a longer one
    /// in windows of this many, each overlapping its neighbours by `overlap` records
    /// on either side and keeping only its core (the prior's pull decays within a few
    /// keyframes, so the cores join as one solve would have them). Memory is then
    /// bounded whatever the run's length.
    len: usize,
    /// Records on either side of a window's core that are solved and not kept.
    overlap: usize,
}

/// The windows of a run: 32,768 records (18 minutes at 30 Hz) solved at once.
const WINDOWS: Windows = Windows {
    len: 1 << 15,
    overlap: 1024,
};

/// A record with a pose on its reference keyframe, as the smoother reads it.
#[derive(Debug, Clone, Copy)]
struct Posed {
    timestamp: f64,
    segment: usize,
    world_from_camera: Se3,
}

impl Posed {
    /// `record` placed on its reference keyframe's pose in `map` (`None` without one),
    /// and that pose, \(T_{rw}\).
    fn of(map: &Map, record: &FrameRecord) -> Option<(Self, Se3)> {
        let (key, camera_from_reference) = record.reference?;
        let reference_from_world = map.keyframe_pose(key)?;
        let pose = camera_from_reference * reference_from_world;
        let posed = Self {
            timestamp: record.timestamp,
            segment: record.segment,
            world_from_camera: pose.inverse(),
        };
        Some((posed, reference_from_world))
    }
}

/// A run of consecutive posed frames: the records it spans (`first..=last`) and how
/// many of them are posed.
#[derive(Debug, Clone, Copy)]
struct RunSpan {
    first: usize,
    last: usize,
    frames: usize,
}

/// Smooths the poses of the tracked frames of `records` in place, reading them from
/// disk: once for the frame interval, once for the runs and the noise, and then run by
/// run ([`WINDOWS`]: 32,768 records at most at a time).
pub fn smooth_records(
    map: &Map,
    config: &SmoothingConfig,
    records: &mut FrameRecords,
) -> Result<SmoothingReport, IoError> {
    smooth_in_windows(map, config, records, WINDOWS)
}

fn smooth_in_windows(
    map: &Map,
    config: &SmoothingConfig,
    records: &mut FrameRecords,
    windows: Windows,
) -> Result<SmoothingReport, IoError> {
    let start = Instant::now();
    let typical = typical_interval(map, records)?;
    let (runs, centre_noise, rotation_noise) = runs_and_noise(map, records, typical)?;
    let mut report = SmoothingReport {
        runs: runs.len(),
        centre_noise_mm: centre_noise * 1e3,
        rotation_noise_deg: rotation_noise.to_degrees(),
        ..SmoothingReport::default()
    };
    let noise = Noise {
        centre: centre_noise,
        rotation: rotation_noise,
    };
    let mut shifts = MedianSample::default();
    for run in runs {
        let (end, overlap) = (run.last + 1, windows.overlap);
        let step = match end - run.first <= windows.len {
            true => end - run.first,
            false => windows.len - 2 * overlap,
        };
        // A window's smoothed core is written once the next window has read its
        // measurements, the overlap among them.
        let mut smoothed: Option<(usize, Vec<FrameRecord>)> = None;
        let mut core = run.first;
        while core < end {
            let core_end = (core + step).min(end);
            let from = core.saturating_sub(overlap).max(run.first);
            let to = (core_end + overlap).min(end);
            let mut frames = records.read_chunk(from, to - from)?;
            if let Some((at, done)) = smoothed.take() {
                records.write_chunk(at, done)?;
            }
            let kept = core - from..core_end - from;
            smooth_window(
                map,
                config,
                noise,
                &mut frames,
                kept.clone(),
                &mut report,
                &mut shifts,
            );
            smoothed = Some((core, frames.drain(kept).collect()));
            core = core_end;
        }
        if let Some((at, done)) = smoothed {
            records.write_chunk(at, done)?;
        }
    }
    report.median_shift_mm = shifts.median();
    report.milliseconds = start.elapsed().as_secs_f64() * 1e3;
    Ok(report)
}

/// The median interval between consecutive posed frames (positive ones only).
fn typical_interval(map: &Map, records: &FrameRecords) -> Result<f64, IoError> {
    let mut intervals = MedianSample::default();
    let mut previous: Option<f64> = None;
    for record in records.iter() {
        let Some((posed, _)) = Posed::of(map, &record?) else {
            continue;
        };
        if let Some(dt) = previous.map(|t| posed.timestamp - t).filter(|&dt| dt > 0.0) {
            intervals.push(dt);
        }
        previous = Some(posed.timestamp);
    }
    Ok(intervals.median())
}

/// The runs of at least 3 consecutive posed frames (a run breaks at a new map
/// segment or a gap over [`MAX_GAP`] `typical` intervals), and \(\sigma_m\) of the
/// centres and of the rotations: white noise of \(\sigma\) gives second differences
/// of deviation \(\sqrt 6 \sigma\), so \(\sigma_m\) is the median absolute
/// deviation of the second differences at the runs' inner frames (per axis, scaled to
/// a standard deviation) over \(\sqrt 6\).
fn runs_and_noise(
    map: &Map,
    records: &FrameRecords,
    typical: f64,
) -> Result<(Vec<RunSpan>, f64, f64), IoError> {
    let (mut runs, mut centres, mut rotations) =
        (Vec::new(), MedianSample::default(), MedianSample::default());
    let mut run: Option<RunSpan> = None;
    // The run's last two posed frames.
    let mut last: [Option<Posed>; 2] = [None, None];
    for (index, record) in records.iter().enumerate() {
        let Some((b, _)) = Posed::of(map, &record?) else {
            continue;
        };
        let breaks = last[1].is_none_or(|a| {
            let dt = b.timestamp - a.timestamp;
            a.segment != b.segment || !(dt > 0.0 && dt <= MAX_GAP * typical)
        });
        if breaks {
            runs.extend(run.take().filter(|r| r.frames >= 3));
            last = [None, None];
        }
        let span = run.get_or_insert(RunSpan {
            first: index,
            last: index,
            frames: 0,
        });
        (span.last, span.frames) = (index, span.frames + 1);
        if let [Some(a), Some(k)] = last {
            let (ca, ck, cb) = [a, k, b]
                .map(|p| p.world_from_camera.translation.vector)
                .into();
            (ca - 2.0 * ck + cb)
                .iter()
                .for_each(|v| centres.push(v.abs()));
            let [ra, rk, rb] = [a, k, b].map(|p| p.world_from_camera.rotation);
            let second = so3::log(&(rb * rk.inverse())) - so3::log(&(rk * ra.inverse()));
            second.iter().for_each(|v| rotations.push(v.abs()));
        }
        last = [last[1], Some(b)];
    }
    runs.extend(run.filter(|r| r.frames >= 3));
    Ok((runs, white_noise(centres), white_noise(rotations)))
}

/// \(\sigma\) of white noise from the absolute values of its second differences
/// (their median absolute deviation, scaled to a standard deviation, over \(\sqrt 6\)).
fn white_noise(second_differences: MedianSample) -> f64 {
    1.4826 * second_differences.median() / 6f64.sqrt()
}

/// The measurement noise of centres (metres) and rotations (radians).
#[derive(Debug, Clone, Copy)]
struct Noise {
    centre: f64,
    rotation: f64,
}

/// Smooths the posed frames of `frames` (records of one run) as one system, and keeps
/// the new poses of those in `kept` (the window's core).
fn smooth_window(
    map: &Map,
    config: &SmoothingConfig,
    noise: Noise,
    frames: &mut [FrameRecord],
    kept: std::ops::Range<usize>,
    report: &mut SmoothingReport,
    shifts: &mut MedianSample,
) {
    // Frames with a pose, where they are, their world_from_camera and their
    // reference's reference_from_world.
    let posed: Vec<(usize, Se3, Se3)> = frames
        .iter()
        .enumerate()
        .filter_map(|(i, f)| Posed::of(map, f).map(|(p, rw)| (i, p.world_from_camera, rw)))
        .collect();
    if posed.len() < 3 {
        return;
    }
    let times: Vec<f64> = posed.iter().map(|p| frames[p.0].timestamp).collect();
    let anchors: Vec<bool> = posed.iter().map(|p| frames[p.0].is_keyframe()).collect();
    let centres: Vec<Vector3<f64>> = posed.iter().map(|p| p.1.translation.vector).collect();
    let rotations: Vec<Rotation3<f64>> = posed.iter().map(|p| p.1.rotation).collect();
    // Measured rotation increments, world frame.
    let increments: Vec<Vector3<f64>> = rotations
        .windows(2)
        .map(|w| so3::log(&(w[1] * w[0].inverse())))
        .collect();
    let new_centres = smooth_axes(
        &times,
        &anchors,
        noise.centre,
        config.acceleration,
        |i| centres[i],
        |_| Vector3::zeros(),
    );
    let corrections = smooth_axes(
        &times,
        &anchors,
        noise.rotation,
        config.angular_acceleration,
        |_| Vector3::zeros(),
        |k| increments[k],
    );
    for (i, (centre, delta)) in new_centres.iter().zip(&corrections).enumerate() {
        let (at, before, reference_from_world) = posed[i];
        let frame = &mut frames[at];
        let Some((key, _)) = frame.reference.filter(|_| !frame.is_keyframe()) else {
            continue;
        };
        if !kept.contains(&at) {
            continue;
        }
        let rotation = so3::exp(delta) * rotations[i];
        let world_from_camera = Se3::from_parts(Translation3::from(*centre), rotation);
        let camera_from_world = world_from_camera.inverse();
        frame.reference = Some((key, camera_from_world * reference_from_world.inverse()));
        frame.camera_from_world = Some(camera_from_world);
        let shift = (centre - before.translation.vector).norm() * 1e3;
        report.max_shift_mm = report.max_shift_mm.max(shift);
        shifts.push(shift);
        report.frames += 1;
    }
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

    /// A map with a keyframe every 15th of `n` frames on a smooth path at 30 Hz, and
    /// the frames' records: each on the keyframe before it, its pose off by jitter
    /// (3 mm, 0.2 degrees).
    fn jittered_records(n: usize, seed: u64) -> (Map, FrameRecords) {
        use crate::frame::Frame;
        use crate::map::KeyFrame;
        let mut rng = Rng::new(seed);
        let truth = |i: usize| {
            let t = i as f64 / 30.0;
            let centre = Vector3::new(2.0 * (0.1 * t).sin(), 0.3 * (0.07 * t).cos(), 0.02 * t);
            let rotation = Rotation3::from_scaled_axis(Vector3::new(0.1 * t.sin(), 0.05 * t, 0.0));
            Se3::from_parts(Translation3::from(centre), rotation).inverse()
        };
        let mut map = Map::default();
        let mut records = FrameRecords::default();
        let mut reference = None;
        for i in 0..n {
            let mut record = FrameRecord::start(i as f64 / 30.0, 0);
            let camera_from_world = if i % 15 == 0 {
                let key = map.add_keyframe(KeyFrame::new(Frame::blank(1, (640, 480)), truth(i)));
                reference = Some((key, truth(i)));
                record.keyframe = Some(key);
                truth(i)
            } else {
                let jitter = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                let turn = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0035;
                Se3::from_parts(
                    Translation3::from(jitter * 0.003),
                    Rotation3::from_scaled_axis(turn),
                ) * truth(i)
            };
            let (key, reference_from_world) = reference.expect("a keyframe first");
            record.reference = Some((key, camera_from_world * reference_from_world.inverse()));
            record.camera_from_world = Some(camera_from_world);
            records.push(record).unwrap();
        }
        (map, records)
    }

    #[test]
    fn a_long_run_smoothed_in_windows_joins_as_one_solve_would() {
        let config = SmoothingConfig::default();
        let (map, mut whole) = jittered_records(3000, 5);
        let (_, mut windowed) = jittered_records(3000, 5);
        let one = Windows {
            len: 4096,
            overlap: 0,
        };
        let small = Windows {
            len: 700,
            overlap: 150,
        };
        let a = smooth_in_windows(&map, &config, &mut whole, one).unwrap();
        let b = smooth_in_windows(&map, &config, &mut windowed, small).unwrap();
        assert_eq!((a.runs, a.frames), (1, 3000 - 200));
        assert_eq!((b.runs, b.frames), (a.runs, a.frames));
        assert_eq!(a.centre_noise_mm, b.centre_noise_mm);
        assert!(a.median_shift_mm > 0.5, "{a:?}");
        let poses = |records: &FrameRecords| -> Vec<Se3> {
            records
                .iter()
                .map(|r| r.unwrap().camera_from_world.unwrap())
                .collect()
        };
        let largest = poses(&whole)
            .iter()
            .zip(&poses(&windowed))
            .map(|(p, q)| (p.inverse().translation.vector - q.inverse().translation.vector).norm())
            .fold(0.0, f64::max);
        // Equal to the bit here (3 mm apart with no overlap).
        assert!(
            largest < 1e-9,
            "windows and one solve differ by {largest} m"
        );
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
        let mut second = MedianSample::default();
        for k in 1..times.len() - 1 {
            let d = measured[k - 1] - 2.0 * measured[k] + measured[k + 1];
            d.iter().for_each(|v| second.push(v.abs()));
        }
        let sigma = white_noise(second);
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
