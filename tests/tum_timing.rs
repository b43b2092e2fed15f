//! The readers on TUM's real index files (`../shared/data/tum-timing`): counts and
//! the greedy association of TUM's associate.py.

use crate::common;

use dopslam::io::file_list::{associate_greedy, read_file_list};
use dopslam::io::tum::read_association_file;
use dopslam::io::Trajectory;

#[test]
fn fr1_xyz_lists_and_association() {
    let Some(data) = common::shared_data("fr1_xyz_lists_and_association") else {
        return;
    };
    let dir = data.join("tum-timing/fr1_xyz");
    let rgb = read_file_list(&dir.join("rgb.txt"), 1).unwrap();
    let depth = read_file_list(&dir.join("depth.txt"), 1).unwrap();
    assert_eq!((rgb.len(), depth.len()), (798, 798));
    let rgb_t: Vec<f64> = rgb.iter().map(|e| e.timestamp).collect();
    let depth_t: Vec<f64> = depth.iter().map(|e| e.timestamp).collect();
    assert_eq!(associate_greedy(&rgb_t, &depth_t, 0.0, 0.02).len(), 792);
    assert_eq!(associate_greedy(&rgb_t, &depth_t, 0.0, 0.01).len(), 605);
    let gt = Trajectory::read_tum(&dir.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.len(), 3000);
}

#[test]
fn walking_association_files() {
    let Some(data) = common::shared_data("walking_association_files") else {
        return;
    };
    for (name, count) in [
        ("xyz", 827),
        ("static", 717),
        ("halfsphere", 1021),
        ("rpy", 866),
    ] {
        let file = data.join(format!("tum-timing/fr3_walking_{name}.txt"));
        let entries = read_association_file(&data, &file).unwrap();
        assert_eq!(entries.len(), count, "{name}");
        assert!(entries
            .iter()
            .all(|e| (e.rgb_timestamp - e.depth_timestamp).abs() < 0.02));
    }
}
