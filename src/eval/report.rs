//! One evaluation of an estimated trajectory against a reference: association,
//! alignment, APE and RPE, and the report that `dopslam eval` prints.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::associate::{associate, Association, AssociationRule};
use super::ate::{absolute_errors, PoseRelation};
use super::kitti_odometry::{kitti_errors, KittiErrors};
use super::rpe::{
    pairs_by_angle, pairs_by_index, pairs_by_path, relative_errors, relative_errors_seconds,
    DeltaUnit,
};
use super::stats::Statistics;
use crate::geometry::alignment::{umeyama, AlignmentError, AlignmentKind};
use crate::geometry::se3::Se3;
use crate::geometry::sim3::Sim3;
use crate::io::Trajectory;

/// How the estimate is aligned to the reference before errors are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum AlignMode {
    /// No alignment.
    None,
    /// Rotation and translation (Umeyama), evo's `-a`.
    Se3,
    /// Rotation, translation and scale (Umeyama), evo's `-as`.
    Sim3,
    /// Scale only, evo's `-s`.
    Scale,
    /// The first estimated pose is moved onto the first reference pose, evo's `--align_origin`.
    Origin,
}

/// One RPE to compute: a delta and its unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RpeSpec {
    /// The distance between the two poses of a pair.
    pub delta: f64,
    /// Its unit (frames, seconds, metres, degrees, radians).
    pub unit: DeltaUnit,
}

/// Everything an evaluation can be asked to do.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// How the poses are paired.
    pub association: AssociationRule,
    /// The association tolerance in seconds; `None` takes the rule's default.
    pub max_diff: Option<f64>,
    /// Added to the estimate's timestamps before association.
    pub offset: f64,
    /// The alignment before the APE.
    pub align: AlignMode,
    /// Align with only the first n associated poses.
    pub n_align: Option<usize>,
    /// What the APE measures (translation, rotation, full pose).
    pub ape_relation: PoseRelation,
    /// The RPEs to compute.
    pub rpe: Vec<RpeSpec>,
    /// What the RPEs measure.
    pub rpe_relation: PoseRelation,
    /// Fail when fewer than this fraction of the shorter trajectory's poses are matched.
    pub min_coverage: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            association: AssociationRule::Evo,
            max_diff: None,
            offset: 0.0,
            align: AlignMode::Se3,
            n_align: None,
            ape_relation: PoseRelation::TransPart,
            rpe: vec![RpeSpec {
                delta: 1.0,
                unit: DeltaUnit::Frames,
            }],
            rpe_relation: PoseRelation::TransPart,
            min_coverage: 0.5,
        }
    }
}

/// Why an evaluation cannot be made.
#[derive(Debug, Error)]
pub enum EvalError {
    #[error("the {which} trajectory is empty")]
    /// One trajectory has no pose.
    Empty {
        /// `reference` or `estimate`.
        which: &'static str,
    },
    #[error("no matching timestamps between the reference ({reference_first:.6}..{reference_last:.6} s) and the estimate ({estimate_first:.6}..{estimate_last:.6} s) with max. time difference {max_diff} s and offset {offset} s; check that both use the same clock, or set --offset / --max-diff")]
    /// No pose pairs within the tolerance.
    NoOverlap {
        /// The tolerance, seconds.
        max_diff: f64,
        /// The offset added to the estimate's times.
        offset: f64,
        /// The reference's first time.
        reference_first: f64,
        /// The reference's last time.
        reference_last: f64,
        /// The estimate's first time.
        estimate_first: f64,
        /// The estimate's last time.
        estimate_last: f64,
    },
    #[error("only {matched} of {max_pairs} poses ({percent:.1} %) could be matched with max. time difference {max_diff} s, below the required {required:.1} %; lower --min-coverage to accept this")]
    /// Too few poses matched.
    LowCoverage {
        /// Poses matched.
        matched: usize,
        /// Poses the shorter trajectory has.
        max_pairs: usize,
        /// `matched` over `max_pairs`, %.
        percent: f64,
        /// The tolerance, seconds.
        max_diff: f64,
        /// The coverage required, %.
        required: f64,
    },
    #[error("pairing by index needs equally long trajectories: the reference has {reference} poses, the estimate {estimate}")]
    /// Pairing by index with trajectories of different lengths.
    LengthMismatch {
        /// Poses of the reference.
        reference: usize,
        /// Poses of the estimate.
        estimate: usize,
    },
    #[error("alignment failed: {0}")]
    /// The alignment failed.
    Alignment(#[from] AlignmentError),
    #[error("RPE with delta {delta} {unit} found no pose pairs; use a smaller delta")]
    /// The RPE's delta is longer than the trajectory.
    NoRpePairs {
        /// The delta.
        delta: f64,
        /// Its unit.
        unit: &'static str,
    },
}

/// The result of one metric.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MetricResult {
    /// "APE" or "RPE".
    pub metric: String,
    /// What the errors measure.
    pub relation: PoseRelation,
    /// The errors' unit.
    pub unit: String,
    /// The RPE's delta (none for the APE).
    pub delta: Option<RpeSpec>,
    /// RMSE, mean, median, … of the errors.
    pub statistics: Statistics,
}

