//! Tests of the glTF loader: real sample models (skipped when absent) and small files built
//! in memory with hand-computed expectations, plus every malformed case.

use super::*;
use base64::Engine as _;
use proptest::prelude::*;

const PI: f32 = std::f32::consts::PI;

/// Builds a glTF document around one embedded buffer.
#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
}

impl Builder {
    /// Appends a buffer view (with `extra` JSON fields such as a stride); returns its index.
    fn view(&mut self, bytes: &[u8], extra: &str) -> usize {
        while self.bin.len() & 3 != 0 {
            self.bin.push(0);
        }
        let off = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views.push(format!(
            r#"{{"buffer":0,"byteOffset":{off},"byteLength":{}{extra}}}"#,
            bytes.len()
        ));
        self.views.len() - 1
    }
    /// Appends an accessor given as JSON; returns its index.
    fn accessor(&mut self, json: String) -> usize {
        self.accessors.push(json);
        self.accessors.len() - 1
    }
    fn push(&mut self, bytes: &[u8], count: usize, ctype: u32, ty: &str, extra: &str) -> usize {
        let v = self.view(bytes, "");
        self.accessor(format!(
            r#"{{"bufferView":{v},"componentType":{ctype},"count":{count},"type":"{ty}"{extra}}}"#
        ))
    }
    fn f32s(&mut self, v: &[f32], ty: &str) -> usize {
        let n = match ty {
            "SCALAR" => 1,
            "VEC3" => 3,
            "VEC4" => 4,
            _ => 16,
        };
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.push(&bytes, v.len() / n, 5126, ty, "")
    }
    fn u16s(&mut self, v: &[u16]) -> usize {
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.push(&bytes, v.len(), 5123, "SCALAR", "")
    }
    fn joints_u8(&mut self, v: &[u8]) -> usize {
        self.push(v, v.len() / 4, 5121, "VEC4", "")
    }
    fn body(&self, rest: &str, buffer: &str) -> String {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{buffer}],"bufferViews":[{}],"accessors":[{}],{rest}}}"#,
            self.views.join(","),
            self.accessors.join(",")
        )
    }
    /// glTF JSON with a base64 data URI.
    fn gltf(&self, rest: &str) -> Vec<u8> {
        let b64 = base64::engine::general_purpose::STANDARD.encode(&self.bin);
        let buf = format!(
            r#"{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}"#,
            self.bin.len()
        );
        self.body(rest, &buf).into_bytes()
    }
    /// GLB container with the buffer in the binary chunk.
    fn glb(&self, rest: &str) -> Vec<u8> {
        let mut json = self
            .body(rest, &format!(r#"{{"byteLength":{}}}"#, self.bin.len()))
            .into_bytes();
        while json.len() & 3 != 0 {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while bin.len() & 3 != 0 {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(&0x4E4F534Au32.to_le_bytes());
        out.extend_from_slice(&json);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(&0x004E4942u32.to_le_bytes());
        out.extend_from_slice(&bin);
        out
    }
}

const TRI: [f32; 9] = [0., 0., 0., 1., 0., 0., 0., 1., 0.];

fn p() -> &'static Path {
    Path::new("mem/test.gltf")
}

fn load(bytes: &[u8]) -> Result<GltfScene, SceneError> {
    parse(bytes, p(), None, &LoadOptions::default())
}

fn load_anim(bytes: &[u8], a: &str) -> Result<GltfScene, SceneError> {
    let opts = LoadOptions {
        animation: Some(a.into()),
        ..Default::default()
    };
    parse(bytes, p(), None, &opts)
}

fn err_of(r: Result<GltfScene, SceneError>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => {
            let s = e.to_string();
            assert!(s.contains("test.gltf"), "error does not name the file: {s}");
            assert!(!s.contains('\n'), "error is not one line: {s}");
            s
        }
    }
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() < 1e-5
}

/// One triangle under a parent; `child` is the child node's transform JSON.
fn hierarchy_doc(child: &str) -> Vec<u8> {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],
        "nodes":[{{"translation":[10,0,0],"children":[1]}},{{"mesh":0,{child}}}],
        "scenes":[{{"nodes":[0]}}],"scene":0"#
    ))
}

