//! The saved SLAM map (`slam_map.bin`, `docs/map_format.md`): what a later recording
//! needs to be tracked in a run's world frame (`dopslam run --map RUN`).
//!
//! The file is a magic line, a JSON header on one line ([`MapHeader`]: the format
//! version, the sensor, the camera, the ORB pyramid and the vocabulary it was made
//! with, the counts), then the body: each keyframe (pose, keypoints, descriptors,
//! depth, covisibility, spanning-tree parent) and each map point (position,
//! descriptor, observations, DOP state) as fixed-width little-endian records
//! (bincode), then a 16-byte trailer: the body's length, its CRC-32 and `DEND`.
//! Reading maps the file, checks the trailer (a cut or changed file is an error
//! naming it, before any record is decoded) and decodes the records in place. Bags
//! of words are not stored: they follow from the descriptors and the vocabulary
//! named in the header, and place recognition computes them again on loading.

use std::io::Write;
use std::path::Path;

use bincode::Options;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use slotmap::SecondaryMap;

use super::{KeyFrame, KeyFrameKey, Map, MapPoint};
use crate::dop::consistency::Consistency;
use crate::features::{Descriptor, KeyPoint};
use crate::frame::Frame;
use crate::geometry::se3::{self, Se3};
use crate::io::atomic::write_atomic_with;
use crate::io::IoError;

/// The file's first line.
pub const MAGIC: &[u8] = b"DOPSLAM MAP\n";
/// The body's format version this build writes and reads.
pub const FORMAT: u32 = 1;
/// The trailer's last four bytes.
const END: &[u8; 4] = b"DEND";
/// The trailer: body length (u64), CRC-32 (u32), [`END`].
const TRAILER_BYTES: usize = 16;
/// The header line's longest length.
const MAX_HEADER_BYTES: usize = 1 << 20;

/// The camera a map was made with.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapCamera {
    /// Focal lengths and principal point, pixels.
    pub fx: f64,
    /// Focal length along y.
    pub fy: f64,
    /// Principal point, x.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Baseline times fx (stereo; RGB-D: the virtual baseline of its settings).
    pub bf: f64,
}

/// What a map was made with, and what it holds: the file's JSON header line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapHeader {
    /// The body's format version ([`FORMAT`]).
    pub format: u32,
    /// The program that wrote it.
    pub written_by: String,
    /// `rgbd` or `stereo`.
    pub sensor: String,
    /// The camera.
    pub camera: MapCamera,
    /// ORB pyramid levels.
    pub orb_levels: usize,
    /// ORB pyramid scale factor.
    pub orb_scale_factor: f64,
    /// The place-recognition vocabulary's content hash (`None`: made without one).
    pub vocabulary: Option<String>,
    /// Stereo: the rig's disparity offset (pixels) in the keyframes' depths.
    pub disparity_offset_px: f64,
    /// The recordings whose keyframes the map holds, in order.
    pub recordings: Vec<String>,
    /// Keyframes in the body.
    pub keyframes: usize,
    /// Map points in the body.
    pub points: usize,
    /// Keyframes ever made (the next keyframe's id).
    pub keyframes_created: usize,
}

impl MapHeader {
    /// Why a map with this header cannot be used by a run set up as `run`, if it
    /// cannot: another sensor, camera, ORB pyramid or vocabulary.
    pub fn mismatch(&self, run: &MapHeader) -> Option<String> {
        if self.sensor != run.sensor {
            return Some(format!(
                "the map was made with a {} sensor and this sequence is {}",
                self.sensor, run.sensor
            ));
        }
        let (a, b) = (&self.camera, &run.camera);
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * x.abs().max(1.0);
        let same = a.width == b.width
            && a.height == b.height
            && [
                (a.fx, b.fx),
                (a.fy, b.fy),
                (a.cx, b.cx),
                (a.cy, b.cy),
                (a.bf, b.bf),
            ]
            .iter()
            .all(|&(x, y)| close(x, y));
        if !same {
            return Some(format!(
                "the map was made with another camera ({}x{}, fx {} fy {} cx {} cy {} bf {}; this run: {}x{}, fx {} fy {} cx {} cy {} bf {})",
                a.width, a.height, a.fx, a.fy, a.cx, a.cy, a.bf, b.width, b.height, b.fx, b.fy, b.cx, b.cy, b.bf
            ));
        }
        if self.orb_levels != run.orb_levels || !close(self.orb_scale_factor, run.orb_scale_factor)
        {
            return Some(format!(
                "the map's ORB pyramid has {} levels at scale {} and this run's {} at {} (ORBextractor.nLevels, scaleFactor)",
                self.orb_levels, self.orb_scale_factor, run.orb_levels, run.orb_scale_factor
            ));
        }
        if self.vocabulary != run.vocabulary {
            return Some(format!(
                "the map was made with vocabulary {} and this run has {} ([global] vocabulary)",
                self.vocabulary.as_deref().unwrap_or("none"),
                run.vocabulary.as_deref().unwrap_or("none")
            ));
        }
        None
    }
}

