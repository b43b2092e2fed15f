//! The topic options of the commands that read recordings.

use clap::Args;
use dopslam::config::Config;
use dopslam::io::recording::TopicChoice;

/// Which topics of a recording make the frames (override `[dataset]`'s keys).
#[derive(Args, Debug, Clone, Default)]
pub struct TopicArgs {
    /// A recording's colour topic (sensor_msgs/Image or CompressedImage); default: found
    /// from the messages' encodings.
    #[arg(long)]
    pub rgb_topic: Option<String>,
    /// A recording's depth topic, registered to the colour camera; default: found.
    #[arg(long)]
    pub depth_topic: Option<String>,
    /// A recording's sensor_msgs/CameraInfo topic; default: the colour topic's.
    #[arg(long)]
    pub camera_info_topic: Option<String>,
    /// A recording's pose topic (PoseStamped, Odometry, TransformStamped) to evaluate
    /// the trajectory against.
    #[arg(long)]
    pub ground_truth_topic: Option<String>,
    /// A TUM trajectory file to evaluate a recording's run against (a recording without
    /// a pose topic).
    #[arg(long, value_name = "FILE")]
    pub ground_truth: Option<std::path::PathBuf>,
}

impl TopicArgs {
    /// Writes the topics given into the config's `[dataset]`.
    pub fn apply(&self, config: &mut Config) {
        config.dataset.override_topics(&TopicChoice {
            rgb: self.rgb_topic.clone(),
            depth: self.depth_topic.clone(),
            camera_info: self.camera_info_topic.clone(),
            ground_truth: self.ground_truth_topic.clone(),
        });
        if self.ground_truth.is_some() {
            config
                .dataset
                .ground_truth_file
                .clone_from(&self.ground_truth);
        }
    }
}