/// The alignment that was applied, as \(p_{ref} = sRp_{est} + t\).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AlignmentUsed {
    /// SE(3), Sim(3) or none.
    pub mode: AlignMode,
    /// \(R\), row-major.
    pub rotation: [[f64; 3]; 3],
    /// \(t\), metres.
    pub translation: [f64; 3],
    /// \(s\) (1 without scale).
    pub scale: f64,
    /// How many poses it was estimated from.
    pub poses_used: usize,
}

/// A metric's errors in order, for its plot: each pair's error and the estimate
/// timestamp it belongs to.
#[derive(Debug, Clone, Default)]
pub struct MetricSeries {
    /// The error of each pair.
    pub errors: Vec<f64>,
    /// Their timestamps.
    pub timestamps: Vec<f64>,
}

/// What the plots of an evaluation draw, beside its report: the associated
/// reference, the associated and aligned estimate, and each metric's errors.
#[derive(Debug, Clone)]
pub struct EvalSeries {
    /// The associated reference.
    pub reference: Trajectory,
    /// The associated estimate, aligned.
    pub aligned_estimate: Trajectory,
    /// The APE's errors.
    pub ape: MetricSeries,
    /// Each RPE's errors, in the report's order.
    pub rpe: Vec<MetricSeries>,
}

/// An evaluation: its report and what its plots draw.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// The figures (`dopslam eval`'s JSON).
    pub report: EvalReport,
    /// The associated trajectories and the errors in order.
    pub series: EvalSeries,
}

/// Everything `dopslam eval` reports.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    /// Poses of the reference.
    pub reference_poses: usize,
    /// Poses of the estimate.
    pub estimate_poses: usize,
    /// Pairs made.
    pub matched_poses: usize,
    /// The shorter trajectory's length, which coverage is measured against.
    pub max_pairs: usize,
    /// `matched_poses` over `max_pairs`.
    pub coverage: f64,
    /// The pairing rule.
    pub association: AssociationRule,
    /// The tolerance used, seconds.
    pub max_diff: f64,
    /// The offset added to the estimate's times.
    pub offset: f64,
    /// The alignment applied.
    pub alignment: AlignmentUsed,
    /// The APE.
    pub ape: MetricResult,
    /// The RPEs.
    pub rpe: Vec<MetricResult>,
    /// KITTI's relative errors over 100-800 m segments of the associated poses
    /// (unaligned), when the reference path is at least 100 m long.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kitti: Option<KittiErrors>,
}

fn check_not_empty(trajectory: &Trajectory, which: &'static str) -> Result<(), EvalError> {
    if trajectory.is_empty() {
        Err(EvalError::Empty { which })
    } else {
        Ok(())
    }
}

/// Computes the transform that aligns the associated estimate to the reference.
fn alignment_transform(
    reference: &Trajectory,
    estimate: &Trajectory,
    options: &EvalOptions,
) -> Result<(Sim3, usize), EvalError> {
    let n = options
        .n_align
        .unwrap_or(estimate.len())
        .min(estimate.len());
    let kind = match options.align {
        AlignMode::None => return Ok((Sim3::identity(), 0)),
        AlignMode::Origin => {
            let to_origin = reference.poses[0] * estimate.poses[0].inverse();
            return Ok((Sim3::from_se3(&to_origin), 1));
        }
        AlignMode::Se3 => AlignmentKind::Se3,
        AlignMode::Sim3 => AlignmentKind::Sim3,
        AlignMode::Scale => AlignmentKind::ScaleOnly,
    };
    let source = estimate.positions()[..n].to_vec();
    let target = reference.positions()[..n].to_vec();
    Ok((umeyama(&source, &target, kind)?, n))
}

/// Associates, aligns and computes APE and the requested RPEs.
pub fn evaluate(
    reference: &Trajectory,
    estimate: &Trajectory,
    options: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    evaluate_with_series(reference, estimate, options).map(|e| e.report)
}

