//! Dense maps judged against the static scene, and against each other
//! (`dopslam compare-maps`).
//!
//! With map points \(M\), a static reference surface \(S\) (a mesh, distances by
//! parry3d's point-to-triangle projection; or a point set, by k-d tree) sampled into
//! \(R\) (area-uniform, `sample_spacing` apart) and a threshold \(\tau\):
//! - accuracy: mean and median of \(d(m, S)\) over \(m \in M\);
//! - completion: mean of \(d(r, M)\) over \(r \in R\); completion ratio: share of
//!   \(R\) with \(d(r, M) \le\) `completion_threshold` (5 cm);
//! - precision \(P\): share of \(M\) within \(\tau\) of \(S\); recall \(Q\): share of
//!   \(R\) within \(\tau\) of \(M\); \(F = 2PQ/(P+Q)\);
//! - ghosts: map points farther than `ghost_distance` from \(S\);
//! - with the movers' ground truth \(D\) (points where movers were, `movers.ply` of a
//!   synthetic sequence, less those within `ghost_distance` of \(S\)): mover points
//!   of \(M\) (within `mover_radius` of \(D\) and farther than it from \(S\)) and the
//!   dynamic accuracy DA, the share of \(D\) with no map point within `mover_radius`
//!   (DynamicMap benchmark: dynamic points removed);
//! - against a baseline map \(B\) (fused without DOP): static accuracy SA, the share
//!   of the reference samples that \(B\) covers (within `completion_threshold`) that
//!   \(M\) covers too (static points kept).

use parry3d::math::Vector;
use parry3d::query::PointQuery;
use parry3d::shape::TriMesh;
use rayon::prelude::*;
use serde::Serialize;

use super::neighbours::PointIndex;
use crate::geometry::mesh::Mesh;

/// Thresholds of a comparison, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CompareSettings {
    /// Accuracy and precision threshold.
    pub threshold: f64,
    /// Completion and recall threshold.
    pub completion_threshold: f64,
    /// Points farther than this from the static reference are ghosts.
    pub ghost_distance: f64,
    /// Points this close to a mover's surface are on the mover.
    pub mover_radius: f64,
    /// The spacing of the reference's samples.
    pub sample_spacing: f64,
}

impl Default for CompareSettings {
    fn default() -> Self {
        Self {
            threshold: 0.02,
            completion_threshold: 0.05,
            ghost_distance: 0.05,
            mover_radius: 0.03,
            sample_spacing: 0.02,
        }
    }
}

/// The static reference: a surface or a point set.
pub enum Reference {
    /// A mesh.
    Surface(Box<TriMesh>),
    /// A point set.
    Points(PointIndex),
}

/// The static reference, with its samples.
pub struct StaticReference {
    reference: Reference,
    /// Points sampled on the reference.
    pub samples: Vec<[f32; 3]>,
}

impl StaticReference {
    /// From a mesh (its triangles) or, without triangles, its points.
    pub fn new(mesh: &Mesh, spacing: f64) -> Result<Self, String> {
        if mesh.triangles.is_empty() {
            return Ok(Self {
                reference: Reference::Points(PointIndex::new(&mesh.vertices)),
                samples: mesh.vertices.clone(),
            });
        }
        let vertices = mesh
            .vertices
            .iter()
            .map(|v| Vector::new(v[0], v[1], v[2]))
            .collect();
        let trimesh = TriMesh::new(vertices, mesh.triangles.clone())
            .map_err(|e| format!("the reference mesh is not usable: {e:?}"))?;
        Ok(Self {
            reference: Reference::Surface(Box::new(trimesh)),
            samples: mesh
                .sample_surface(spacing)
                .iter()
                .map(|p| p.map(|c| c as f32).into())
                .collect(),
        })
    }

    /// Distances of `points` to the reference (in parallel).
    pub fn distances(&self, points: &[[f32; 3]]) -> Vec<f32> {
        match &self.reference {
            Reference::Surface(mesh) => points
                .par_iter()
                .map(|p| mesh.distance_to_local_point(Vector::new(p[0], p[1], p[2]), false))
                .collect(),
            Reference::Points(index) => index.nearest_distances(points),
        }
    }
}

