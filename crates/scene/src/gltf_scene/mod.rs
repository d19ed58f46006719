//! glTF 2.0 scenes (`.gltf` + `.bin`, `.glb`): node hierarchies, mesh primitives, skins,
//! morph targets and keyframe animations, sampled at any time as world-space triangles.
//!
//! Everything that does not depend on time (decoded positions, indices, skin influences,
//! morph deltas, the node order) is decoded and checked at load, so [`Scene::mesh_at`] only
//! samples the animation, composes transforms and skins. The `gltf` crate parses and
//! validates the JSON; buffers and accessors are resolved and bounds-checked here
//! (module `data`) because the crate's readers trust declared lengths.
//!
//! Conventions of this loader:
//! - Scene: the default scene, else scene 0, else every parentless node.
//! - Primitives: TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN become triangles (strips and
//!   fans converted per the spec's vertex order); POINTS and LINES* are skipped and
//!   counted in [`GltfScene::skipped_primitives`].
//! - Materials: a triangle's id is its primitive's glTF material index; names are the
//!   material names (`material N` when unnamed). When some primitive has no material, one
//!   extra entry `default` is appended and those primitives use it. Names are therefore in
//!   glTF index order, not order of first appearance.
//! - Skins: joint matrix = global(joint) * inverseBindMatrix; the skinned node's own
//!   transform is ignored (glTF 3.7.3.3). Weights are renormalized to sum 1; a vertex whose
//!   weights sum to 0 uses the node's rigid transform. Influences with weight 0 are dropped;
//!   a non-zero weight on a joint index outside the skin is a load error.
//! - Morph targets: POSITION deltas weighted by the node's (or mesh's) weights, animated by
//!   `weights` channels. Other target attributes are ignored (only positions matter here).
//! - Non-finite data (positions, keys, transforms) is an error, at load or at the sampled
//!   time (the crate's NaN policy for animated sources).
//! - Animation: [`LoadOptions::animation`] is matched against animation names first, then
//!   read as an index; default the first animation. Duration = the largest key time of
//!   its channels. Nodes given as a matrix and animated are decomposed into TRS.
//! - Camera: [`Camera::framing`] of the bounds at time 0 (glTF cameras are ignored).
//! - Leniency: POSITION accessors without `min`/`max` are accepted; required extensions
//!   that only affect appearance (and `KHR_mesh_quantization`) are accepted, any other
//!   is refused as unsupported.
//! - External buffers: only relative paths inside the file's directory (no `..`, no
//!   absolute paths or URL schemes); `data:` URIs must be base64.

mod anim;
mod data;
#[cfg(test)]
mod tests;

use crate::source::DEFAULT_FPS;
use crate::{Camera, LoadOptions, Mesh, Scene, SceneError, SceneInfo, Timeline};
use anim::{Channel, Interp, Target};
use geom::{Mat4, Quat, Vec3};
use gltf::accessor::Dimensions;
use gltf::mesh::Mode;
use gltf::Semantic;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Most vertices or triangles a scene may have after instancing (about 33 million): a
/// small file can reference one large mesh from many nodes, so this bounds memory
/// (about 0.4 GB of positions and as much of triangles).
const MAX_ELEMENTS: usize = 1 << 25;

/// Vertex count from which a primitive is skinned in parallel.
const PARALLEL_VERTICES: usize = 16 * 1024;

/// Required extensions that cannot change positions or topology (appearance only), or
/// that the accessor reader handles (`KHR_mesh_quantization`: integer positions). Any
/// other required extension (Draco, meshopt, GPU instancing, unknown ones) is refused
/// rather than read wrongly.
fn harmless_extension(name: &str) -> bool {
    name == "KHR_mesh_quantization"
        || [
            "KHR_materials_",
            "KHR_texture_",
            "KHR_lights_",
            "EXT_texture_",
        ]
        .iter()
        .any(|p| name.starts_with(p))
}

/// A node's rest (non-animated) local transform.
#[derive(Clone, Copy, Debug)]
struct Rest {
    t: Vec3,
    r: Quat,
    s: Vec3,
    /// The node's matrix, used as is when the node is not animated.
    matrix: Option<Mat4>,
}

/// Skin weights of one vertex range: vertex `v` has influences
/// `infl[start[v]..start[v + 1]]` as (joint slot in the skin, weight), weights summing to 1.
#[derive(Debug, Default)]
struct Influences {
    start: Vec<u32>,
    infl: Vec<(u32, f32)>,
    /// Largest joint slot used (to check against each skin using this primitive).
    max_joint: Option<u32>,
}

