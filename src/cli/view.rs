//! The Rerun recording from the command line: `run --rerun OUT.rrd` /
//! `--rerun-connect ADDR`, and `dopslam view RUN_DIR` (the recording of a finished run
//! folder, without tracking again).

use std::net::{TcpStream, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Args;
use dopslam::config::Config;
use dopslam::io::run_dir::RunDir;
use dopslam::io::sequence::Sequence;
use dopslam::view::{Logger, Target};

/// Where `run` sends its recording.
#[derive(Args, Debug, Clone, Default)]
pub struct RerunArgs {
    /// Write a Rerun recording of the run into this new file (open it with `rerun
    /// OUT.rrd`, from `pip install rerun-sdk==0.36.3`): images, keypoints by DOP
    /// state, boxes, poses, map, events, then the final trajectory and dense map.
    #[arg(long, value_name = "OUT.rrd", conflicts_with = "rerun_connect")]
    pub rerun: Option<PathBuf>,
    /// Stream the run to a running Rerun viewer instead (HOST:PORT, or
    /// rerun+http://HOST:PORT/proxy; the viewer listens on 9876). A viewer that does
    /// not answer is a warning, and the run goes on.
    #[arg(long, value_name = "ADDR")]
    pub rerun_connect: Option<String>,
}

/// `dopslam view`.
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// A finished run folder (what `dopslam run --out` wrote).
    run: PathBuf,
    /// The recording to write (a new file; default: RUN_NAME.rrd in the working folder).
    #[arg(
        short = 'o',
        long = "out",
        value_name = "OUT.rrd",
        conflicts_with = "connect"
    )]
    out: Option<PathBuf>,
    /// Stream to a running viewer instead (HOST:PORT or rerun+http://HOST:PORT/proxy).
    #[arg(long, value_name = "ADDR")]
    connect: Option<String>,
    /// The config the run was made with (images are logged from the sequence the
    /// report names when it can be opened; [output] sets the image scale).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// dopslam never writes into its inputs: a recording at or inside `input` is refused.
fn refuse_inside(option: &str, path: &Path, input: &Path) -> Result<()> {
    if dopslam::io::output::is_within(path, input) {
        bail!(
            "{option} {}: inside the input {}; dopslam never writes into its inputs (name a file elsewhere)",
            path.display(),
            input.display()
        );
    }
    Ok(())
}

/// A viewer's proxy address from `HOST:PORT` or a full `rerun+http://` address, and
/// the host and port to try first.
fn proxy_address(address: &str) -> Result<(String, String)> {
    let rest = address
        .strip_prefix("rerun+http://")
        .or_else(|| address.strip_prefix("rerun+https://"))
        .unwrap_or(address);
    let host_port = rest.split('/').next().unwrap_or_default();
    if !host_port.contains(':') {
        bail!("--rerun-connect {address:?}: give HOST:PORT (the viewer listens on 9876) or rerun+http://HOST:PORT/proxy");
    }
    Ok((
        format!("rerun+http://{host_port}/proxy"),
        host_port.to_string(),
    ))
}

/// The recording `run` logs into: a new file (an error before any work when it
/// exists or cannot be written), or a viewer (a warning when it does not answer).
pub fn open_for_run(args: &RerunArgs, config: &Config, input: &Path) -> Result<Option<Logger>> {
    if let Some(path) = &args.rerun {
        refuse_inside("--rerun", path, input)?;
        let logger = Logger::open(Target::File(path.clone()), &config.output, "dopslam")
            .map_err(anyhow::Error::from)
            .context("--rerun")?;
        return Ok(Some(logger));
    }
    let Some(address) = &args.rerun_connect else {
        return Ok(None);
    };
    connect(address, config)
}

/// A recording streamed to the viewer at `address`; `None`, with a warning, when
/// nothing answers there.
fn connect(address: &str, config: &Config) -> Result<Option<Logger>> {
    if !dopslam::view::AVAILABLE {
        bail!(dopslam::view::MISSING_FEATURE);
    }
    let (proxy, host_port) = proxy_address(address)?;
    let answered = host_port
        .to_socket_addrs()
        .ok()
        .and_then(|mut addresses| addresses.next())
        .map(|socket| TcpStream::connect_timeout(&socket, Duration::from_secs(2)));
    match answered {
        Some(Ok(_)) => {}
        Some(Err(e)) => {
            eprintln!("warning: --rerun-connect {address}: {e}; the run goes on without the Rerun stream (start the viewer with `rerun`)");
            return Ok(None);
        }
        None => {
            eprintln!("warning: --rerun-connect {address}: the address does not resolve; the run goes on without the Rerun stream");
            return Ok(None);
        }
    }
    let logger = Logger::open(Target::Connect(proxy), &config.output, "dopslam")?;
    Ok(Some(logger))
}

/// `dopslam view RUN_DIR`.
pub fn run_view(args: ViewArgs, config: Config) -> Result<()> {
    if !args.run.is_dir() {
        bail!(
            "{}: no such run folder (what `dopslam run --out` wrote)",
            args.run.display()
        );
    }
    let run = RunDir::new(&args.run);
    let merged = run.file(dopslam::io::run_dir::names::MERGE_REPORT);
    if !run.report().exists() && merged.exists() {
        return view_merged(&args, &config);
    }
    if !run.report().exists() {
        bail!(
            "{}: not a finished run folder (it has no report.json) nor a merged map (merge.json)",
            args.run.display()
        );
    }
    let report = dopslam::records::read_report(&run)?;
    let logger = open_view(&args, &config)?;
    let target = logger.target.clone();
    let replayed = match replay(&logger, &run, &report, &config) {
        Ok(replayed) => replayed,
        // The recording was made new by this command: a partial one goes.
        Err(e) => return Err(discard_partial(logger, e)),
    };
    dopslam::run::finish_recording(logger, false)?;
    println!(
        "{} frames ({} poses, {} images, {} keyframes' boxes) into {}",
        replayed.frames,
        replayed.poses,
        replayed.images,
        replayed.keyframe_boxes,
        target.name()
    );
    Ok(())
}

