//! The place-recognition vocabulary's binary format.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(vocabulary) = dopslam::bow::vocabulary::Vocabulary::from_bytes(data) {
        // A vocabulary that reads must also describe a descriptor without panicking.
        let _ = vocabulary.word_of_at(&[0x5555_5555_5555_5555; 4], 2);
    }
});