/// One keyframe's record.
#[derive(Serialize, Deserialize)]
struct KeyFrameRecord {
    id: u64,
    index: u64,
    timestamp: f64,
    recording: u32,
    segment: u32,
    /// \(T_{cw}\): rotation row by row, then translation.
    pose: [f64; 12],
    width: u32,
    height: u32,
    keypoints: Vec<KeyPoint>,
    descriptors: Vec<Descriptor>,
    depth: Vec<f32>,
    right_u: Vec<f32>,
    moving: Vec<f32>,
    /// Covisible keyframes (record numbers) and weights, most first.
    connections: Vec<(u32, u32)>,
    parent: Option<u32>,
}

/// One map point's record.
#[derive(Serialize, Deserialize)]
struct PointRecord {
    position: [f64; 3],
    descriptor: Descriptor,
    normal: [f64; 3],
    min_distance: f64,
    max_distance: f64,
    /// (keyframe record, keypoint) in the point's order (its first is its reference).
    observations: Vec<(u32, u32)>,
    visible: u32,
    found: u32,
    first_keyframe_id: u64,
    moving: f32,
    consistency: Consistency,
}

fn codec() -> impl Options {
    bincode::DefaultOptions::new()
        .with_fixint_encoding()
        .with_little_endian()
}

fn pose_record(pose: &Se3) -> [f64; 12] {
    let (r, t) = (pose.rotation.matrix(), pose.translation.vector);
    [
        r[(0, 0)],
        r[(0, 1)],
        r[(0, 2)],
        r[(1, 0)],
        r[(1, 1)],
        r[(1, 2)],
        r[(2, 0)],
        r[(2, 1)],
        r[(2, 2)],
        t.x,
        t.y,
        t.z,
    ]
}

fn pose_of(p: &[f64; 12]) -> Se3 {
    let r = Matrix3::new(p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]);
    se3::from_parts(Vector3::new(p[9], p[10], p[11]), r)
}

/// A writer that counts the bytes and their CRC-32 on the way through.
struct Summed<'a> {
    out: &'a mut dyn Write,
    bytes: u64,
    crc: crc32fast::Hasher,
}

impl Write for Summed<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.out.write(buf)?;
        self.bytes += n as u64;
        self.crc.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// Writes `map` to `path` (atomically) under `header`, whose counts and recordings
/// are taken from the map. Keyframes go in insertion order, one record at a time.
pub fn write_map(path: &Path, map: &Map, header: &MapHeader) -> Result<(), IoError> {
    let header = MapHeader {
        format: FORMAT,
        recordings: map.recordings.clone(),
        keyframes: map.keyframe_order.len(),
        points: map.points.len(),
        keyframes_created: map.keyframes_created,
        ..header.clone()
    };
    let json = serde_json::to_string(&header).expect("the header serialises");
    write_atomic_with(path, |out| {
        out.write_all(MAGIC)?;
        out.write_all(json.as_bytes())?;
        out.write_all(b"\n")?;
        let mut body = Summed {
            out,
            bytes: 0,
            crc: crc32fast::Hasher::new(),
        };
        write_body(&mut body, map).map_err(std::io::Error::other)?;
        let (bytes, crc) = (body.bytes, body.crc.finalize());
        out.write_all(&bytes.to_le_bytes())?;
        out.write_all(&crc.to_le_bytes())?;
        out.write_all(END)
    })
}