/// A decoded mesh primitive in its own space (shared by every node instancing it).
#[derive(Debug)]
struct Prim {
    positions: Vec<Vec3>,
    /// Triangles indexing `positions`.
    triangles: Vec<[u32; 3]>,
    material: u32,
    /// POSITION deltas of each morph target (empty when the target has none).
    targets: Vec<Vec<Vec3>>,
    influences: Option<Influences>,
}

/// A primitive placed by a node.
#[derive(Debug)]
struct Instance {
    node: usize,
    prim: Arc<Prim>,
    /// Skin index when the node has a skin and the primitive has weights.
    skin: Option<usize>,
    /// First vertex of this instance in the output mesh.
    vertex_base: usize,
    /// Morph weights when not animated (node weights, else mesh weights, else zeros).
    weights: Vec<f32>,
}

/// A decoded skin.
#[derive(Debug)]
struct Skin {
    joints: Vec<usize>,
    inverse_bind: Vec<Mat4>,
}

/// A loaded glTF scene: decoded geometry plus the selected animation.
pub struct GltfScene {
    info: SceneInfo,
    path: PathBuf,
    /// Parent of each node.
    parents: Vec<Option<usize>>,
    /// Every node, parents before children.
    order: Vec<usize>,
    rest: Vec<Rest>,
    /// True for nodes that some TRS channel of the selected animation targets.
    animated: Vec<bool>,
    skins: Vec<Skin>,
    instances: Vec<Instance>,
    channels: Vec<Channel>,
    vertex_count: usize,
    triangles: Vec<[u32; 3]>,
    material_ids: Vec<u32>,
    material_names: Vec<String>,
    skipped_primitives: usize,
    animation_names: Vec<String>,
}

/// Opens a `.gltf` or `.glb` file as an animated scene.
pub fn open(spec: &str, path: &Path, opts: &LoadOptions) -> Result<Box<dyn Scene>, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    opts.report(0, bytes.len() as u64);
    let mut scene = parse(&bytes, path, path.parent(), opts)?;
    scene.info.source = spec.to_string();
    opts.report(bytes.len() as u64, bytes.len() as u64);
    Ok(Box::new(scene))
}

/// Parses glTF JSON or GLB `bytes`; `path` names the file in errors and `base_dir` resolves
/// external buffers (`None`: only embedded buffers are allowed). Never panics on any input:
/// this is the fuzzing entry point.
pub fn parse(
    bytes: &[u8],
    path: &Path,
    base_dir: Option<&Path>,
    opts: &LoadOptions,
) -> Result<GltfScene, SceneError> {
    let bad = |m: String| SceneError::malformed(path, m);
    let (json, bin) = if data::is_glb(bytes) {
        let glb = data::parse_glb(bytes).map_err(bad)?;
        (glb.json, glb.bin)
    } else {
        // A UTF-8 byte order mark is not JSON; the spec lets readers ignore it.
        (bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes), None)
    };
    let root: gltf::json::Root = gltf::json::deserialize::from_slice(json)
        .map_err(|e| bad(format!("invalid glTF JSON: {e}")))?;
    if let Some(x) = root
        .extensions_required
        .iter()
        .find(|x| !harmless_extension(x))
    {
        return Err(SceneError::unsupported(
            path,
            format!("required extension {x}"),
        ));
    }
    validate(&root).map_err(|m| bad(format!("invalid glTF: {m}")))?;
    let doc = gltf::Document::from_json_without_validation(root);
    let buffers = data::resolve_buffers(&doc, bin, base_dir, path)?;
    let reader = data::Reader::new(path, &buffers);
    Loader {
        path,
        doc: &doc,
        rd: reader,
    }
    .load(opts)
}