#[test]
fn hierarchy_trs_and_matrix() {
    let h = (PI / 4.0).sin();
    let trs = format!(r#""rotation":[0,0,{h},{h}],"scale":[2,2,2]"#);
    let s = load(&hierarchy_doc(&trs)).unwrap();
    let m = s.mesh_at(0.0).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    // Scale 2, rotate 90 degrees about z, then translate by the parent's (10, 0, 0).
    assert!(close(m.positions[0], Vec3::new(10., 0., 0.)));
    assert!(close(m.positions[1], Vec3::new(10., 2., 0.)));
    assert!(close(m.positions[2], Vec3::new(8., 0., 0.)));
    assert_eq!(s.info().timeline.duration_s, 0.0);
    assert_eq!(m.material_names, vec!["default".to_string()]);
    // The same transform as a column-major matrix.
    let mat = r#""matrix":[0,2,0,0, -2,0,0,0, 0,0,2,0, 0,0,0,1]"#;
    let m2 = load(&hierarchy_doc(mat)).unwrap().mesh_at(0.0).unwrap();
    for i in 0..3 {
        assert!(close(m.positions[i], m2.positions[i]));
    }
}

/// A triangle on node 0 animated by `channels` over `samplers` built by `f`.
fn animated_doc(f: impl FnOnce(&mut Builder) -> (String, String)) -> Vec<u8> {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let (samplers, channels) = f(&mut b);
    b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],
        "nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],
        "animations":[{{"name":"move","samplers":[{samplers}],"channels":[{channels}]}}]"#
    ))
}

#[test]
fn linear_step_and_slerp_sampling() {
    let doc = animated_doc(|b| {
        let t = b.f32s(&[0.0, 2.0], "SCALAR");
        let tr = b.f32s(&[0., 0., 0., 4., 0., 0.], "VEC3");
        let t2 = b.f32s(&[0.0, 1.0], "SCALAR");
        let sc = b.f32s(&[1., 1., 1., 3., 3., 3.], "VEC3");
        let h = (PI / 4.0).sin();
        let rot = b.f32s(&[0., 0., 0., 1., 0., 0., h, h], "VEC4");
        (
            format!(
                r#"{{"input":{t},"output":{tr}}},{{"input":{t2},"output":{sc},"interpolation":"STEP"}},
                   {{"input":{t},"output":{rot},"interpolation":"LINEAR"}}"#
            ),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}},
               {"sampler":1,"target":{"node":0,"path":"scale"}},
               {"sampler":2,"target":{"node":0,"path":"rotation"}}"#
                .into(),
        )
    });
    let s = load(&doc).unwrap();
    assert_eq!(s.info().timeline.duration_s, 2.0);
    assert_eq!(s.info().timeline.frame_count(), 61);
    // t = 0.5: translation (1,0,0); scale still 1 (STEP until t = 1); rotation a quarter of
    // the way to 90 degrees = 22.5 degrees. Vertex (1,0,0) -> (cos, sin, 0) + (1,0,0).
    let m = s.mesh_at(0.5).unwrap();
    let a = PI / 8.0;
    assert!(close(m.positions[0], Vec3::new(1., 0., 0.)));
    assert!(
        close(m.positions[1], Vec3::new(1. + a.cos(), a.sin(), 0.)),
        "{}",
        m.positions[1]
    );
    // t = 1.5: translation 3, scale 3, rotation 67.5 degrees.
    let m = s.mesh_at(1.5).unwrap();
    let a = 3.0 * PI / 8.0;
    assert!(close(
        m.positions[1],
        Vec3::new(3. + 3. * a.cos(), 3. * a.sin(), 0.)
    ));
    // Past the end holds the last pose: (4,0,0) + 3 * (0,1,0) for vertex 1.
    let m = s.mesh_at(100.0).unwrap();
    assert!(close(m.positions[1], Vec3::new(4., 3., 0.)));
    // Deterministic.
    assert_eq!(s.mesh_at(0.7).unwrap(), s.mesh_at(0.7).unwrap());
}

#[test]
fn cubic_spline_translation() {
    let doc = animated_doc(|b| {
        let t = b.f32s(&[0.0, 2.0], "SCALAR");
        // (in, value, out) per key: key 0 value 0 out-tangent (1,0,0); key 1 value (1,0,0).
        let v = b.f32s(
            &[
                9., 9., 9., 0., 0., 0., 1., 0., 0., 0., 0., 0., 1., 0., 0., 9., 9., 9.,
            ],
            "VEC3",
        );
        (
            format!(r#"{{"input":{t},"output":{v},"interpolation":"CUBICSPLINE"}}"#),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}}"#.into(),
        )
    });
    let m = load(&doc).unwrap().mesh_at(1.0).unwrap();
    // See anim::tests: p(0.5) = 0.125 * 2 * 1 + 0.5 * 1 = 0.75.
    assert!(
        close(m.positions[0], Vec3::new(0.75, 0., 0.)),
        "{}",
        m.positions[0]
    );
}

#[test]
fn morph_target_weights_animate() {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let delta = b.f32s(&[0., 0., 1., 0., 0., 1., 0., 0., 1.], "VEC3");
    let t = b.f32s(&[0.0, 1.0], "SCALAR");
    let w = b.f32s(&[0.0, 2.0], "SCALAR");
    let doc = b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"targets":[{{"POSITION":{delta}}}]}}],"weights":[0.5]}}],
        "nodes":[{{"mesh":0}}],
        "animations":[{{"samplers":[{{"input":{t},"output":{w}}}],"channels":[{{"sampler":0,"target":{{"node":0,"path":"weights"}}}}]}}]"#
    ));
    let s = load(&doc).unwrap();
    assert!(close(
        s.mesh_at(0.25).unwrap().positions[1],
        Vec3::new(1., 0., 0.5)
    ));
    assert!(close(
        s.mesh_at(1.0).unwrap().positions[1],
        Vec3::new(1., 0., 2.0)
    ));
    // Without the animation, the mesh's default weight 0.5 applies.
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let delta = b.f32s(&[0., 0., 1., 0., 0., 1., 0., 0., 1.], "VEC3");
    let doc = b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"targets":[{{"POSITION":{delta}}}]}}],"weights":[0.5]}}],"nodes":[{{"mesh":0}}]"#
    ));
    assert!(close(
        load(&doc).unwrap().mesh_at(0.0).unwrap().positions[0],
        Vec3::new(0., 0., 0.5)
    ));
}

