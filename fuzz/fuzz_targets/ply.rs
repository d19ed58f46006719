//! Fuzzes the PLY parser: any input must give a mesh that passes `check()` or an error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(l) = scene::ply::parse(data, Path::new("fuzz.ply"), &Default::default()) {
        l.mesh.check().expect("parsed mesh violates its invariants");
    }
});