/// The `gltf` crate's validation (every index in range, every enum known), which the
/// crate's accessors rely on to not panic, except that missing POSITION `min`/`max` bounds
/// are tolerated (many exporters omit them and they are not needed here), and required
/// extensions are judged by [`harmless_extension`] instead.
fn validate(root: &gltf::json::Root) -> Result<(), String> {
    use gltf::json::validation::{Checked, Error, Validate};
    // gltf-json 1.4's primitive hook indexes `accessors` with the POSITION index before
    // that index is checked, and panics on a bad one: check it first.
    for (mi, m) in root.meshes.iter().enumerate() {
        for (pi, p) in m.primitives.iter().enumerate() {
            let pos = p
                .attributes
                .get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if let Some(i) = pos.filter(|i| i.value() >= root.accessors.len()) {
                return Err(format!(
                    "meshes[{mi}].primitives[{pi}]: POSITION accessor {} does not exist",
                    i.value()
                ));
            }
        }
    }
    let mut errors = Vec::new();
    root.validate(root, gltf::json::Path::new, &mut |path, e| {
        let path = path();
        let p = path.as_str();
        let bounds = matches!(e, Error::Missing) && (p.ends_with(".min") || p.ends_with(".max"));
        // Required extensions were checked by `harmless_extension` already.
        let ext = p.starts_with("extensionsRequired");
        if !bounds && !ext && errors.len() < 4 {
            errors.push(format!("{p}: {e}"));
        }
    });
    if errors.is_empty() {
        Ok(())
    } else {
        Err(errors.join("; "))
    }
}

struct Loader<'a> {
    path: &'a Path,
    doc: &'a gltf::Document,
    rd: data::Reader<'a>,
}

fn finite_mat(m: &Mat4) -> bool {
    m.to_cols_array().iter().all(|x| x.is_finite())
}