/// The figures of one map.
#[derive(Debug, Clone, Default, Serialize)]
pub struct MapFigures {
    /// Points in the map.
    pub points: usize,
    /// Mean distance to the reference.
    pub accuracy_mean: f64,
    /// Median distance to the reference.
    pub accuracy_median: f64,
    /// Mean distance from the reference's samples to the map.
    pub completion_mean: f64,
    /// Share of the samples within the completion threshold.
    pub completion_ratio: f64,
    /// Share of the map within the threshold.
    pub precision: f64,
    /// Share of the reference within the threshold.
    pub recall: f64,
    /// The harmonic mean of precision and recall.
    pub fscore: f64,
    /// Points farther than the ghost distance from the reference.
    pub ghost_points: usize,
    /// Their share of the map.
    pub ghost_fraction: f64,
    /// With movers' ground truth.
    pub mover_points: Option<usize>,
    /// Median distance of the mover points to the movers' surfaces.
    pub dynamic_accuracy: Option<f64>,
    /// Against the baseline map.
    pub static_accuracy: Option<f64>,
}

/// What a map's figures were counted from, for its coloured PLY, its picture and SA.
#[derive(Debug, Clone, Default)]
pub struct MapSamples {
    /// Per map point, its distance to the reference.
    pub distances: Vec<f32>,
    /// Per reference sample, whether this map covers it.
    pub covers: Vec<bool>,
}

/// A map judged: its figures and what they were counted from.
#[derive(Debug, Clone, Default)]
pub struct Judged {
    /// The figures (`compare.json`).
    pub figures: MapFigures,
    /// The distances and coverage behind them.
    pub samples: MapSamples,
}

fn share(count: usize, total: usize) -> f64 {
    if total == 0 {
        0.0
    } else {
        count as f64 / total as f64
    }
}

/// Judges `map` against `reference` (and `movers` when given).
pub fn judge(
    map: &Mesh,
    reference: &StaticReference,
    movers: Option<&[[f32; 3]]>,
    settings: &CompareSettings,
) -> Judged {
    let distances = reference.distances(&map.vertices);
    let n = distances.len();
    let mut sorted: Vec<f32> = distances.clone();
    sorted.sort_by(f32::total_cmp);
    let index = PointIndex::new(&map.vertices);
    let back = index.nearest_distances(&reference.samples);
    let covers: Vec<bool> = back
        .iter()
        .map(|&d| d as f64 <= settings.completion_threshold)
        .collect();
    let precision = share(
        distances
            .iter()
            .filter(|&&d| d as f64 <= settings.threshold)
            .count(),
        n,
    );
    let recall = share(
        back.iter()
            .filter(|&&d| d as f64 <= settings.threshold)
            .count(),
        back.len(),
    );
    let ghost_points = distances
        .iter()
        .filter(|&&d| d as f64 > settings.ghost_distance)
        .count();
    let finite_mean = |values: &[f32]| {
        let finite: Vec<f64> = values
            .iter()
            .filter(|d| d.is_finite())
            .map(|&d| d as f64)
            .collect();
        finite.iter().sum::<f64>() / finite.len().max(1) as f64
    };
    let mut figures = MapFigures {
        points: n,
        accuracy_mean: finite_mean(&distances),
        accuracy_median: sorted.get(n / 2).map_or(0.0, |&d| d as f64),
        completion_mean: finite_mean(&back),
        completion_ratio: share(covers.iter().filter(|&&c| c).count(), covers.len()),
        precision,
        recall,
        fscore: if precision + recall > 0.0 {
            2.0 * precision * recall / (precision + recall)
        } else {
            0.0
        },
        ghost_points,
        ghost_fraction: share(ghost_points, n),
        ..MapFigures::default()
    };
    if let Some(movers) = movers {
        judge_movers(
            &mut figures,
            map,
            &index,
            reference,
            movers,
            &distances,
            settings,
        );
    }
    Judged {
        figures,
        samples: MapSamples { distances, covers },
    }
}

/// The mover figures of `map`: its points near the movers' ground truth (`movers`
/// away from the static scene: feet on the floor are static) and off the static
/// scene, and the share of the movers' truth it leaves empty.
fn judge_movers(
    figures: &mut MapFigures,
    map: &Mesh,
    index: &PointIndex,
    reference: &StaticReference,
    movers: &[[f32; 3]],
    distances: &[f32],
    settings: &CompareSettings,
) {
    let away = reference.distances(movers);
    let truth: Vec<[f32; 3]> = movers
        .iter()
        .zip(&away)
        .filter(|(_, &d)| d as f64 > settings.ghost_distance)
        .map(|(p, _)| *p)
        .collect();
    let truth_index = PointIndex::new(&truth);
    let r = settings.mover_radius as f32;
    let near_truth = truth_index.nearest_distances(&map.vertices);
    figures.mover_points = Some(
        near_truth
            .iter()
            .zip(distances)
            .filter(|(&t, &s)| t <= r && s > r)
            .count(),
    );
    let kept = index.nearest_distances(&truth);
    figures.dynamic_accuracy = Some(share(kept.iter().filter(|&&d| d > r).count(), truth.len()));
}

