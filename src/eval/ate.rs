//! The absolute pose error (evo's APE, TUM's ATE).
//!
//! After association and alignment, for each pair \(i\) with reference pose \(Q_i\) and
//! aligned estimated pose \(P_i\):
//! - translation part: \(e_i = \|t(P_i) - t(Q_i)\|\) (the ATE of TUM's script),
//! - otherwise \(E_i = P_i^{-1} Q_i\) and \(e_i\) is \(\|R(E_i) - I\|_F\) (rotation part),
//!   \(\|E_i - I\|_F\) (full), or the angle of \(R(E_i)\) in radians or degrees.

use serde::{Deserialize, Serialize};

use crate::geometry::se3::{self, Se3};
use crate::geometry::so3;

/// Which part of the pose an error compares (evo's `PoseRelation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum PoseRelation {
    /// Translation in metres.
    #[value(name = "trans_part")]
    TransPart,
    /// Rotation angle in degrees.
    #[value(name = "angle_deg")]
    AngleDeg,
    /// Rotation angle in radians.
    #[value(name = "angle_rad")]
    AngleRad,
    /// \(\|R - I\|_F\), unit-less.
    #[value(name = "rot_part")]
    RotPart,
    /// \(\|E - I\|_F\) of the 4x4 matrix, unit-less.
    #[value(name = "full")]
    Full,
}

impl PoseRelation {
    /// evo's wording of the relation.
    pub fn label(self) -> &'static str {
        match self {
            Self::TransPart => "translation part",
            Self::AngleDeg => "rotation angle in degrees",
            Self::AngleRad => "rotation angle in radians",
            Self::RotPart => "rotation part",
            Self::Full => "full transformation",
        }
    }

    /// The unit of the relation's errors: `m`, `deg`, `rad` or `unit-less`.
    pub fn unit(self) -> &'static str {
        match self {
            Self::TransPart => "m",
            Self::AngleDeg => "deg",
            Self::AngleRad => "rad",
            Self::RotPart | Self::Full => "unit-less",
        }
    }

    /// The error of one relative pose \(E\) (a pose that is the identity when there is no error).
    pub fn error_of(self, e: &Se3) -> f64 {
        match self {
            Self::TransPart => e.translation.vector.norm(),
            Self::AngleRad => so3::angle(e.rotation.matrix()),
            Self::AngleDeg => so3::angle(e.rotation.matrix()).to_degrees(),
            Self::RotPart => (e.rotation.matrix() - nalgebra::Matrix3::identity()).norm(),
            Self::Full => (se3::to_matrix(e) - nalgebra::Matrix4::identity()).norm(),
        }
    }
}

/// The absolute error of each pair of associated poses.
pub fn absolute_errors(reference: &[Se3], estimate: &[Se3], relation: PoseRelation) -> Vec<f64> {
    reference
        .iter()
        .zip(estimate)
        .map(|(q, p)| match relation {
            PoseRelation::TransPart => (p.translation.vector - q.translation.vector).norm(),
            _ => relation.error_of(&se3::relative(p, q)),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;

    #[test]
    fn hand_computed_errors() {
        let q = se3::exp(&Vector6::new(1.0, 2.0, 3.0, 0.0, 0.0, 0.0));
        let rotation = crate::geometry::so3::exp(&nalgebra::Vector3::new(0.0, 0.0, 0.1));
        let p = se3::from_parts(nalgebra::Vector3::new(1.0, 2.0, 3.5), *rotation.matrix());
        let trans = absolute_errors(&[q], &[p], PoseRelation::TransPart)[0];
        assert!((trans - 0.5).abs() < 1e-12);
        let angle = absolute_errors(&[q], &[p], PoseRelation::AngleRad)[0];
        assert!((angle - 0.1).abs() < 1e-12);
        let degrees = absolute_errors(&[q], &[p], PoseRelation::AngleDeg)[0];
        assert!((degrees - 0.1f64.to_degrees()).abs() < 1e-10);
    }
}