impl Loader<'_> {
    fn err(&self, m: impl Into<String>) -> SceneError {
        SceneError::malformed(self.path, m)
    }

    fn load(&self, opts: &LoadOptions) -> Result<GltfScene, SceneError> {
        let n = self.doc.nodes().len();
        let (parents, order) = self.hierarchy(n)?;
        let rest = self.rest_transforms()?;
        let skins = self.skins()?;
        let roots = self.scene_roots(&parents)?;
        let (material_names, default_material) = self.materials();

        // Instances: every primitive of every mesh node reachable from the roots, in
        // depth-first order (children in their listed order) so triangle order is fixed.
        let mut prim_cache: Vec<Vec<Option<Arc<Prim>>>> = self
            .doc
            .meshes()
            .map(|m| vec![None; m.primitives().len()])
            .collect();
        let mut instances = Vec::new();
        let mut triangles = Vec::new();
        let mut material_ids = Vec::new();
        let mut vertex_count = 0usize;
        let mut skipped = 0usize;
        let nodes: Vec<gltf::Node> = self.doc.nodes().collect();
        let mut stack: Vec<usize> = roots.iter().rev().copied().collect();
        while let Some(ni) = stack.pop() {
            let node = &nodes[ni];
            stack.extend(
                node.children()
                    .map(|c| c.index())
                    .collect::<Vec<_>>()
                    .into_iter()
                    .rev(),
            );
            let Some(mesh) = node.mesh() else { continue };
            for p in mesh.primitives() {
                let prim = match &prim_cache[mesh.index()][p.index()] {
                    Some(pr) => pr.clone(),
                    None => match self.primitive(&mesh, &p, default_material)? {
                        Some(pr) => {
                            let pr = Arc::new(pr);
                            prim_cache[mesh.index()][p.index()] = Some(pr.clone());
                            pr
                        }
                        None => {
                            skipped += 1;
                            continue;
                        }
                    },
                };
                let skin = match (node.skin(), &prim.influences) {
                    (Some(s), Some(inf)) => {
                        let joints = skins[s.index()].joints.len();
                        if let Some(m) = inf.max_joint.filter(|&m| m as usize >= joints) {
                            return Err(self.err(format!(
                                "mesh {} primitive {}: joint index {m} out of range of skin {} ({joints} joints)",
                                mesh.index(),
                                p.index(),
                                s.index()
                            )));
                        }
                        Some(s.index())
                    }
                    _ => None,
                };
                let ntargets = prim.targets.len();
                let mut weights = node
                    .weights()
                    .or(mesh.weights())
                    .map(|w| w.to_vec())
                    .unwrap_or_default();
                weights.resize(ntargets, 0.0);
                if weights.iter().any(|w| !w.is_finite()) {
                    return Err(self.err(format!("node {ni}: non-finite morph weights")));
                }
                if vertex_count + prim.positions.len() > MAX_ELEMENTS
                    || triangles.len() + prim.triangles.len() > MAX_ELEMENTS
                {
                    return Err(self.err(format!(
                        "scene too large after instancing (limit {MAX_ELEMENTS} vertices or triangles)"
                    )));
                }
                let base = vertex_count as u32;
                triangles.extend(prim.triangles.iter().map(|t| t.map(|i| i + base)));
                material_ids.extend(std::iter::repeat_n(prim.material, prim.triangles.len()));
                instances.push(Instance {
                    node: ni,
                    prim: prim.clone(),
                    skin,
                    vertex_base: vertex_count,
                    weights,
                });
                vertex_count += prim.positions.len();
            }
        }

        let animation_names: Vec<String> = self
            .doc
            .animations()
            .map(|a| {
                a.name()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("animation {}", a.index()))
            })
            .collect();
        let channels = match self.select_animation(opts, &animation_names)? {
            Some(a) => self.channels(a, &instances)?,
            None => Vec::new(),
        };
        let mut animated = vec![false; n];
        for c in &channels {
            if c.target != Target::Weights {
                animated[c.node] = true;
            }
        }
        let duration_s = channels
            .iter()
            .filter_map(|c| c.times.last().copied())
            .fold(0.0f32, f32::max);
        let fps = opts
            .fps
            .filter(|f| f.is_finite() && *f > 0.0)
            .unwrap_or(DEFAULT_FPS);
        let name = self
            .path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut scene = GltfScene {
            info: SceneInfo {
                name,
                source: self.path.display().to_string(),
                format: "gltf".into(),
                timeline: Timeline { duration_s, fps },
                stable_topology: true,
                dropped_triangles: 0,
                camera: Camera::framing(&geom::Aabb::EMPTY),
            },
            path: self.path.to_path_buf(),
            parents,
            order,
            rest,
            animated,
            skins,
            instances,
            channels,
            vertex_count,
            triangles,
            material_ids,
            material_names,
            skipped_primitives: skipped,
            animation_names,
        };
        let first = scene.mesh_at(0.0)?;
        scene.info.camera = Camera::framing(&first.bounds());
        Ok(scene)
    }

    /// Parent of every node and a parents-first order; rejects nodes with two parents and
    /// cycles.
    fn hierarchy(&self, n: usize) -> Result<(Vec<Option<usize>>, Vec<usize>), SceneError> {
        let mut parents = vec![None; n];
        for node in self.doc.nodes() {
            for c in node.children() {
                let ci = c.index();
                if ci == node.index() {
                    return Err(self.err(format!("node {ci} is its own child")));
                }
                if let Some(p) = parents[ci] {
                    return Err(self.err(format!(
                        "node {ci} has two parents ({p} and {}): the node graph must be a forest",
                        node.index()
                    )));
                }
                parents[ci] = Some(node.index());
            }
        }
        // Breadth-first from parentless nodes; with single parents, any node not reached
        // lies on a cycle.
        let children: Vec<Vec<usize>> = self
            .doc
            .nodes()
            .map(|nd| nd.children().map(|c| c.index()).collect())
            .collect();
        let mut order: Vec<usize> = (0..n).filter(|&i| parents[i].is_none()).collect();
        let mut head = 0;
        while head < order.len() {
            let i = order[head];
            head += 1;
            order.extend_from_slice(&children[i]);
        }
        if order.len() != n {
            let mut seen = vec![false; n];
            order.iter().for_each(|&i| seen[i] = true);
            let bad = seen.iter().position(|s| !s).unwrap_or(0);
            return Err(self.err(format!("node graph has a cycle through node {bad}")));
        }
        Ok((parents, order))
    }

    fn rest_transforms(&self) -> Result<Vec<Rest>, SceneError> {
        self.doc
            .nodes()
            .map(|node| {
                let r = match node.transform() {
                    gltf::scene::Transform::Matrix { matrix } => {
                        let m = Mat4::from_cols_array_2d(&matrix);
                        if !finite_mat(&m) {
                            return Err(
                                self.err(format!("node {}: non-finite matrix", node.index()))
                            );
                        }
                        let (s, r, t) = m.to_scale_rotation_translation();
                        Rest {
                            t,
                            r,
                            s,
                            matrix: Some(m),
                        }
                    }
                    gltf::scene::Transform::Decomposed {
                        translation,
                        rotation,
                        scale,
                    } => {
                        let (t, r, s) = (
                            Vec3::from(translation),
                            Quat::from_array(rotation),
                            Vec3::from(scale),
                        );
                        if !(t.is_finite() && r.is_finite() && s.is_finite()) || r.length() < 1e-6 {
                            return Err(self.err(format!(
                                "node {}: non-finite or zero-length rotation TRS",
                                node.index()
                            )));
                        }
                        Rest {
                            t,
                            r: r.normalize(),
                            s,
                            matrix: None,
                        }
                    }
                };
                Ok(r)
            })
            .collect()
    }

    fn skins(&self) -> Result<Vec<Skin>, SceneError> {
        self.doc
            .skins()
            .map(|skin| {
                let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
                let inverse_bind = match skin.inverse_bind_matrices() {
                    None => vec![Mat4::IDENTITY; joints.len()],
                    Some(acc) => {
                        let what = format!("skin {} inverseBindMatrices", skin.index());
                        let (v, _) = self.rd.f32s(&what, &acc, &[Dimensions::Mat4])?;
                        if v.len() / 16 < joints.len() {
                            return Err(self.err(format!(
                                "{what}: {} matrices for {} joints",
                                v.len() / 16,
                                joints.len()
                            )));
                        }
                        let m: Vec<Mat4> = v.chunks_exact(16).map(Mat4::from_cols_slice).collect();
                        if !m.iter().all(finite_mat) {
                            return Err(self.err(format!("{what}: non-finite matrix")));
                        }
                        m
                    }
                };
                Ok(Skin {
                    joints,
                    inverse_bind,
                })
            })
            .collect()
    }

    fn scene_roots(&self, parents: &[Option<usize>]) -> Result<Vec<usize>, SceneError> {
        let scene = self
            .doc
            .default_scene()
            .or_else(|| self.doc.scenes().next());
        match scene {
            Some(s) => {
                let roots: Vec<usize> = s.nodes().map(|n| n.index()).collect();
                if let Some(&r) = roots.iter().find(|&&r| parents[r].is_some()) {
                    return Err(
                        self.err(format!("scene {}: root node {r} has a parent", s.index()))
                    );
                }
                let mut seen = vec![false; parents.len()];
                for &r in &roots {
                    if std::mem::replace(&mut seen[r], true) {
                        return Err(
                            self.err(format!("scene {}: root node {r} listed twice", s.index()))
                        );
                    }
                }
                Ok(roots)
            }
            None => Ok((0..parents.len())
                .filter(|&i| parents[i].is_none())
                .collect()),
        }
    }

    /// Material names and the id of the extra `default` material (used only if needed).
    fn materials(&self) -> (Vec<String>, u32) {
        let mut names: Vec<String> = self
            .doc
            .materials()
            .map(|m| {
                m.name()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("material {}", m.index().unwrap_or(0)))
            })
            .collect();
        let default = names.len() as u32;
        let needs_default = self
            .doc
            .meshes()
            .flat_map(|m| m.primitives())
            .filter(|p| {
                matches!(
                    p.mode(),
                    Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
                )
            })
            .any(|p| p.material().index().is_none());
        if needs_default {
            names.push("default".into());
        }
        (names, default)
    }

    /// Decodes one primitive, or `None` for a point or line primitive.
    fn primitive(
        &self,
        mesh: &gltf::Mesh,
        p: &gltf::Primitive,
        default_material: u32,
    ) -> Result<Option<Prim>, SceneError> {
        let what = format!("mesh {} primitive {}", mesh.index(), p.index());
        let mode = p.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Ok(None);
        }
        let pos_acc = p
            .get(&Semantic::Positions)
            .ok_or_else(|| self.err(format!("{what}: no POSITION attribute")))?;
        let positions = self.vec3s(&format!("{what} POSITION"), &pos_acc)?;
        let nv = positions.len();
        let idx: Vec<u32> = match p.indices() {
            Some(acc) => {
                self.rd
                    .uints(&format!("{what} indices"), &acc, &[Dimensions::Scalar])?
                    .0
            }
            None => (0..nv as u32).collect(),
        };
        if let Some((k, &i)) = idx.iter().enumerate().find(|(_, &i)| i as usize >= nv) {
            return Err(self.err(format!(
                "{what}: index {k} is {i}, out of range ({nv} vertices)"
            )));
        }
        let triangles = to_triangles(mode, &idx);
        let material = p
            .material()
            .index()
            .map(|m| m as u32)
            .unwrap_or(default_material);

        let mut targets = Vec::new();
        for (ti, t) in p.morph_targets().enumerate() {
            let deltas = match t.positions() {
                Some(acc) => {
                    let d = self.vec3s(&format!("{what} morph target {ti} POSITION"), &acc)?;
                    if d.len() != nv {
                        return Err(self.err(format!(
                            "{what} morph target {ti}: {} deltas for {nv} vertices",
                            d.len()
                        )));
                    }
                    d
                }
                None => Vec::new(),
            };
            targets.push(deltas);
        }
        let influences = self.influences(&what, p, nv)?;
        Ok(Some(Prim {
            positions,
            triangles,
            material,
            targets,
            influences,
        }))
    }

    fn vec3s(&self, what: &str, acc: &gltf::Accessor) -> Result<Vec<Vec3>, SceneError> {
        let (v, _) = self.rd.floats(what, acc, &[Dimensions::Vec3])?;
        let out: Vec<Vec3> = v.chunks_exact(3).map(Vec3::from_slice).collect();
        if let Some(i) = out.iter().position(|p| !p.is_finite()) {
            return Err(self.err(format!("{what}: element {i} is not finite ({})", out[i])));
        }
        Ok(out)
    }

    /// JOINTS_n / WEIGHTS_n sets 0 and 1, zero weights dropped and the rest normalized.
    fn influences(
        &self,
        what: &str,
        p: &gltf::Primitive,
        nv: usize,
    ) -> Result<Option<Influences>, SceneError> {
        let mut sets = Vec::new();
        for set in 0..2u32 {
            let (Some(j), Some(w)) = (
                p.get(&Semantic::Joints(set)),
                p.get(&Semantic::Weights(set)),
            ) else {
                continue;
            };
            let (jv, _) =
                self.rd
                    .uints(&format!("{what} JOINTS_{set}"), &j, &[Dimensions::Vec4])?;
            let (wv, _) =
                self.rd
                    .floats(&format!("{what} WEIGHTS_{set}"), &w, &[Dimensions::Vec4])?;
            if jv.len() != nv * 4 || wv.len() != nv * 4 {
                return Err(self.err(format!(
                    "{what}: JOINTS_{set}/WEIGHTS_{set} counts ({}, {}) differ from POSITION ({nv})",
                    jv.len() / 4,
                    wv.len() / 4
                )));
            }
            if let Some(x) = wv.iter().find(|x| !x.is_finite() || **x < 0.0) {
                return Err(self.err(format!(
                    "{what}: WEIGHTS_{set} holds {x} (must be finite, >= 0)"
                )));
            }
            sets.push((jv, wv));
        }
        if sets.is_empty() {
            return Ok(None);
        }
        let mut inf = Influences {
            start: Vec::with_capacity(nv + 1),
            infl: Vec::new(),
            max_joint: None,
        };
        for v in 0..nv {
            inf.start.push(inf.infl.len() as u32);
            let first = inf.infl.len();
            for (jv, wv) in &sets {
                for k in 0..4 {
                    let w = wv[v * 4 + k];
                    if w > 0.0 {
                        let j = jv[v * 4 + k];
                        inf.max_joint = Some(inf.max_joint.map_or(j, |m| m.max(j)));
                        inf.infl.push((j, w));
                    }
                }
            }
            let sum: f32 = inf.infl[first..].iter().map(|x| x.1).sum();
            if sum > 0.0 && sum.is_finite() {
                inf.infl[first..].iter_mut().for_each(|x| x.1 /= sum);
            } else {
                // No weight: the vertex follows the node rigidly (see module docs).
                inf.infl.truncate(first);
            }
        }
        inf.start.push(inf.infl.len() as u32);
        Ok(Some(inf))
    }

    /// The animation `opts.animation` names (index or name), else the first; `None` when
    /// the file has none and none was asked for.
    fn select_animation(
        &self,
        opts: &LoadOptions,
        names: &[String],
    ) -> Result<Option<gltf::Animation<'_>>, SceneError> {
        let Some(want) = opts.animation.as_deref() else {
            return Ok(self.doc.animations().next());
        };
        let found = self
            .doc
            .animations()
            .find(|a| a.name() == Some(want))
            .or_else(|| {
                want.parse::<usize>()
                    .ok()
                    .and_then(|i| self.doc.animations().nth(i))
            });
        found.map(Some).ok_or_else(|| {
            let list = if names.is_empty() {
                "the file has no animations".to_string()
            } else {
                let l: Vec<String> = names
                    .iter()
                    .enumerate()
                    .map(|(i, n)| format!("{i}: '{n}'"))
                    .collect();
                format!("available: {}", l.join(", "))
            };
            SceneError::unsupported(self.path, format!("no animation '{want}' ({list})"))
        })
    }

    fn channels(
        &self,
        anim: gltf::Animation,
        instances: &[Instance],
    ) -> Result<Vec<Channel>, SceneError> {
        let ai = anim.index();
        // Channel targets are read from the JSON: the crate does not validate them.
        let json = &self.doc.as_json().animations[ai];
        let samplers: Vec<gltf::animation::Sampler> = anim.samplers().collect();
        let n_nodes = self.doc.nodes().len();
        // Morph target count of each node's mesh (linear in instances, not per channel).
        let mut targets_of_node: Vec<Option<usize>> = vec![None; n_nodes];
        for i in instances {
            let t = &mut targets_of_node[i.node];
            *t = Some(t.unwrap_or(0).max(i.prim.targets.len()));
        }
        let mut out = Vec::new();
        for (ci, ch) in json.channels.iter().enumerate() {
            let what = format!("animation {ai} channel {ci}");
            let node = ch.target.node.value();
            if node >= n_nodes {
                return Err(self.err(format!("{what}: target node {node} does not exist")));
            }
            use gltf::json::animation::Property as P;
            use gltf::json::validation::Checked;
            let target = match ch.target.path {
                Checked::Valid(P::Translation) => Target::Translation,
                Checked::Valid(P::Rotation) => Target::Rotation,
                Checked::Valid(P::Scale) => Target::Scale,
                Checked::Valid(P::MorphTargetWeights) => Target::Weights,
                Checked::Invalid => return Err(self.err(format!("{what}: unknown target path"))),
            };
            let sampler = samplers.get(ch.sampler.value()).ok_or_else(|| {
                self.err(format!(
                    "{what}: sampler {} does not exist",
                    ch.sampler.value()
                ))
            })?;
            let interp = match sampler.interpolation() {
                gltf::animation::Interpolation::Step => Interp::Step,
                gltf::animation::Interpolation::Linear => Interp::Linear,
                gltf::animation::Interpolation::CubicSpline => Interp::Cubic,
            };
            let (times, _) = self.rd.f32s(
                &format!("{what} input"),
                &sampler.input(),
                &[Dimensions::Scalar],
            )?;
            if times.is_empty() {
                return Err(self.err(format!("{what}: no keyframes")));
            }
            if let Some(k) = times.iter().position(|t| !t.is_finite()) {
                return Err(self.err(format!("{what}: key time {k} is not finite ({})", times[k])));
            }
            if let Some(k) = times.windows(2).position(|w| w[1] < w[0]) {
                return Err(self.err(format!("{what}: key times decrease at key {}", k + 1)));
            }
            let dims: &[Dimensions] = match target {
                Target::Translation | Target::Scale => &[Dimensions::Vec3],
                Target::Rotation => &[Dimensions::Vec4],
                Target::Weights => &[Dimensions::Scalar],
            };
            let (values, comps) =
                self.rd
                    .floats(&format!("{what} output"), &sampler.output(), dims)?;
            let groups = times.len() * if interp == Interp::Cubic { 3 } else { 1 };
            let width = if target == Target::Weights {
                targets_of_node[node].unwrap_or(values.len() / groups)
            } else {
                comps
            };
            if values.len() != groups * width {
                return Err(self.err(format!(
                    "{what}: {} output values for {} keys of {width} floats{}",
                    values.len(),
                    times.len(),
                    if interp == Interp::Cubic {
                        " (x3 for CUBICSPLINE)"
                    } else {
                        ""
                    }
                )));
            }
            if let Some(v) = values.iter().find(|v| !v.is_finite()) {
                return Err(self.err(format!("{what}: non-finite output value {v}")));
            }
            if width == 0 {
                continue;
            }
            out.push(Channel {
                node,
                target,
                interp,
                times,
                values,
                width,
            });
        }
        Ok(out)
    }
}

