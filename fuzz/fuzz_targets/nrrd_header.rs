//! Arbitrary bytes as a NRRD file, read as attached (`f.nrrd`) and as a
//! detached header (`f.nhdr`) beside a data file `f.data`. Any outcome but a
//! panic, an abort, a hang or a huge allocation is fine; a volume that reads
//! keeps the reader's promises.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let dir = common::scratch();
    let payload = dir.join("f.data");
    if !payload.exists() {
        // i16 5x4x3, raw.
        std::fs::write(
            &payload,
            (0i16..60)
                .flat_map(|v| v.to_le_bytes())
                .collect::<Vec<u8>>(),
        )
        .expect("write f.data");
    }
    for name in ["f.nrrd", "f.nhdr"] {
        let p = dir.join(name);
        std::fs::write(&p, data).expect("write the input");
        if let Ok(v) = brickray_io::read_volume(&p) {
            common::check_volume(&v);
        }
    }
});
