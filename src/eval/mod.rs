//! Trajectory evaluation: ATE and RPE exactly as evo (1.38) and TUM's
//! `evaluate_ate.py` / `evaluate_rpe.py` define them, KITTI's relative errors as its
//! devkit does, with statistics, reports and plots.

pub mod associate;
pub mod ate;
pub mod kitti_odometry;
pub mod plot;
pub mod report;
pub mod rpe;
pub mod stats;
pub mod truth;

pub use report::{
    evaluate, evaluate_with_series, EvalError, EvalOptions, EvalReport, EvalSeries, Evaluation,
};