/// Triangles of an index list in the given mode (glTF 3.7.2.1 vertex orders).
fn to_triangles(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i], idx[i + 1], idx[i + 2]]
                } else {
                    [idx[i], idx[i + 2], idx[i + 1]]
                }
            })
            .collect(),
        Mode::TriangleFan => (1..idx.len().saturating_sub(1))
            .map(|i| [idx[i], idx[i + 1], idx[0]])
            .collect(),
        _ => idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
    }
}

impl GltfScene {
    /// Number of point and line primitives skipped (they have no triangles).
    pub fn skipped_primitives(&self) -> usize {
        self.skipped_primitives
    }

    /// Names of the file's animations (`animation N` when unnamed), in file order.
    pub fn animation_names(&self) -> &[String] {
        &self.animation_names
    }

    /// Global transform of every node at time `t`, and morph weights of animated nodes.
    fn pose(&self, t: f32) -> (Vec<Mat4>, Vec<Option<Vec<f32>>>) {
        let n = self.rest.len();
        let mut trs: Vec<(Vec3, Quat, Vec3)> = self.rest.iter().map(|r| (r.t, r.r, r.s)).collect();
        let mut weights: Vec<Option<Vec<f32>>> = vec![None; n];
        let mut buf = [0.0f32; 4];
        for c in &self.channels {
            match c.target {
                Target::Weights => {
                    let w = weights[c.node].get_or_insert_with(Vec::new);
                    w.resize(c.width, 0.0);
                    c.sample(t, w);
                }
                Target::Translation => {
                    c.sample(t, &mut buf[..3]);
                    trs[c.node].0 = Vec3::from_slice(&buf);
                }
                Target::Rotation => {
                    c.sample(t, &mut buf);
                    trs[c.node].1 = Quat::from_array(buf);
                }
                Target::Scale => {
                    c.sample(t, &mut buf[..3]);
                    trs[c.node].2 = Vec3::from_slice(&buf);
                }
            }
        }
        let mut global = vec![Mat4::IDENTITY; n];
        for &i in &self.order {
            let local = match self.rest[i].matrix {
                Some(m) if !self.animated[i] => m,
                _ => Mat4::from_scale_rotation_translation(trs[i].2, trs[i].1, trs[i].0),
            };
            global[i] = match self.parents[i] {
                Some(p) => global[p] * local,
                None => local,
            };
        }
        (global, weights)
    }
}