/// A two-joint skin: joint 0 at the origin, joint 1 its child at (0,1,0) rotated 90
/// degrees about z; the skinned node sits at (100,0,0), which skinning must ignore.
fn skin_doc(joints: &[u8], weights: &[f32]) -> (Builder, String) {
    let mut b = Builder::default();
    let pos = b.f32s(&[0., 2., 0., 0., 2., 0., 1., 0., 0.], "VEC3");
    let j = b.joints_u8(joints);
    let w = b.f32s(weights, "VEC4");
    let mut ibm = Vec::new();
    ibm.extend(Mat4::IDENTITY.to_cols_array());
    ibm.extend(Mat4::from_translation(Vec3::new(0., -1., 0.)).to_cols_array());
    let ibm = b.f32s(&ibm, "MAT4");
    let h = (PI / 4.0).sin();
    let rest = format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos},"JOINTS_0":{j},"WEIGHTS_0":{w}}}}}]}}],
        "skins":[{{"joints":[1,2],"inverseBindMatrices":{ibm}}}],
        "nodes":[{{"mesh":0,"skin":0,"translation":[100,0,0]}},{{"children":[2]}},
                 {{"translation":[0,1,0],"rotation":[0,0,{h},{h}]}}],
        "scenes":[{{"nodes":[0,1]}}]"#
    );
    (b, rest)
}

#[test]
fn two_joint_skin_bends_vertices() {
    let (b, rest) = skin_doc(
        &[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[1., 0., 0., 0., 0.5, 0.5, 0., 0., 0., 0., 0., 0.],
    );
    for bytes in [b.gltf(&rest), b.glb(&rest)] {
        let m = load(&bytes).unwrap().mesh_at(0.0).unwrap();
        // Joint 1: T(0,1,0) R(90z) T(0,-1,0) takes (0,2,0) to (-1,1,0).
        assert!(
            close(m.positions[0], Vec3::new(-1., 1., 0.)),
            "{}",
            m.positions[0]
        );
        // Half joint 0 (identity), half joint 1: (0,2,0) and (-1,1,0) averaged.
        assert!(
            close(m.positions[1], Vec3::new(-0.5, 1.5, 0.)),
            "{}",
            m.positions[1]
        );
        // All-zero weights: the node's rigid transform.
        assert!(
            close(m.positions[2], Vec3::new(101., 0., 0.)),
            "{}",
            m.positions[2]
        );
    }
    // Weights summing to 2 are normalized: same as (1, 0) and (0.5, 0.5).
    let (b, rest) = skin_doc(
        &[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[2., 0., 0., 0., 1., 1., 0., 0., 0., 0., 0., 0.],
    );
    let m = load(&b.gltf(&rest)).unwrap().mesh_at(0.0).unwrap();
    assert!(close(m.positions[1], Vec3::new(-0.5, 1.5, 0.)));
}

#[test]
fn joint_out_of_range_is_an_error() {
    let (b, rest) = skin_doc(
        &[5, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[1., 0., 0., 0., 0.5, 0.5, 0., 0., 0., 0., 0., 0.],
    );
    let e = err_of(load(&b.gltf(&rest)));
    assert!(e.contains("joint index 5 out of range"), "{e}");
}

#[test]
fn strip_and_fan_conversion() {
    assert_eq!(
        to_triangles(Mode::TriangleStrip, &[0, 1, 2, 3, 4]),
        vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]
    );
    assert_eq!(
        to_triangles(Mode::TriangleFan, &[0, 1, 2, 3]),
        vec![[1, 2, 0], [2, 3, 0]]
    );
    assert!(to_triangles(Mode::TriangleStrip, &[0, 1]).is_empty());
    // Points and lines are skipped and counted; materials get names.
    let mut b = Builder::default();
    let pos = b.f32s(&[0., 0., 0., 1., 0., 0., 0., 1., 0., 1., 1., 0.], "VEC3");
    let idx = b.u16s(&[0, 1, 2, 3]);
    let doc = b.gltf(&format!(
        r#""materials":[{{"name":"red"}},{{}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{idx},"mode":5,"material":1}},
                                  {{"attributes":{{"POSITION":{pos}}},"mode":0}},
                                  {{"attributes":{{"POSITION":{pos}}},"mode":6,"material":0}}]}}],
        "nodes":[{{"mesh":0}}]"#
    ));
    let s = load(&doc).unwrap();
    assert_eq!(s.skipped_primitives(), 1);
    let m = s.mesh_at(0.0).unwrap();
    m.check().unwrap();
    assert_eq!(m.triangle_count(), 4);
    assert_eq!(m.material_ids, vec![1, 1, 0, 0]);
    assert_eq!(
        m.material_names,
        vec!["red".to_string(), "material 1".into()]
    );
    // The fan instance's vertices come after the strip's four.
    assert_eq!(m.triangles[2], [5, 6, 4]);
}

