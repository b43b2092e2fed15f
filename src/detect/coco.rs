//! The 80 COCO class names in the index order detectors trained on COCO output
//! (YOLO's `coco.names`, with COCO's own spellings; "motorbike", "aeroplane", "sofa",
//! "tvmonitor" and the like are accepted as aliases).

/// The 80 COCO class names in the detectors' index order (0 = person).
pub const CLASSES: [&str; 80] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
];

/// Darknet's spellings of some classes.
const ALIASES: [(&str, &str); 6] = [
    ("motorbike", "motorcycle"),
    ("aeroplane", "airplane"),
    ("sofa", "couch"),
    ("pottedplant", "potted plant"),
    ("diningtable", "dining table"),
    ("tvmonitor", "tv"),
];

/// `Ok` when every name of `classes` (the list at `key`) is a COCO class name.
pub fn check_class_names(key: &str, classes: &[String]) -> Result<(), crate::checks::BadValue> {
    match classes.iter().find(|c| class_id(c).is_none()) {
        Some(class) => Err(crate::checks::BadValue::new(
            key,
            format!("lists {class:?}, which is not a COCO class name"),
        )),
        None => Ok(()),
    }
}

/// The COCO index of a class name (case-insensitive, aliases accepted).
pub fn class_id(name: &str) -> Option<u32> {
    let lower = name.trim().to_lowercase();
    let canonical = ALIASES
        .iter()
        .find(|(alias, _)| *alias == lower)
        .map_or(lower.as_str(), |(_, c)| c);
    CLASSES
        .iter()
        .position(|c| *c == canonical)
        .map(|i| i as u32)
}

/// The canonical name of a COCO index.
pub fn class_name(id: u32) -> Option<&'static str> {
    CLASSES.get(id as usize).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_ids_agree() {
        assert_eq!(class_id("person"), Some(0));
        assert_eq!(class_id("Chair"), Some(56));
        assert_eq!(class_id("motorbike"), Some(3));
        assert_eq!(class_id("tvmonitor"), Some(62));
        assert_eq!(class_id("unicorn"), None);
        assert_eq!(class_name(79), Some("toothbrush"));
        assert_eq!(class_name(80), None);
    }
}