/// Positions of one instance: morphed, then skinned or placed by the node.
fn place(
    inst: &Instance,
    global: &[Mat4],
    joints: Option<&[Mat4]>,
    weights: &[f32],
    out: &mut [Vec3],
) {
    let prim = &*inst.prim;
    let node_m = global[inst.node];
    let active: Vec<(usize, f32)> = weights
        .iter()
        .enumerate()
        .filter(|(k, w)| **w != 0.0 && prim.targets.get(*k).is_some_and(|d| !d.is_empty()))
        .map(|(k, w)| (k, *w))
        .collect();
    let vertex = |v: usize| -> Vec3 {
        let mut p = prim.positions[v];
        for &(k, w) in &active {
            p += prim.targets[k][v] * w;
        }
        match (joints, &prim.influences) {
            (Some(jm), Some(inf)) => {
                let r = inf.start[v] as usize..inf.start[v + 1] as usize;
                if r.is_empty() {
                    return node_m.transform_point3(p);
                }
                let mut m = Mat4::ZERO;
                for &(j, w) in &inf.infl[r] {
                    m += jm[j as usize] * w;
                }
                m.transform_point3(p)
            }
            _ => node_m.transform_point3(p),
        }
    };
    if out.len() >= PARALLEL_VERTICES {
        out.par_chunks_mut(4096).enumerate().for_each(|(c, chunk)| {
            for (i, o) in chunk.iter_mut().enumerate() {
                *o = vertex(c * 4096 + i);
            }
        });
    } else {
        for (v, o) in out.iter_mut().enumerate() {
            *o = vertex(v);
        }
    }
}

