//! Arbitrary bytes as the one file of a DICOM series (a folder holding
//! `one.dcm`): the header walk, the parser, encapsulated pixel data and the
//! pixel decoders (RLE, JPEG, JPEG 2000). Seed the corpus with files of
//! `../shared/data/formats/dicom/`. Any outcome but a panic, an abort, a
//! hang or a huge allocation is fine; a volume that reads keeps the
//! reader's promises.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let dir = common::scratch().join("dicom");
    std::fs::create_dir_all(&dir).expect("scratch folder");
    std::fs::write(dir.join("one.dcm"), data).expect("write the input");
    if let Ok(v) = brickray_io::read_volume(&dir) {
        common::check_volume(&v);
    }
});
