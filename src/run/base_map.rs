//! A run in the map an earlier run left (`dopslam run SEQ --map RUN`): the map file
//! found and checked against the run's set-up before any work ([`check`]), the
//! set-up adjusted to it ([`adjust`]), the map read when the run starts ([`load`]),
//! and the header a run writes its own map under ([`header_of`]).

use std::path::Path;
use std::time::Instant;

use super::error::RunError;
use super::options::BaseMap;
use super::setup::Setup;
use crate::io::run_dir::names::SLAM_MAP;
use crate::io::sequence::SensorKind;
use crate::map::file::{read_header, read_map, MapCamera, MapHeader, FORMAT};
use crate::map::Map;
use crate::records::{LoadedMap, RigOffset};

/// The map of run folder (or map file) `run`, frozen or not: its file must exist.
pub fn base_map(run: &Path, frozen: bool) -> Result<BaseMap, RunError> {
    let file = if run.is_dir() {
        run.join(SLAM_MAP)
    } else {
        run.to_path_buf()
    };
    if !file.is_file() {
        return Err(RunError::Input(format!(
            "--map {}: {} not found: a run writes its map there at its end (unless [output] slam_map = false or it ran with --map-frozen); run that recording again with this version to make one",
            run.display(),
            file.display()
        )));
    }
    Ok(BaseMap { file, frozen })
}

/// What a run of `setup` would write as its map's header (counts and recordings
/// are filled in when it is written).
pub fn header_of(setup: &Setup, disparity_offset_px: f64) -> MapHeader {
    let camera = &setup.calibration.camera;
    let pyramid = &setup.extractor.pyramid;
    MapHeader {
        format: FORMAT,
        written_by: format!("dopslam {}", env!("CARGO_PKG_VERSION")),
        sensor: sensor_name(setup.sensor).into(),
        camera: MapCamera {
            fx: setup.camera.fx,
            fy: setup.camera.fy,
            cx: setup.camera.cx,
            cy: setup.camera.cy,
            width: camera.width,
            height: camera.height,
            bf: setup.camera.bf,
        },
        orb_levels: pyramid.factors.len(),
        orb_scale_factor: pyramid.scale_factor,
        vocabulary: match &setup.vocabulary {
            Some(Ok(vocabulary)) => Some(crate::io::content_hash(&vocabulary.to_bytes())),
            _ => None,
        },
        disparity_offset_px,
        recordings: Vec::new(),
        keyframes: 0,
        points: 0,
        keyframes_created: 0,
    }
}

fn sensor_name(sensor: SensorKind) -> &'static str {
    match sensor {
        SensorKind::Rgbd => "rgbd",
        SensorKind::Stereo => "stereo",
    }
}

/// Before any work: the map file is whole (its checksum), of a format this build
/// reads, and made with this sensor, camera, ORB pyramid and vocabulary. Returns its
/// header. (The map's run folder is never written: the output check counts it as an
/// input, [`super::outputs::prepare`].)
pub fn check(setup: &Setup, base: &BaseMap) -> Result<MapHeader, RunError> {
    let header = read_header(&base.file)?;
    if let Some(why) = header.mismatch(&header_of(setup, header.disparity_offset_px)) {
        return Err(RunError::Input(format!(
            "--map {}: {why}",
            base.file.display()
        )));
    }
    Ok(header)
}

/// The set-up of a run in a loaded map: a stereo map's disparity offset is the
/// run's (not searched again, nor estimated by the global pass); a frozen map is not
/// optimised (no loop closing, so no place recognition beside tracking either, and
/// no full BA).
pub fn adjust(mut setup: Setup, header: &MapHeader, frozen: bool) -> Setup {
    if setup.sensor == SensorKind::Stereo {
        setup.disparity_offset = Some(RigOffset {
            offset_px: header.disparity_offset_px,
            source: "map".into(),
            frames: None,
            estimate: None,
            taken: Vec::new(),
        });
    }
    let global = &mut setup.config.global;
    global.disparity_offset = false;
    if frozen {
        global.loops.enabled = false;
        global.full_ba = false;
        if setup.vocabulary.is_some() {
            setup.vocabulary = Some(Err(crate::global::NoLoops::TurnedOff));
        }
    }
    setup
}

/// Reads the map of `base` (checked by [`check`]): the map and what the report says
/// of it.
pub fn load(base: &BaseMap) -> Result<(Map, LoadedMap), RunError> {
    let start = Instant::now();
    let (header, map) = read_map(&base.file)?;
    let loaded = LoadedMap {
        file: crate::io::output::resolved(&base.file),
        frozen: base.frozen,
        recordings: header.recordings,
        keyframes: map.keyframes().len(),
        points: map.points().len(),
        bytes: std::fs::metadata(&base.file).map_or(0, |m| m.len()),
        load_s: start.elapsed().as_secs_f64(),
        placed_at_frame: None,
    };
    Ok((map, loaded))
}