impl Scene for GltfScene {
    fn info(&self) -> &SceneInfo {
        &self.info
    }

    fn mesh_at(&self, t: f32) -> Result<Mesh, SceneError> {
        let t = self.info.timeline.clamp(t);
        let (global, anim_weights) = self.pose(t);
        let joint_mats: Vec<Vec<Mat4>> = self
            .skins
            .iter()
            .map(|s| {
                s.joints
                    .iter()
                    .zip(&s.inverse_bind)
                    .map(|(&j, ib)| global[j] * *ib)
                    .collect()
            })
            .collect();
        let mut positions = vec![Vec3::ZERO; self.vertex_count];
        for inst in &self.instances {
            let n = inst.prim.positions.len();
            let out = &mut positions[inst.vertex_base..inst.vertex_base + n];
            let weights = anim_weights[inst.node].as_deref().unwrap_or(&inst.weights);
            let joints = inst.skin.map(|s| joint_mats[s].as_slice());
            place(inst, &global, joints, weights, out);
        }
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(SceneError::malformed(
                &self.path,
                format!("vertex {i} is not finite at t = {t} s ({})", positions[i]),
            ));
        }
        Ok(Mesh {
            positions,
            triangles: self.triangles.clone(),
            material_ids: self.material_ids.clone(),
            material_names: self.material_names.clone(),
        })
    }
}
