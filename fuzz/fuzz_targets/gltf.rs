//! Fuzzes the glTF / GLB parser and the animation sampler: any input must give a scene whose
//! meshes pass `check()` at any time, or an error; nothing may panic, hang or allocate
//! without bound.
#![no_main]

use libfuzzer_sys::fuzz_target;
use scene::Scene;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(s) = scene::gltf_scene::parse(data, Path::new("fuzz.glb"), None, &Default::default())
    else {
        return;
    };
    let d = s.info().timeline.duration_s;
    for t in [0.0, d * 0.37, d, d + 1.0] {
        if let Ok(m) = s.mesh_at(t) {
            m.check().expect("sampled mesh violates its invariants");
            assert!(m.positions.iter().all(|p| p.is_finite()), "non-finite position at t = {t}");
        }
    }
});