fn write_body(out: &mut dyn Write, map: &Map) -> Result<(), bincode::Error> {
    let keyframe_number: SecondaryMap<KeyFrameKey, u32> = map
        .keyframe_order
        .iter()
        .enumerate()
        .map(|(i, k)| (*k, i as u32))
        .collect();
    for key in &map.keyframe_order {
        let kf = &map.keyframes[*key];
        codec().serialize_into(&mut *out, &keyframe_record(kf, &keyframe_number))?;
    }
    for point in map.points.values() {
        let observations = point
            .observations
            .iter()
            .filter_map(|(k, i)| Some((*keyframe_number.get(*k)?, *i as u32)))
            .collect();
        let record = PointRecord {
            position: point.position.into(),
            descriptor: point.descriptor,
            normal: point.normal.into(),
            min_distance: point.min_distance,
            max_distance: point.max_distance,
            observations,
            visible: point.visible,
            found: point.found,
            first_keyframe_id: point.first_keyframe_id as u64,
            moving: point.moving,
            consistency: point.consistency,
        };
        codec().serialize_into(&mut *out, &record)?;
    }
    Ok(())
}

fn keyframe_record(kf: &KeyFrame, number: &SecondaryMap<KeyFrameKey, u32>) -> KeyFrameRecord {
    let frame = &kf.frame;
    KeyFrameRecord {
        id: kf.id as u64,
        index: frame.index as u64,
        timestamp: frame.timestamp,
        recording: kf.recording,
        segment: kf.segment as u32,
        pose: pose_record(&kf.camera_from_world),
        width: frame.width,
        height: frame.height,
        keypoints: frame.keypoints.clone(),
        descriptors: frame.descriptors.clone(),
        depth: frame.depth.clone(),
        right_u: frame.right_u.clone(),
        moving: frame.moving.clone(),
        connections: kf
            .connections
            .iter()
            .filter_map(|(k, w)| Some((*number.get(*k)?, *w as u32)))
            .collect(),
        parent: kf.parent.and_then(|p| number.get(p).copied()),
    }
}

/// The map file's length and the CRC-32 its trailer records, read from its last
/// [`TRAILER_BYTES`] bytes alone (what identifies a map without reading it; the
/// trailer is not checked here: [`read_header`] and [`read_map`] do).
pub fn checksum(path: &Path) -> std::io::Result<(u64, u32)> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path)?;
    let length = file.seek(SeekFrom::End(0))?;
    file.seek(SeekFrom::End(-(TRAILER_BYTES as i64)))?;
    let mut trailer = [0u8; TRAILER_BYTES];
    file.read_exact(&mut trailer)?;
    let crc = u32::from_le_bytes(trailer[8..12].try_into().expect("4 bytes"));
    Ok((length, crc))
}

/// The header of the map file at `path`, checked as far as it goes without the body.
pub fn read_header(path: &Path) -> Result<MapHeader, IoError> {
    let bytes = crate::io::recording::mapped::map(path)?;
    Ok(split(path, &bytes)?.0)
}

/// The header and the body of a map file's bytes, the trailer checked.
fn split<'a>(path: &Path, bytes: &'a [u8]) -> Result<(MapHeader, &'a [u8]), IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    if !bytes.starts_with(MAGIC) {
        return Err(invalid(
            "not a dopslam map (a run folder's slam_map.bin starts with \"DOPSLAM MAP\")".into(),
        ));
    }
    let rest = &bytes[MAGIC.len()..];
    let line_end = rest
        .iter()
        .take(MAX_HEADER_BYTES)
        .position(|&b| b == b'\n')
        .ok_or_else(|| invalid("the header line is cut or too long".into()))?;
    let header: MapHeader = serde_json::from_slice(&rest[..line_end])
        .map_err(|e| invalid(format!("the header cannot be read: {e}")))?;
    if header.format != FORMAT {
        return Err(invalid(format!(
            "map format version {}, and this dopslam reads version {FORMAT}: run the recording again with this version to make its map",
            header.format
        )));
    }
    let body = &rest[line_end + 1..];
    let cut = || {
        invalid(
            "the file is cut short (its end marker is missing): copy it again, or run the recording again"
                .into(),
        )
    };
    if body.len() < TRAILER_BYTES || &body[body.len() - 4..] != END {
        return Err(cut());
    }
    let (body, trailer) = body.split_at(body.len() - TRAILER_BYTES);
    let length = u64::from_le_bytes(trailer[..8].try_into().expect("8 bytes"));
    let crc = u32::from_le_bytes(trailer[8..12].try_into().expect("4 bytes"));
    if length != body.len() as u64 {
        return Err(cut());
    }
    if crc32fast::hash(body) != crc {
        return Err(invalid(
            "the file is damaged (its checksum does not match its contents)".into(),
        ));
    }
    Ok((header, body))
}