#[test]
fn animation_selection_and_missing_animation() {
    let doc = animated_doc(|b| {
        let t = b.f32s(&[0.0, 2.0], "SCALAR");
        let tr = b.f32s(&[0., 0., 0., 4., 0., 0.], "VEC3");
        (
            format!(r#"{{"input":{t},"output":{tr}}}"#),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}}"#.into(),
        )
    });
    assert_eq!(
        load_anim(&doc, "move").unwrap().info().timeline.duration_s,
        2.0
    );
    assert_eq!(
        load_anim(&doc, "0").unwrap().animation_names(),
        &["move".to_string()]
    );
    let e = err_of(load_anim(&doc, "dance"));
    assert!(
        e.contains("no animation 'dance'") && e.contains("0: 'move'"),
        "{e}"
    );
    let e = err_of(load_anim(&hierarchy_doc(r#""scale":[1,1,1]"#), "1"));
    assert!(e.contains("no animations"), "{e}");
}

// ---- malformed input: each gives an error naming the file -------------------------------

#[test]
fn truncated_glb_every_prefix() {
    let (b, rest) = skin_doc(
        &[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[1., 0., 0., 0., 0.5, 0.5, 0., 0., 0., 0., 0., 0.],
    );
    let glb = b.glb(&rest);
    assert!(load(&glb).is_ok());
    for n in 0..glb.len() {
        err_of(load(&glb[..n]));
    }
}

#[test]
fn short_buffer_is_an_error() {
    let doc = String::from_utf8(hierarchy_doc(r#""scale":[1,1,1]"#)).unwrap();
    let bad = doc.replace(r#""byteLength":36,"uri""#, r#""byteLength":4000,"uri""#);
    assert_ne!(doc, bad);
    let e = err_of(load(bad.as_bytes()));
    assert!(e.contains("declares byteLength 4000"), "{e}");
    // GLB whose binary chunk is shorter than buffer 0.
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let rest = format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],"nodes":[{{"mesh":0}}]"#
    );
    let glb = String::from_utf8_lossy(&b.glb(&rest))
        .replace(r#"{"byteLength":36}"#, r#"{"byteLength":99}"#);
    err_of(load(glb.as_bytes()));
}

#[test]
fn accessor_past_view_is_an_error() {
    let doc = String::from_utf8(hierarchy_doc(r#""scale":[1,1,1]"#)).unwrap();
    let bad = doc.replace(r#""count":3"#, r#""count":4000000000"#);
    let e = err_of(load(bad.as_bytes()));
    assert!(e.contains("do not fit buffer view"), "{e}");
}

#[test]
fn bad_index_is_an_error() {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let idx = b.u16s(&[0, 1, 7]);
    let doc = b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{idx}}}]}}],"nodes":[{{"mesh":0}}]"#
    ));
    let e = err_of(load(&doc));
    assert!(e.contains("out of range (3 vertices)"), "{e}");
}

#[test]
fn nan_position_and_nan_key_are_errors() {
    let mut b = Builder::default();
    let pos = b.f32s(&[0., 0., 0., f32::NAN, 0., 0., 0., 1., 0.], "VEC3");
    let doc = b.gltf(&format!(r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],"nodes":[{{"mesh":0}}]"#));
    assert!(err_of(load(&doc)).contains("not finite"));
    let doc = animated_doc(|b| {
        let t = b.f32s(&[0.0, f32::NAN], "SCALAR");
        let tr = b.f32s(&[0., 0., 0., 4., 0., 0.], "VEC3");
        (
            format!(r#"{{"input":{t},"output":{tr}}}"#),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}}"#.into(),
        )
    });
    assert!(err_of(load(&doc)).contains("key time 1 is not finite"));
    let doc = animated_doc(|b| {
        let t = b.f32s(&[0.0, 1.0], "SCALAR");
        let tr = b.f32s(&[0., 0., 0., f32::INFINITY, 0., 0.], "VEC3");
        (
            format!(r#"{{"input":{t},"output":{tr}}}"#),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}}"#.into(),
        )
    });
    assert!(err_of(load(&doc)).contains("non-finite output"));
    // Finite inputs whose product overflows: caught when sampled.
    let doc = String::from_utf8(hierarchy_doc(r#""scale":[3e38,3e38,3e38]"#)).unwrap();
    let doc = doc.replace(r#""translation":[10,0,0]"#, r#""scale":[3e38,3e38,3e38]"#);
    let e = err_of(load(doc.as_bytes()));
    assert!(e.contains("not finite at t = 0"), "{e}");
    let doc = hierarchy_doc(r#""matrix":[1,0,0,0, 0,1,0,0, 0,0,1,0, 1e39,0,0,1]"#);
    err_of(load(&doc));
}

#[test]
fn bad_channels_are_errors() {
    let chan = |path: &str, node: usize| {
        let path = path.to_string();
        animated_doc(move |b| {
            let t = b.f32s(&[0.0, 1.0], "SCALAR");
            let tr = b.f32s(&[0., 0., 0., 4., 0., 0.], "VEC3");
            (
                format!(r#"{{"input":{t},"output":{tr}}}"#),
                format!(r#"{{"sampler":0,"target":{{"node":{node},"path":"{path}"}}}}"#),
            )
        })
    };
    assert!(err_of(load(&chan("translation", 9))).contains("target node 9"));
    err_of(load(&chan("rotation", 0))); // VEC3 output for a rotation
    err_of(load(&chan("colour", 0)));
    let doc = animated_doc(|b| {
        let t = b.f32s(&[1.0, 0.0], "SCALAR");
        let tr = b.f32s(&[0., 0., 0., 4., 0., 0.], "VEC3");
        (
            format!(r#"{{"input":{t},"output":{tr}}}"#),
            r#"{"sampler":0,"target":{"node":0,"path":"translation"}}"#.into(),
        )
    });
    assert!(err_of(load(&doc)).contains("decrease"));
}

#[test]
fn cyclic_and_shared_nodes_are_errors() {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let mesh = format!(r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}]"#);
    let cyc = b.gltf(&format!(
        r#"{mesh},"nodes":[{{"mesh":0,"children":[1]}},{{"children":[0]}}]"#
    ));
    err_of(load(&cyc));
    let own = b.gltf(&format!(r#"{mesh},"nodes":[{{"mesh":0,"children":[0]}}]"#));
    err_of(load(&own));
    let shared = b.gltf(&format!(
        r#"{mesh},"nodes":[{{"children":[2]}},{{"children":[2]}},{{"mesh":0}}]"#
    ));
    assert!(err_of(load(&shared)).contains("two parents"));
    let root_child = b.gltf(&format!(
        r#"{mesh},"nodes":[{{"children":[1]}},{{"mesh":0}}],"scenes":[{{"nodes":[0,1]}}]"#
    ));
    err_of(load(&root_child));
}

#[test]
fn utf8_bom_is_ignored() {
    let mut doc = b"\xEF\xBB\xBF".to_vec();
    doc.extend(hierarchy_doc(r#""scale":[1,1,1]"#));
    assert_eq!(
        load(&doc).unwrap().mesh_at(0.0).unwrap().triangle_count(),
        1
    );
}

#[test]
fn garbage_and_empty_inputs_are_errors() {
    for bytes in [
        &b""[..],
        b"{",
        b"glTF",
        b"\xff\xfe\x00",
        b"{}",
        b"null",
        b"glTF\x02\0\0\0\x05\0\0\0",
    ] {
        err_of(load(bytes));
    }
}

#[test]
fn external_bin_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let rest = format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],"nodes":[{{"mesh":0}}]"#
    );
    let with_uri = |uri: &str| b.body(&rest, &format!(r#"{{"byteLength":36,"uri":"{uri}"}}"#));
    let gl = dir.path().join("scene.gltf");
    std::fs::write(&gl, with_uri("scene%20data.bin")).unwrap();
    std::fs::write(dir.path().join("scene data.bin"), &b.bin).unwrap();
    let s = crate::open(gl.to_str().unwrap(), &LoadOptions::default()).unwrap();
    assert_eq!(s.mesh_at(0.0).unwrap().triangle_count(), 1);
    assert_eq!(s.info().format, "gltf");
    for (uri, want) in [
        ("missing.bin", "missing.bin"),
        ("../scene.bin", "not a relative path"),
        ("/etc/passwd", "not a relative path"),
        ("http://example.com/a.bin", "not a relative path"),
    ] {
        std::fs::write(&gl, with_uri(uri)).unwrap();
        let e = crate::open(gl.to_str().unwrap(), &LoadOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("scene.gltf") && e.contains(want), "{uri}: {e}");
    }
    // Parsed from memory without a base directory, an external buffer cannot be resolved.
    err_of(load(with_uri("a.bin").as_bytes()));
}

fn small_glb() -> Vec<u8> {
    let (b, rest) = skin_doc(
        &[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[1., 0., 0., 0., 0.5, 0.5, 0., 0., 0., 0., 0., 0.],
    );
    b.glb(&rest)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Mutated GLB bytes never panic: they load or give an error naming the file.
    #[test]
    fn mutated_glb_never_panics(edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
                                cut in any::<prop::sample::Index>()) {
        let mut g = small_glb();
        for (i, v) in edits {
            let k = i.index(g.len());
            g[k] = v;
        }
        let n = cut.index(g.len() + 1);
        match load(&g[..n]) {
            Ok(s) => {
                if let Ok(m) = s.mesh_at(0.5) {
                    prop_assert!(m.check().is_ok());
                }
            }
            Err(e) => prop_assert!(e.to_string().contains("test.gltf")),
        }
    }

    /// Arbitrary bytes never panic.
    #[test]
    fn random_bytes_never_panic(mut bytes in prop::collection::vec(any::<u8>(), 0..256), glb in any::<bool>()) {
        if glb && bytes.len() >= 4 {
            bytes[..4].copy_from_slice(b"glTF");
        }
        let _ = load(&bytes);
    }
}

// ---- real sample models -------------------------------------------------------------------

fn sample(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/scenes/gltf")
        .join(name);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

fn open_sample(name: &str, anim: Option<&str>) -> Option<Box<dyn Scene>> {
    let p = sample(name)?;
    let opts = LoadOptions {
        animation: anim.map(str::to_string),
        ..Default::default()
    };
    Some(crate::open(p.to_str().unwrap(), &opts).unwrap())
}

#[test]
fn sample_models_load_and_animate() {
    for (name, tris) in [
        ("BrainStem.glb", 61_666),
        ("CesiumMan.glb", 4_672),
        ("Fox.glb", 576),
        ("RiggedFigure.glb", 256),
        ("RiggedSimple.glb", 188),
    ] {
        let Some(s) = open_sample(name, None) else {
            continue;
        };
        let info = s.info();
        assert!(
            info.stable_topology && info.timeline.duration_s > 0.0,
            "{name}"
        );
        let a = s.mesh_at(0.0).unwrap();
        a.check().unwrap();
        assert_eq!(a.triangle_count(), tris, "{name}");
        let mid = info.timeline.duration_s * 0.5;
        let b = s.mesh_at(mid).unwrap();
        assert_eq!(a.triangles, b.triangles, "{name}: topology must be stable");
        assert_ne!(
            a.bounds(),
            b.bounds(),
            "{name}: a skinned character must move"
        );
        assert_eq!(
            b,
            s.mesh_at(mid).unwrap(),
            "{name}: sampling must be deterministic"
        );
    }
}

#[test]
fn fox_animation_selection() {
    let Some(first) = open_sample("Fox.glb", None) else {
        return;
    };
    let by_index = open_sample("Fox.glb", Some("2")).unwrap();
    let Some(p) = sample("Fox.glb") else { return };
    let bytes = std::fs::read(&p).unwrap();
    let s = parse(&bytes, &p, p.parent(), &LoadOptions::default()).unwrap();
    let names = s.animation_names().to_vec();
    assert_eq!(names.len(), 3);
    let by_name = open_sample("Fox.glb", Some(&names[2])).unwrap();
    assert_eq!(by_index.info().timeline, by_name.info().timeline);
    assert_eq!(
        by_index.mesh_at(0.3).unwrap(),
        by_name.mesh_at(0.3).unwrap()
    );
    assert_ne!(
        first.info().timeline.duration_s,
        by_index.info().timeline.duration_s
    );
    let opts = LoadOptions {
        animation: Some("Moonwalk".into()),
        ..Default::default()
    };
    let e = crate::open(p.to_str().unwrap(), &opts)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("Fox.glb") && e.contains("Moonwalk") && e.contains(&names[0]),
        "{e}"
    );
}

fn le<T: Copy, const N: usize>(v: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    v.iter().flat_map(|&x| f(x)).collect()
}

#[test]
fn sparse_interleaved_and_quantized_accessors() {
    // Interleaved: position then a 3-float colour, stride 24.
    let mut b = Builder::default();
    let mut inter = Vec::new();
    for k in 0..3 {
        inter.extend_from_slice(&TRI[3 * k..3 * k + 3]);
        inter.extend_from_slice(&[7.0, 7.0, 7.0]);
    }
    let v = b.view(&le(&inter, f32::to_le_bytes), r#","byteStride":24"#);
    let pos = b.accessor(format!(
        r#"{{"bufferView":{v},"componentType":5126,"count":3,"type":"VEC3"}}"#
    ));
    // Sparse: the same triangle with vertex 1 replaced by (5,5,5), no base view.
    let iv = b.view(&le(&[1u16], u16::to_le_bytes), "");
    let vv = b.view(&le(&[5.0f32, 5.0, 5.0], f32::to_le_bytes), "");
    let sparse = b.accessor(format!(
        r#"{{"componentType":5126,"count":3,"type":"VEC3","sparse":{{"count":1,
            "indices":{{"bufferView":{iv},"componentType":5123}},"values":{{"bufferView":{vv}}}}}}}"#
    ));
    // Quantized: i16 positions, not normalized (KHR_mesh_quantization).
    let q = b.push(
        &le(&[0i16, 0, 0, 300, 0, 0, 0, -2, 0], i16::to_le_bytes),
        3,
        5122,
        "VEC3",
        "",
    );
    let doc = b.gltf(&format!(
        r#""extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}},{{"attributes":{{"POSITION":{sparse}}}}},
                                  {{"attributes":{{"POSITION":{q}}}}}]}}],"nodes":[{{"mesh":0}}]"#
    ));
    let m = load(&doc).unwrap().mesh_at(0.0).unwrap();
    assert_eq!(&m.positions[..3], &[Vec3::ZERO, Vec3::X, Vec3::Y]);
    assert_eq!(
        &m.positions[3..6],
        &[Vec3::ZERO, Vec3::splat(5.0), Vec3::ZERO]
    );
    assert_eq!(m.positions[7], Vec3::new(300., 0., 0.));
    assert_eq!(m.positions[8], Vec3::new(0., -2., 0.));
    // A sparse index past the count is an error.
    let bad = String::from_utf8(doc)
        .unwrap()
        .replace(r#""count":1,"#, r#""count":4,"#);
    err_of(load(bad.as_bytes()));
}

#[test]
fn stride_smaller_than_element_is_an_error() {
    let mut b = Builder::default();
    let v = b.view(&le(&TRI, f32::to_le_bytes), r#","byteStride":4"#);
    let pos = b.accessor(format!(
        r#"{{"bufferView":{v},"componentType":5126,"count":3,"type":"VEC3"}}"#
    ));
    let doc = b.gltf(&format!(r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],"nodes":[{{"mesh":0}}]"#));
    assert!(err_of(load(&doc)).contains("stride"));
}

#[test]
fn geometry_extensions_are_refused() {
    let doc = String::from_utf8(hierarchy_doc(r#""scale":[1,1,1]"#)).unwrap();
    for ext in [
        "KHR_draco_mesh_compression",
        "EXT_meshopt_compression",
        "VENDOR_unknown",
    ] {
        let d = doc.replacen('{', &format!(r#"{{"extensionsRequired":["{ext}"],"#), 1);
        let e = err_of(load(d.as_bytes()));
        assert!(e.contains("unsupported") && e.contains(ext), "{e}");
    }
    let d = doc.replacen('{', r#"{"extensionsRequired":["KHR_materials_unlit"],"#, 1);
    assert!(load(d.as_bytes()).is_ok());
}

/// Byte spans of the JSON numbers outside strings.
fn number_spans(json: &str) -> Vec<(usize, usize)> {
    let b = json.as_bytes();
    let (mut out, mut i, mut in_str) = (Vec::new(), 0, false);
    while i < b.len() {
        let c = b[i];
        if in_str {
            in_str = c != b'"' || b[i - 1] == b'\\';
            i += 1;
        } else if c == b'"' {
            in_str = true;
            i += 1;
        } else if c == b'-' || c.is_ascii_digit() {
            let s = i;
            while i < b.len() && (b[i].is_ascii_digit() || b"-+.eE".contains(&b[i])) {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

fn skin_anim_json() -> String {
    let (mut b, rest) = skin_doc(
        &[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0],
        &[1., 0., 0., 0., 0.5, 0.5, 0., 0., 0., 0., 0., 0.],
    );
    let t = b.f32s(&[0.0, 1.0], "SCALAR");
    let r = b.f32s(&[0., 0., 0., 1., 0., 0., 1., 0.], "VEC4");
    let idx = b.u16s(&[0, 1, 2, 2, 1, 0]);
    let rest = rest.replace(
        r#""WEIGHTS_0":"#,
        &format!(r#""TEXCOORD_0":{t},"WEIGHTS_0":"#),
    );
    let rest = rest.replace(r#"}}]}],"#, &format!(r#"}},"indices":{idx}}}]}}],"#));
    String::from_utf8(b.gltf(&format!(
        r#"{rest},"animations":[{{"samplers":[{{"input":{t},"output":{r},"interpolation":"CUBICSPLINE"}},{{"input":{t},"output":{r}}}],
        "channels":[{{"sampler":1,"target":{{"node":2,"path":"rotation"}}}}]}}]"#
    )))
    .unwrap()
}

#[test]
fn structured_fuzz_seed_is_valid() {
    let s = load(skin_anim_json().as_bytes()).unwrap();
    assert_eq!(s.mesh_at(0.0).unwrap().triangle_count(), 2);
    assert!(number_spans(&skin_anim_json()).len() > 50);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1024))]

    /// Replacing numbers of a valid document (indices, counts, offsets, strides, component
    /// types, modes) with hostile values never panics, hangs or allocates wildly.
    #[test]
    fn hostile_numbers_never_panic(edits in prop::collection::vec((any::<prop::sample::Index>(), 0usize..14), 1..5)) {
        const VALUES: [&str; 14] = ["0", "1", "2", "3", "4", "5", "7", "-1", "255", "5121", "5125",
                                    "65535", "4294967295", "1e30"];
        let json = skin_anim_json();
        let spans = number_spans(&json);
        let mut chosen: Vec<(usize, usize)> =
            edits.iter().map(|(i, v)| (i.index(spans.len()), *v)).collect();
        chosen.sort();
        chosen.dedup_by_key(|c| c.0);
        let mut out = json.clone();
        for &(k, v) in chosen.iter().rev() {
            let (s, e) = spans[k];
            out.replace_range(s..e, VALUES[v]);
        }
        match load(out.as_bytes()) {
            Ok(s) => {
                let m = s.mesh_at(0.5);
                if let Ok(m) = m {
                    prop_assert!(m.check().is_ok());
                }
            }
            Err(e) => prop_assert!(e.to_string().contains("test.gltf")),
        }
    }
}

#[test]
fn second_joint_set_u16_joints_and_normalized_u8_weights() {
    let mut b = Builder::default();
    let pos = b.f32s(&[0., 2., 0., 0., 2., 0., 1., 0., 0.], "VEC3");
    let j0 = b.push(&le(&[0u16; 12], u16::to_le_bytes), 3, 5123, "VEC4", "");
    let w0 = b.push(
        &[0, 0, 0, 0, 128, 0, 0, 0, 0, 0, 0, 0],
        3,
        5121,
        "VEC4",
        r#","normalized":true"#,
    );
    let j1 = b.push(
        &le(&[1u16, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0], u16::to_le_bytes),
        3,
        5123,
        "VEC4",
        "",
    );
    let w1 = b.push(
        &[255, 0, 0, 0, 128, 0, 0, 0, 0, 0, 0, 0],
        3,
        5121,
        "VEC4",
        r#","normalized":true"#,
    );
    let mut ibm = Vec::new();
    ibm.extend(Mat4::IDENTITY.to_cols_array());
    ibm.extend(Mat4::from_translation(Vec3::new(0., -1., 0.)).to_cols_array());
    let ibm = b.f32s(&ibm, "MAT4");
    let h = (PI / 4.0).sin();
    let doc = b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos},"JOINTS_0":{j0},"WEIGHTS_0":{w0},"JOINTS_1":{j1},"WEIGHTS_1":{w1}}}}}]}}],
        "skins":[{{"joints":[1,2],"inverseBindMatrices":{ibm}}}],
        "nodes":[{{"mesh":0,"skin":0,"translation":[100,0,0]}},{{"children":[2]}},
                 {{"translation":[0,1,0],"rotation":[0,0,{h},{h}]}}]"#
    ));
    let m = load(&doc).unwrap().mesh_at(0.0).unwrap();
    // Same expectations as `two_joint_skin_bends_vertices`, with influences split over
    // two sets: all on joint 1; half and half; none (rigid).
    assert!(
        close(m.positions[0], Vec3::new(-1., 1., 0.)),
        "{}",
        m.positions[0]
    );
    assert!(
        close(m.positions[1], Vec3::new(-0.5, 1.5, 0.)),
        "{}",
        m.positions[1]
    );
    assert!(
        close(m.positions[2], Vec3::new(101., 0., 0.)),
        "{}",
        m.positions[2]
    );
}

#[test]
fn animated_matrix_node_is_decomposed() {
    let mut b = Builder::default();
    let pos = b.f32s(&TRI, "VEC3");
    let t = b.f32s(&[0.0], "SCALAR");
    let v = b.f32s(&[0., 5., 0.], "VEC3");
    let doc = b.gltf(&format!(
        r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}],
        "nodes":[{{"translation":[10,0,0],"children":[1]}},
                 {{"mesh":0,"matrix":[2,0,0,0, 0,2,0,0, 0,0,2,0, 1,0,0,1]}}],
        "animations":[{{"samplers":[{{"input":{t},"output":{v}}}],
                        "channels":[{{"sampler":0,"target":{{"node":1,"path":"translation"}}}}]}}]"#
    ));
    let m = load(&doc).unwrap().mesh_at(0.0).unwrap();
    // Scale 2 kept from the matrix, its translation (1,0,0) replaced by the animated
    // (0,5,0); the parent adds (10,0,0).
    assert!(
        close(m.positions[1], Vec3::new(12., 5., 0.)),
        "{}",
        m.positions[1]
    );
}