impl AlignmentUsed {
    /// The alignment `transform` found in `mode` from `poses_used` pose pairs.
    fn of(mode: AlignMode, transform: &Sim3, poses_used: usize) -> Self {
        let r = transform.rotation.matrix();
        Self {
            mode,
            rotation: [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            translation: transform.translation.into(),
            scale: transform.scale,
            poses_used,
        }
    }
}

/// [`evaluate`], with what its plots draw ([`EvalSeries`]).
pub fn evaluate_with_series(
    reference: &Trajectory,
    estimate: &Trajectory,
    options: &EvalOptions,
) -> Result<Evaluation, EvalError> {
    let (association, max_diff) = associate_checked(reference, estimate, options)?;
    let matched = association.pairs.len();
    let coverage = matched as f64 / association.max_pairs as f64;
    let reference_ids: Vec<usize> = association.pairs.iter().map(|p| p.0).collect();
    let estimate_ids: Vec<usize> = association.pairs.iter().map(|p| p.1).collect();
    let reference_sync = reference.select(&reference_ids);
    let estimate_sync = estimate.select(&estimate_ids);

    let kitti =
        kitti_errors(&reference_sync.poses, &estimate_sync.poses).filter(|k| k.segments > 0);
    let (transform, poses_used) = alignment_transform(&reference_sync, &estimate_sync, options)?;
    let aligned = aligned_by(&transform, &estimate_sync);

    let ape_errors = absolute_errors(&reference_sync.poses, &aligned.poses, options.ape_relation);
    let ape = MetricResult {
        metric: "APE".into(),
        relation: options.ape_relation,
        unit: options.ape_relation.unit().to_string(),
        delta: None,
        statistics: Statistics::of(&ape_errors).expect("matched > 0"),
    };
    let ape_series = MetricSeries {
        errors: ape_errors,
        timestamps: aligned.timestamps.clone(),
    };

    let rpe = options
        .rpe
        .iter()
        .map(|spec| {
            rpe_metric(
                spec,
                reference,
                estimate,
                &reference_sync,
                &aligned,
                &transform,
                options,
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (rpe, rpe_series): (Vec<_>, Vec<_>) = rpe.into_iter().unzip();

    let report = EvalReport {
        reference_poses: reference.len(),
        estimate_poses: estimate.len(),
        matched_poses: matched,
        max_pairs: association.max_pairs,
        coverage,
        association: options.association,
        max_diff,
        offset: options.offset,
        alignment: AlignmentUsed::of(options.align, &transform, poses_used),
        ape,
        rpe,
        kitti,
    };
    let series = EvalSeries {
        reference: reference_sync,
        aligned_estimate: aligned,
        ape: ape_series,
        rpe: rpe_series,
    };
    Ok(Evaluation { report, series })
}

/// The pose pairs of `reference` and `estimate` under `options`' association rule,
/// with the `max_diff` used; an error when they do not overlap enough.
fn associate_checked(
    reference: &Trajectory,
    estimate: &Trajectory,
    options: &EvalOptions,
) -> Result<(Association, f64), EvalError> {
    check_not_empty(reference, "reference")?;
    check_not_empty(estimate, "estimate")?;
    if options.association == AssociationRule::ByIndex && reference.len() != estimate.len() {
        return Err(EvalError::LengthMismatch {
            reference: reference.len(),
            estimate: estimate.len(),
        });
    }
    let max_diff = options
        .max_diff
        .unwrap_or(options.association.default_max_diff());
    let association = associate(
        reference,
        estimate,
        options.association,
        max_diff,
        options.offset,
    );
    let matched = association.pairs.len();
    if matched == 0 {
        return Err(EvalError::NoOverlap {
            max_diff,
            offset: options.offset,
            reference_first: reference.timestamps[0],
            reference_last: *reference.timestamps.last().expect("not empty"),
            estimate_first: estimate.timestamps[0],
            estimate_last: *estimate.timestamps.last().expect("not empty"),
        });
    }
    let coverage = matched as f64 / association.max_pairs as f64;
    if coverage < options.min_coverage {
        return Err(EvalError::LowCoverage {
            matched,
            max_pairs: association.max_pairs,
            percent: 100.0 * coverage,
            max_diff,
            required: 100.0 * options.min_coverage,
        });
    }
    Ok((association, max_diff))
}

/// `trajectory` moved by `transform` (the alignment), pose by pose.
fn aligned_by(transform: &Sim3, trajectory: &Trajectory) -> Trajectory {
    Trajectory {
        timestamps: trajectory.timestamps.clone(),
        poses: trajectory
            .poses
            .iter()
            .map(|p| transform.apply_to_pose(p))
            .collect::<Vec<Se3>>(),
    }
}

/// One RPE metric (`spec`): the aligned estimate's relative errors against the
/// reference's, \(E_{ij} = (Q_i^{-1} Q_j)^{-1} (P_i^{-1} P_j)\) over the pairs `spec`
/// picks (frames, metres, degrees or radians apart on the synchronised poses; seconds
/// apart on the full trajectories, as TUM's `evaluate_rpe.py` does).
fn rpe_metric(
    spec: &RpeSpec,
    reference: &Trajectory,
    estimate: &Trajectory,
    reference_sync: &Trajectory,
    aligned: &Trajectory,
    transform: &Sim3,
    options: &EvalOptions,
) -> Result<(MetricResult, MetricSeries), EvalError> {
    let (errors, timestamps, unit) = match spec.unit {
        DeltaUnit::Seconds => {
            let (stamps, errors) = relative_errors_seconds(
                reference,
                &aligned_by(transform, estimate),
                spec.delta,
                options.offset,
                options.rpe_relation,
            )
            .into_iter()
            .unzip();
            (errors, stamps, format!("{}/s", options.rpe_relation.unit()))
        }
        unit => {
            let pairs = match unit {
                DeltaUnit::Frames => {
                    pairs_by_index(aligned.len(), spec.delta.round().max(1.0) as usize)
                }
                DeltaUnit::Metres => pairs_by_path(&aligned.poses, spec.delta),
                DeltaUnit::Degrees => pairs_by_angle(&aligned.poses, spec.delta, true),
                DeltaUnit::Radians => pairs_by_angle(&aligned.poses, spec.delta, false),
                DeltaUnit::Seconds => unreachable!("handled above"),
            };
            let errors = relative_errors(
                &reference_sync.poses,
                &aligned.poses,
                &pairs,
                options.rpe_relation,
            );
            let stamps = pairs.iter().map(|&(_, j)| aligned.timestamps[j]).collect();
            (errors, stamps, options.rpe_relation.unit().to_string())
        }
    };
    let statistics = Statistics::of(&errors).ok_or(EvalError::NoRpePairs {
        delta: spec.delta,
        unit: spec.unit.symbol(),
    })?;
    let result = MetricResult {
        metric: "RPE".into(),
        relation: options.rpe_relation,
        unit,
        delta: Some(*spec),
        statistics,
    };
    Ok((result, MetricSeries { errors, timestamps }))
}

impl EvalReport {
    /// The human-readable table `dopslam eval` prints.
    pub fn to_table(&self) -> String {
        let mut out = String::new();
        let rule = match self.association {
            AssociationRule::Evo => "evo nearest timestamp",
            AssociationRule::TumGreedy => "TUM associate.py greedy",
            AssociationRule::ByIndex => "by index",
        };
        let _ = writeln!(
            out,
            "matched {} of {} poses ({:.1} %; reference {} poses, estimate {}), association: {rule}, max. time difference {} s, offset {} s",
            self.matched_poses,
            self.max_pairs,
            100.0 * self.coverage,
            self.reference_poses,
            self.estimate_poses,
            self.max_diff,
            self.offset
        );
        let alignment = match self.alignment.mode {
            AlignMode::None => "none".to_string(),
            AlignMode::Origin => "origin (first poses made equal)".to_string(),
            AlignMode::Se3 => format!("SE(3) Umeyama on {} poses", self.alignment.poses_used),
            AlignMode::Sim3 => format!(
                "Sim(3) Umeyama on {} poses, scale {:.6}",
                self.alignment.poses_used, self.alignment.scale
            ),
            AlignMode::Scale => format!("scale only, scale {:.6}", self.alignment.scale),
        };
        let _ = writeln!(out, "alignment: {alignment}");
        for metric in std::iter::once(&self.ape).chain(&self.rpe) {
            let mut title = format!(
                "{} w.r.t. {} ({})",
                metric.metric,
                metric.relation.label(),
                metric.unit
            );
            if let Some(spec) = metric.delta {
                let _ = write!(title, ", delta {} {}", spec.delta, spec.unit.symbol());
            }
            let _ = writeln!(out, "\n{title}, {} pairs", metric.statistics.count);
            for (name, value) in metric.statistics.rows() {
                let _ = writeln!(out, "  {name:>7}  {value:.6}");
            }
        }
        if let Some(kitti) = &self.kitti {
            let _ = writeln!(
                out,
                "\nKITTI relative errors (devkit: 100-800 m segments every {} frames), {} segments\n  translation  {:.4} %\n  rotation     {:.4} deg/100 m",
                super::kitti_odometry::STEP,
                kitti.segments,
                kitti.translation_percent,
                kitti.rotation_deg_per_100m
            );
            for l in &kitti.per_length {
                let _ = writeln!(
                    out,
                    "  {:>4} m: {:>5} segments, {:.4} %, {:.4} deg/100 m",
                    l.length_m, l.segments, l.translation_percent, l.rotation_deg_per_100m
                );
            }
        }
        out
    }
}