/// Reads the map file at `path`: its header and the map, with every keyframe and
/// point it holds (keys are new; ids, poses, observations, covisibility, the spanning
/// tree and the DOP state as written).
pub fn read_map(path: &Path) -> Result<(MapHeader, Map), IoError> {
    let bytes = crate::io::recording::mapped::map(path)?;
    let (header, body) = split(path, &bytes)?;
    let damaged = |what: String| IoError::invalid(path, format!("the map is damaged: {what}"));
    let broken = |n: usize, kind: &str, e: Damage| damaged(format!("{kind} {n}: {}", e.0));
    let mut reader = body;
    let limit = body.len() as u64;
    let mut map = Map {
        recordings: header.recordings.clone(),
        keyframes_created: header.keyframes_created,
        ..Map::default()
    };
    let mut links = Vec::with_capacity(header.keyframes);
    for n in 0..header.keyframes {
        let record: KeyFrameRecord = codec()
            .with_limit(limit)
            .deserialize_from(&mut reader)
            .map_err(|e| damaged(format!("keyframe {n}: {e}")))?;
        let (key, connections, parent) =
            insert_keyframe(&mut map, record).map_err(|e| broken(n, "keyframe", e))?;
        links.push((key, connections, parent));
    }
    let keys: Vec<KeyFrameKey> = links.iter().map(|l| l.0).collect();
    link_keyframes(&mut map, &keys, links).map_err(|e| damaged(e.0))?;
    for n in 0..header.points {
        let record: PointRecord = codec()
            .with_limit(limit)
            .deserialize_from(&mut reader)
            .map_err(|e| damaged(format!("point {n}: {e}")))?;
        insert_point(&mut map, &keys, record).map_err(|e| broken(n, "point", e))?;
    }
    if !reader.is_empty() {
        return Err(damaged(format!(
            "{} bytes after the last point",
            reader.len()
        )));
    }
    Ok((header, map))
}

/// What is wrong with a record that passed the checksum (a writer's fault).
struct Damage(String);

/// A keyframe's key, its covisible keyframes (record numbers, weights) and parent.
type Links = (KeyFrameKey, Vec<(u32, u32)>, Option<u32>);

fn insert_keyframe(map: &mut Map, record: KeyFrameRecord) -> Result<Links, Damage> {
    let n = record.keypoints.len();
    let lengths = [
        record.descriptors.len(),
        record.depth.len(),
        record.right_u.len(),
        record.moving.len(),
    ];
    if lengths.iter().any(|&l| l != n) {
        return Err(Damage(format!(
            "{n} keypoints but {lengths:?} descriptors, depths, right columns, probabilities"
        )));
    }
    let mut frame = Frame::from_parts(
        record.index as usize,
        record.timestamp,
        record.keypoints,
        record.descriptors,
        record.depth,
        record.right_u,
        (record.width, record.height),
    );
    frame.moving = record.moving;
    let keyframe = KeyFrame {
        id: record.id as usize,
        segment: record.segment as usize,
        recording: record.recording,
        ..KeyFrame::new(frame, pose_of(&record.pose))
    };
    let key = map.keyframes.insert(keyframe);
    map.keyframe_order.push(key);
    Ok((key, record.connections, record.parent))
}

/// Covisibility edges and the spanning tree, once every keyframe has its key.
fn link_keyframes(map: &mut Map, keys: &[KeyFrameKey], links: Vec<Links>) -> Result<(), Damage> {
    let key_of = |n: u32| {
        keys.get(n as usize)
            .copied()
            .ok_or_else(|| Damage(format!("keyframe number {n} of {}", keys.len())))
    };
    for (key, connections, parent) in links {
        let connections = connections
            .into_iter()
            .map(|(n, w)| Ok((key_of(n)?, w as usize)))
            .collect::<Result<Vec<_>, Damage>>()?;
        map.keyframes[key].connections = connections;
        if let Some(parent) = parent.map(key_of).transpose()? {
            map.keyframes[key].parent = Some(parent);
            map.keyframes[parent].children.push(key);
        }
    }
    Ok(())
}