/// SA of `map` against `baseline`: of the samples the baseline covers, the share the
/// map covers too.
pub fn static_accuracy(map: &MapSamples, baseline: &MapSamples) -> f64 {
    let covered = baseline.covers.iter().filter(|&&c| c).count();
    let both = map
        .covers
        .iter()
        .zip(&baseline.covers)
        .filter(|(&a, &b)| a && b)
        .count();
    share(both, covered)
}

/// Colours by distance: blue (0) through green to red (at `full` and beyond).
pub fn distance_colour(d: f32, full: f32) -> [u8; 3] {
    let t = (d / full).clamp(0.0, 1.0);
    let (r, g, b) = if t < 0.5 {
        (0.0, t * 2.0, 1.0 - t * 2.0)
    } else {
        ((t - 0.5) * 2.0, 1.0 - (t - 0.5) * 2.0, 0.0)
    };
    [r, g, b].map(|c| (c * 255.0).round() as u8)
}

/// A markdown table of maps' figures, one column per map.
pub fn table(names: &[String], figures: &[&MapFigures]) -> String {
    let mut out = format!(
        "| figure | {} |\n|---|{}\n",
        names.join(" | "),
        "---|".repeat(names.len())
    );
    let mut row = |label: &str, value: &dyn Fn(&MapFigures) -> String| {
        let cells: Vec<String> = figures.iter().map(|f| value(f)).collect();
        out += &format!("| {label} | {} |\n", cells.join(" | "));
    };
    row("points", &|f| f.points.to_string());
    row("accuracy mean (m)", &|f| format!("{:.4}", f.accuracy_mean));
    row("accuracy median (m)", &|f| {
        format!("{:.4}", f.accuracy_median)
    });
    row("completion mean (m)", &|f| {
        format!("{:.4}", f.completion_mean)
    });
    row("completion ratio", &|f| {
        format!("{:.4}", f.completion_ratio)
    });
    row("precision", &|f| format!("{:.4}", f.precision));
    row("recall", &|f| format!("{:.4}", f.recall));
    row("F-score", &|f| format!("{:.4}", f.fscore));
    row("ghost points", &|f| {
        format!("{} ({:.2} %)", f.ghost_points, 100.0 * f.ghost_fraction)
    });
    let optional = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    row("mover points", &|f| {
        f.mover_points.map_or("-".into(), |v| v.to_string())
    });
    row("DA (dynamic removed)", &|f| optional(f.dynamic_accuracy));
    row("SA (static kept)", &|f| optional(f.static_accuracy));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(z: f32, step: f32) -> Vec<[f32; 3]> {
        let n = (1.0 / step) as usize;
        (0..=n)
            .flat_map(|i| (0..=n).map(move |j| [i as f32 * step, j as f32 * step, z]))
            .collect()
    }

    #[test]
    fn a_perfect_map_scores_one_and_a_ghost_counts() {
        let settings = CompareSettings::default();
        let reference = StaticReference::new(&crate::geometry::mesh::unit_square(), 0.02).unwrap();
        let mut points = grid(0.0, 0.01);
        let perfect = judge(&Mesh::points(points.clone()), &reference, None, &settings);
        let (perfect, perfect_samples) = (perfect.figures, perfect.samples);
        assert!(perfect.accuracy_mean < 1e-6 && perfect.precision == 1.0);
        assert!(perfect.completion_ratio == 1.0 && perfect.recall > 0.99);
        // A "person" standing 0.5 m above the floor: ghosts, mover points, DA 0.
        let person: Vec<[f32; 3]> = grid(0.5, 0.05).into_iter().filter(|p| p[0] < 0.3).collect();
        points.extend(&person);
        let haunted = judge(&Mesh::points(points), &reference, Some(&person), &settings).figures;
        assert_eq!(haunted.ghost_points, person.len());
        assert_eq!(haunted.mover_points, Some(person.len()));
        assert_eq!(haunted.dynamic_accuracy, Some(0.0));
        assert_eq!(perfect.points + person.len(), haunted.points);
        // Half the floor only: SA against the full map is about one half.
        let half: Vec<[f32; 3]> = grid(0.0, 0.01)
            .into_iter()
            .filter(|p| p[0] <= 0.5)
            .collect();
        let half = judge(&Mesh::points(half), &reference, Some(&person), &settings);
        assert_eq!(half.figures.dynamic_accuracy, Some(1.0));
        let sa = static_accuracy(&half.samples, &perfect_samples);
        let half = half.figures;
        assert!((0.5..0.6).contains(&sa), "{sa}");
        assert!(table(&["a".into()], &[&half]).contains("| ghost points | 0 (0.00 %) |"));
    }
}
