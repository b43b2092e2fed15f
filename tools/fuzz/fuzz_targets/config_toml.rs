//! `--config` files (TOML) and the synth presets.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(config) = dopslam::config::Config::from_toml(text) {
            let _ = config.validate();
        }
        let _ = toml::from_str::<dopslam::synth::config::SynthConfig>(text);
    }
});