fn insert_point(map: &mut Map, keys: &[KeyFrameKey], record: PointRecord) -> Result<(), Damage> {
    let mut point = MapPoint::new(
        record.position.into(),
        record.descriptor,
        record.normal.into(),
        (record.min_distance, record.max_distance),
        record.first_keyframe_id as usize,
    );
    (point.visible, point.found) = (record.visible, record.found);
    (point.moving, point.consistency) = (record.moving, record.consistency);
    let key = map.points.insert(point);
    for (n, index) in record.observations {
        let keyframe = *keys
            .get(n as usize)
            .ok_or_else(|| Damage(format!("observed by keyframe number {n} of {}", keys.len())))?;
        if index as usize >= map.keyframes[keyframe].map_points.len() {
            return Err(Damage(format!("keypoint {index} of a keyframe with fewer")));
        }
        map.add_observation(key, keyframe, index as usize);
    }
    if map.points[key].observations.is_empty() {
        map.points.remove(key);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    fn header() -> MapHeader {
        MapHeader {
            format: FORMAT,
            written_by: "test".into(),
            sensor: "rgbd".into(),
            camera: MapCamera {
                fx: 500.0,
                fy: 500.0,
                cx: 320.0,
                cy: 240.0,
                width: 640,
                height: 480,
                bf: 40.0,
            },
            orb_levels: 8,
            orb_scale_factor: 1.2,
            vocabulary: Some("0123".into()),
            disparity_offset_px: 0.0,
            recordings: Vec::new(),
            keyframes: 0,
            points: 0,
            keyframes_created: 0,
        }
    }

    /// Four keyframes of 50 random keypoints, 60 points seen by two or three of them,
    /// one keyframe culled (ids skip it), two recordings.
    fn map() -> Map {
        let mut rng = Rng::new(5);
        let mut map = Map::default();
        map.begin_recording("first");
        let mut keys = Vec::new();
        for k in 0..5 {
            if k == 3 {
                map.begin_recording("second");
            }
            let n = 50;
            let keypoints = (0..n)
                .map(|_| KeyPoint {
                    x: rng.range(0.0, 640.0) as f32,
                    y: rng.range(0.0, 480.0) as f32,
                    level: (rng.uniform() * 8.0) as u8,
                    angle: rng.range(0.0, 6.0) as f32,
                    response: rng.uniform() as f32,
                })
                .collect();
            let descriptors = (0..n)
                .map(|_| [rng.next_u64(), 1, 2, rng.next_u64()])
                .collect();
            let depth = (0..n).map(|_| rng.range(0.5, 4.0) as f32).collect();
            let frame = Frame::from_parts(
                10 * k,
                k as f64 / 30.0,
                keypoints,
                descriptors,
                depth,
                vec![-1.0; n],
                (640, 480),
            );
            let pose = se3::from_parts(
                Vector3::new(0.1 * k as f64, 0.0, 0.02),
                *nalgebra::Rotation3::from_euler_angles(0.01 * k as f64, 0.2, 0.0).matrix(),
            );
            let key = map.add_keyframe(KeyFrame::new(frame, pose));
            map.set_keyframe_segment(key, k / 2);
            keys.push(key);
        }
        for p in 0..60 {
            let point = MapPoint::new(
                Vector3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(1.0, 3.0),
                ),
                [p, 0, 0, 0],
                Vector3::z(),
                (0.2, 5.0),
                0,
            );
            let point = map.insert_point(point);
            for (j, key) in keys.iter().enumerate() {
                if !(p as usize + j).is_multiple_of(3) {
                    map.add_observation(point, *key, (p as usize * 7 + j) % 50);
                }
            }
            map.point_dop_mut(point)
                .unwrap()
                .0
                .clone_from(&(p as f32 / 60.0));
        }
        for key in &keys {
            map.update_connections(*key);
        }
        map.remove_keyframe(keys[2]);
        map
    }

    /// Everything a map file keeps, with keys replaced by keyframe ids.
    fn contents(map: &Map) -> String {
        let id = |k: &KeyFrameKey| map.keyframes()[*k].id;
        let mut text = format!("{:?} {}\n", map.recordings(), map.keyframes_created());
        for key in map.keyframe_order() {
            let kf = &map.keyframes()[*key];
            let connections: Vec<_> = kf.connections.iter().map(|(k, w)| (id(k), *w)).collect();
            let mut children: Vec<_> = kf.children.iter().map(id).collect();
            children.sort();
            text += &format!(
                "kf {} {} {} {} {} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {:?}\n",
                kf.id,
                kf.frame.index,
                kf.frame.timestamp,
                kf.segment,
                kf.recording,
                kf.camera_from_world,
                kf.frame.keypoints,
                kf.frame.descriptors,
                kf.frame.depth,
                kf.frame.moving,
                connections,
                kf.parent.map(|p| id(&p)),
                children,
                kf.frame.features_in_area(320.0, 240.0, 100.0, 0, 7),
            );
        }
        let mut points: Vec<String> = map
            .points()
            .values()
            .map(|p| {
                let observations: Vec<_> =
                    p.observations.iter().map(|(k, i)| (id(k), *i)).collect();
                format!(
                    "{:?} {:?} {:?} {} {} {observations:?} {} {}",
                    p.position,
                    p.descriptor,
                    p.normal,
                    p.min_distance,
                    p.max_distance,
                    p.moving,
                    p.first_keyframe_id
                )
            })
            .collect();
        points.sort();
        text + &points.join("\n")
    }

    fn temp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("dopslam-map-file-{}-{name}", std::process::id()))
    }

    #[test]
    fn a_map_read_back_holds_what_was_written() {
        let map = map();
        let path = temp("round");
        write_map(&path, &map, &header()).unwrap();
        let (read_header, read) = read_map(&path).unwrap();
        assert_eq!(read_header.keyframes, 4);
        assert_eq!(read_header.points, map.points().len());
        assert_eq!(read_header.recordings, vec!["first", "second"]);
        assert_eq!(read.current_recording(), 1);
        assert_eq!(contents(&read), contents(&map));
        // Written again, the same bytes.
        let again = temp("again");
        write_map(&again, &read, &header()).unwrap();
        assert_eq!(
            std::fs::read(&path).unwrap(),
            std::fs::read(&again).unwrap()
        );
        std::fs::remove_file(path).unwrap();
        std::fs::remove_file(again).unwrap();
    }

    #[test]
    fn a_cut_changed_or_foreign_file_is_an_error_naming_it() {
        let path = temp("bad");
        write_map(&path, &map(), &header()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let error = |bytes: &[u8]| {
            std::fs::write(&path, bytes).unwrap();
            let message = read_map(&path).expect_err("an error").to_string();
            assert!(message.contains(&path.display().to_string()), "{message}");
            message
        };
        assert!(error(&bytes[..bytes.len() - 100]).contains("cut short"));
        let mut changed = bytes.clone();
        changed[bytes.len() / 2] ^= 0x40;
        assert!(error(&changed).contains("checksum"));
        assert!(error(b"ply\nformat binary").contains("not a dopslam map"));
        let text = String::from_utf8_lossy(&bytes[..200]).into_owned();
        let newer = text.replacen("\"format\":1", "\"format\":7", 1);
        let mut newer = newer.into_bytes();
        newer.extend_from_slice(&bytes[200..]);
        assert!(error(&newer).contains("version 7"));
        std::fs::remove_file(path).unwrap();
    }

    #[test]
    fn a_map_of_another_camera_or_vocabulary_is_refused() {
        let made = header();
        assert_eq!(made.mismatch(&header()), None);
        let mut other = header();
        other.camera.fx = 517.3;
        assert!(made.mismatch(&other).unwrap().contains("another camera"));
        let mut other = header();
        other.vocabulary = None;
        assert!(made.mismatch(&other).unwrap().contains("vocabulary"));
        let mut other = header();
        other.sensor = "stereo".into();
        assert!(made.mismatch(&other).unwrap().contains("stereo"));
    }
}
