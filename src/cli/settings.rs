//! ORB-SLAM2's settings file applied to a config (`run --settings`, `fuse --settings`).

use std::path::Path;

use anyhow::Result;
use dopslam::config::Config;

/// Applies an ORB-SLAM2 settings file (the one path: [`Config::apply_orbslam_settings`])
/// and prints once what it ignored.
pub fn apply_settings(config: &mut Config, path: &Path) -> Result<()> {
    config.apply_orbslam_settings(path)?;
    print_settings_notes(config);
    Ok(())
}

/// Prints the keys of the config's settings file that were not applied.
pub fn print_settings_notes(config: &Config) {
    if let Some(applied) = &config.dataset.settings_applied {
        for note in applied.notes() {
            eprintln!("{note}");
        }
    }
}