/// Logs the run folder `run` (its frames, then its results and its baseline's) into
/// `logger`'s recording.
fn replay(
    logger: &Logger,
    run: &RunDir,
    report: &dopslam::records::RunReport,
    config: &Config,
) -> Result<dopslam::view::results::Replayed> {
    let log = logger.waiting_handle();
    dopslam::run::log_pinhole(&log, &report.setup.calibration.camera);
    let sequence = open_reported_sequence(report.sequence_path.as_deref(), config);
    let replayed = dopslam::view::results::replay_frames(&log, run, report, sequence.as_deref())?;
    let truth = sequence.as_deref().and_then(|s| s.ground_truth());
    dopslam::view::results::log_results(&log, run, "", truth)?;
    let baseline = run.sub_run(dopslam::io::run_dir::names::NO_DOP);
    if baseline.report().exists() {
        dopslam::view::results::log_results(&log, &baseline, "no_dop", None)?;
    }
    Ok(replayed)
}

/// The recording of a merged map's folder (`dopslam merge --out DIR`): each recording's
/// trajectory, ground truth and own dense map under `world/recordings/<k>_<sequence>/`,
/// the merged map under `world/merged/`, all in the one world frame they share.
fn view_merged(args: &ViewArgs, config: &Config) -> Result<()> {
    let dir = RunDir::new(&args.run);
    let merge = dopslam::records::read_merge(&dir)?;
    let logger = open_view(args, config)?;
    let target = logger.target.clone();
    let logged = (|| -> Result<usize> {
        let log = logger.waiting_handle();
        for (k, recording) in merge.recordings.iter().enumerate() {
            let run = RunDir::new(&recording.run);
            let report = dopslam::records::read_report(&run).with_context(|| {
                format!(
                    "recording {} of {}",
                    k + 1,
                    dir.file("merge.json").display()
                )
            })?;
            if k == 0 {
                dopslam::run::log_pinhole(&log, &report.setup.calibration.camera);
            }
            let sequence = open_reported_sequence(report.sequence_path.as_deref(), config);
            let truth = sequence.as_deref().and_then(|s| s.ground_truth());
            let prefix = format!("recordings/{}_{}", k + 1, report.sequence);
            dopslam::view::results::log_results(&log, &run, &prefix, truth)?;
        }
        dopslam::view::results::log_dense(&log, &dir, "merged")?;
        Ok(merge.recordings.len())
    })();
    let recordings = match logged {
        Ok(n) => n,
        Err(e) => return Err(discard_partial(logger, e)),
    };
    dopslam::run::finish_recording(logger, false)?;
    println!(
        "{recordings} recordings and their merged map into {}",
        target.name()
    );
    Ok(())
}

/// The recording `view` writes: a new file (default: NAME.rrd in the working folder),
/// or a viewer at `--connect`.
fn open_view(args: &ViewArgs, config: &Config) -> Result<Logger> {
    match (&args.connect, &args.out) {
        (Some(address), _) => match connect(address, config)? {
            Some(logger) => Ok(logger),
            None => bail!("--connect {address}: no viewer answers there"),
        },
        (None, out) => {
            let path = out.clone().unwrap_or_else(|| default_out(&args.run));
            refuse_inside("-o", &path, &args.run)?;
            Ok(Logger::open(Target::File(path), &config.output, "dopslam")?)
        }
    }
}

/// `error`, after removing the partial recording file this command made.
fn discard_partial(logger: Logger, error: anyhow::Error) -> anyhow::Error {
    let target = logger.target.clone();
    drop(logger);
    match &target {
        Target::File(path) => {
            let _ = std::fs::remove_file(path);
            anyhow::anyhow!(
                "{error:#} (the partial recording {} was removed)",
                path.display()
            )
        }
        Target::Connect(_) => error,
    }
}

/// `NAME.rrd` in the working folder for the run folder `NAME`.
fn default_out(run: &Path) -> PathBuf {
    let name = run
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_os_string()))
        .unwrap_or_else(|| "run".into());
    PathBuf::from(name).with_extension("rrd")
}

/// The sequence the report names, when it still opens (a warning says why not).
fn open_reported_sequence(path: Option<&Path>, config: &Config) -> Option<Box<dyn Sequence>> {
    let path = path?;
    match dopslam::run::open_sequence(path, config) {
        Ok(sequence) => Some(sequence),
        Err(e) => {
            eprintln!(
                "warning: the run's sequence {} does not open ({e}): no images in the recording",
                path.display()
            );
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viewer_addresses() {
        assert_eq!(
            proxy_address("127.0.0.1:9876").unwrap().0,
            "rerun+http://127.0.0.1:9876/proxy"
        );
        assert_eq!(
            proxy_address("rerun+http://host:9000/proxy").unwrap().1,
            "host:9000"
        );
        assert!(proxy_address("localhost").is_err());
    }
}
