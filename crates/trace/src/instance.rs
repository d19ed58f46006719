//! Two-level instancing: a top-level tree over instances, each a bottom-level triangle
//! tree ([`BottomLevel`], any [`Accel`] format) placed in the world by an affine
//! [`Transform`]. A ray is traced through the top level, and at each instance it reaches,
//! it is moved into the instance's object space and traced through its bottom level.
//!
//! The top level is a [`CustomAccel`] whose primitives are the instances (one callback
//! does the bottom-level trace), so its traversal, tie rule and counters are those of
//! custom primitives. Object-space rays keep the parametrization of the world ray
//! (`o' = M⁻¹ o`, `d' = M⁻¹ d`, unnormalized), so a hit's `t` is its world-space distance
//! along the world ray, and the closest hit is the smallest `t` over all instances, ties
//! going to the smaller instance id and then the smaller primitive id. Up to the rounding
//! of the ray transform, that is the closest hit among the world-space triangles.
//!
//! Animation: [`InstanceAccel::set_transforms`] (moved instances) and
//! [`InstanceAccel::refit_bottom`] (a deformed mesh) refit the top level in place; after
//! large motion [`InstanceAccel::rebuild`] builds it anew.
//!
//! # Example
//!
//! ```
//! use geom::{Mat4, Quat, Ray, Triangle, Vec3};
//! use trace::instance::{BottomLevel, Instance, InstanceAccel, InstanceStack, Transform};
//! use trace::{Accel, Bvh2Accel, KernelOptions, RayStats};
//!
//! // One triangle in the plane z = 0, instanced twice.
//! let tris = [Triangle::new(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0))];
//! let tree = bvh::SweepSahBuilder::default().build(&bvh::triangle_aabbs(&tris))?;
//! let accel = Accel::Bvh2(Bvh2Accel::new(tree, &tris, KernelOptions::default())?);
//! let bottom = BottomLevel::new(accel, &tris)?;
//! let place = |z: f32, scale: f32| {
//!     let m = Mat4::from_scale_rotation_translation(Vec3::splat(scale), Quat::IDENTITY, Vec3::new(0.0, 0.0, z));
//!     Transform::from_mat4(m)
//! };
//! let instances = vec![
//!     Instance { bottom: 0, transform: place(-5.0, 1.0)? },
//!     Instance { bottom: 0, transform: place(-3.0, 2.0)? },
//! ];
//! let mut scene = InstanceAccel::new(vec![bottom], instances)?;
//! let (mut stack, mut stats) = (InstanceStack::new(), RayStats::default());
//! let ray = Ray::new(Vec3::ZERO, -Vec3::Z);
//! let hit = scene.closest_hit(&ray, &mut stack, &mut stats).unwrap();
//! assert_eq!((hit.instance, hit.prim, hit.t), (1, 0, 3.0)); // world-space distance
//!
//! // Animate: move instance 1 behind instance 0; the top level is refitted.
//! scene.set_transforms(&[place(-5.0, 1.0)?, place(-8.0, 2.0)?])?;
//! let hit = scene.closest_hit(&ray, &mut stack, &mut stats).unwrap();
//! assert_eq!((hit.instance, hit.t), (0, 5.0));
//! assert!(scene.any_hit(&ray, &mut stack, &mut stats).is_some());
//!
//! // A singular transform is an error, not a panic.
//! assert!(Transform::new([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]).is_err());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::accel::{TraversalStack, Traverse};
use crate::custom::CustomAccel;
use crate::observer::Query;
use crate::stats::RayStats;
use crate::{Accel, TraceError};
use geom::{Aabb, Mat4, Ray, Triangle, Vec3};

/// An affine transform from object to world space, `p_world = M p_object + t`, stored as
/// the 3x4 matrix `[M | t]` (rows) together with its inverse. Constructed only through
/// checks: both are finite and `M` is far from singular, so a transformed ray never
/// becomes NaN through the transform itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Object to world: rows of `[M | t]`.
    to_world: [[f32; 4]; 3],
    /// World to object: rows of `[M⁻¹ | -M⁻¹ t]`.
    to_object: [[f32; 4]; 3],
}

/// Smallest accepted `|det M| / (|row 0| |row 1| |row 2|)`: the volume of the unit cube's
/// image relative to the largest it could have with those rows. Below it, `M` is singular
/// at single precision (its rows are parallel to within about one ulp).
const MIN_RELATIVE_DET: f64 = f32::EPSILON as f64;

/// Relative padding of an instance's world box: transforming the corners, and rays into
/// object space, rounds at `f32` precision; `2^-16` of the box's magnitude covers both
/// many times over, so that the top level never culls an instance whose bottom level a
/// ray hits. Padding only ever costs work.
const WORLD_BOX_SLACK: f32 = 1.0 / 65536.0;

fn bad(msg: String) -> TraceError {
    TraceError::BadTransform(msg)
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform = Transform {
        to_world: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        to_object: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
    };

    /// The transform of the 3x4 matrix `rows` (`[M | t]`, row by row). Fails when an
    /// entry is not finite or `M` is singular (the inverse is computed in double
    /// precision and must be finite in single precision).
    pub fn new(rows: [[f32; 4]; 3]) -> Result<Self, TraceError> {
        if rows.iter().flatten().any(|x| !x.is_finite()) {
            return Err(bad(format!("non-finite matrix entry in {rows:?}")));
        }
        let m: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| rows[r][c] as f64));
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        // The inverse's columns are the cross products of the rows over the determinant.
        let cols = [cross(m[1], m[2]), cross(m[2], m[0]), cross(m[0], m[1])];
        let det = dot(m[0], cols[0]);
        let norms: f64 = m.iter().map(|r| dot(*r, *r).sqrt()).product();
        // (False for a NaN determinant too.)
        let invertible = det != 0.0 && det.abs() >= MIN_RELATIVE_DET * norms;
        if !invertible {
            return Err(bad(format!(
                "singular matrix (determinant {det:e}) in {rows:?}"
            )));
        }
        let t = [rows[0][3] as f64, rows[1][3] as f64, rows[2][3] as f64];
        let mut to_object = [[0f32; 4]; 3];
        for (r, row) in to_object.iter_mut().enumerate() {
            let inv_row = [cols[0][r] / det, cols[1][r] / det, cols[2][r] / det];
            row[..3].copy_from_slice(&inv_row.map(|x| x as f32));
            row[3] = -dot(inv_row, t) as f32;
        }
        if to_object.iter().flatten().any(|x| !x.is_finite()) {
            return Err(bad(format!(
                "the inverse of {rows:?} is not finite in single precision"
            )));
        }
        Ok(Self {
            to_world: rows,
            to_object,
        })
    }

    /// The transform of a 4x4 matrix (column vectors, as `glam` composes them) whose
    /// last row is `0 0 0 1`. Fails on a projective matrix and as [`Transform::new`].
    pub fn from_mat4(m: Mat4) -> Result<Self, TraceError> {
        if m.row(3) != geom::Vec4::W {
            return Err(bad(format!(
                "not affine: the last row is {:?}, not (0, 0, 0, 1)",
                m.row(3)
            )));
        }
        Self::new(std::array::from_fn(|r| m.row(r).to_array()))
    }

    /// The object-to-world matrix `[M | t]`, row by row.
    pub fn matrix(&self) -> [[f32; 4]; 3] {
        self.to_world
    }

    /// The world-to-object matrix `[M⁻¹ | -M⁻¹ t]`, row by row.
    pub fn inverse_matrix(&self) -> [[f32; 4]; 3] {
        self.to_object
    }

    /// An object-space point in world space.
    #[inline]
    pub fn point_to_world(&self, p: Vec3) -> Vec3 {
        apply(&self.to_world, p, 1.0)
    }

    /// A world-space point in object space.
    #[inline]
    pub fn point_to_object(&self, p: Vec3) -> Vec3 {
        apply(&self.to_object, p, 1.0)
    }

    /// A world-space direction in object space (not renormalized).
    #[inline]
    pub fn vector_to_object(&self, v: Vec3) -> Vec3 {
        apply(&self.to_object, v, 0.0)
    }

    /// An object-space triangle in world space.
    pub fn triangle_to_world(&self, tri: &Triangle) -> Triangle {
        Triangle {
            v: tri.v.map(|p| self.point_to_world(p)),
        }
    }

    /// `ray` in object space, with the same `t` range: a point at distance `t` along the
    /// object-space ray is the image of the point at `t` along `ray`.
    #[inline]
    pub fn ray_to_object(&self, ray: &Ray) -> Ray {
        Ray::with_range(
            self.point_to_object(ray.origin),
            self.vector_to_object(ray.dir),
            ray.t_min,
            ray.t_max,
        )
    }

    /// A world-space box around the object-space box `b` (its eight corners transformed,
    /// padded by 2^-16 of its magnitude, see `WORLD_BOX_SLACK`); empty for an empty box.
    pub fn aabb_to_world(&self, b: &Aabb) -> Aabb {
        if b.is_empty() {
            return Aabb::EMPTY;
        }
        let world = Aabb::from_points((0..8).map(|i| {
            let pick = |bit: usize, lo: f32, hi: f32| if i >> bit & 1 == 0 { lo } else { hi };
            self.point_to_world(Vec3::new(
                pick(0, b.min.x, b.max.x),
                pick(1, b.min.y, b.max.y),
                pick(2, b.min.z, b.max.z),
            ))
        }));
        let magnitude = world.min.abs().max(world.max.abs()).max_element();
        let pad = Vec3::splat(magnitude * WORLD_BOX_SLACK);
        Aabb::new(world.min - pad, world.max + pad)
    }
}

/// `[M | t] (p, w)`: the point (`w = 1`) or vector (`w = 0`) `p` through the 3x4 matrix `m`.
#[inline(always)]
fn apply(m: &[[f32; 4]; 3], p: Vec3, w: f32) -> Vec3 {
    let row = |r: &[f32; 4]| r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3] * w;
    Vec3::new(row(&m[0]), row(&m[1]), row(&m[2]))
}

/// A bottom-level tree: a prepared triangle tree and the object-space box of its
/// triangles (what the top level places in the world).
#[derive(Clone, Debug)]
pub struct BottomLevel {
    accel: Accel,
    bounds: Aabb,
}

/// The box of `triangles`, which must be finite.
fn triangles_box(triangles: &[Triangle]) -> Result<Aabb, TraceError> {
    let b = triangles.iter().fold(Aabb::EMPTY, |b, t| b.union(t.aabb()));
    if !b.is_empty() && !b.is_finite() {
        return Err(TraceError::Config(
            "a bottom level's triangles have non-finite coordinates".into(),
        ));
    }
    Ok(b)
}

impl BottomLevel {
    /// `accel`, prepared over `triangles` (the same list).
    pub fn new(accel: Accel, triangles: &[Triangle]) -> Result<Self, TraceError> {
        if accel.source_triangles() != triangles.len() {
            return Err(TraceError::Config(format!(
                "the bottom level was prepared over {} triangles, {} given",
                accel.source_triangles(),
                triangles.len()
            )));
        }
        Ok(Self {
            bounds: triangles_box(triangles)?,
            accel,
        })
    }

    /// The prepared tree.
    pub fn accel(&self) -> &Accel {
        &self.accel
    }

    /// The object-space box of its triangles.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Refits in place to `triangles` (moved vertices, same topology; see
    /// [`Accel::refit`]). Returns false, changing nothing, for a CBVH.
    pub fn refit(&mut self, triangles: &[Triangle]) -> Result<bool, TraceError> {
        let bounds = triangles_box(triangles)?;
        let done = self.accel.refit(triangles)?;
        if done {
            self.bounds = bounds;
        }
        Ok(done)
    }
}

/// One placement of a bottom level in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index of the bottom level in the list given to [`InstanceAccel::new`].
    pub bottom: u32,
    /// Object to world.
    pub transform: Transform,
}

/// A hit on an instanced triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceHit {
    /// World-space distance along the ray, in units of the ray direction.
    pub t: f32,
    /// The instance (its index in the instance list).
    pub instance: u32,
    /// The triangle: its index in the list its bottom level was prepared over.
    pub prim: u32,
    /// Barycentric weights of the triangle's three vertices.
    pub bary: [f32; 3],
}

/// The two traversal stacks of an instanced trace (top level, bottom level), reused
/// across rays.
#[derive(Clone, Debug, Default)]
pub struct InstanceStack {
    top: TraversalStack,
    bottom: TraversalStack,
}

impl InstanceStack {
    /// Empty stacks.
    pub fn new() -> Self {
        Self {
            top: TraversalStack::new(),
            bottom: TraversalStack::new(),
        }
    }
}

/// Instances of bottom-level trees under one top-level tree.
#[derive(Clone, Debug)]
pub struct InstanceAccel {
    bottoms: Vec<BottomLevel>,
    instances: Vec<Instance>,
    top: CustomAccel,
}

impl InstanceAccel {
    /// The top level over `instances` of `bottoms` (a binary SAH tree over the instances'
    /// world boxes, one instance per leaf). Fails when an instance names a bottom level
    /// that does not exist.
    pub fn new(bottoms: Vec<BottomLevel>, instances: Vec<Instance>) -> Result<Self, TraceError> {
        if let Some((i, inst)) = instances
            .iter()
            .enumerate()
            .find(|(_, inst)| inst.bottom as usize >= bottoms.len())
        {
            return Err(TraceError::Config(format!(
                "instance {i} names bottom level {}, but there are {}",
                inst.bottom,
                bottoms.len()
            )));
        }
        let mut accel = Self {
            bottoms,
            instances,
            top: CustomAccel::new(bvh::Bvh2::empty())?,
        };
        accel.rebuild()?;
        Ok(accel)
    }

    /// The instances.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// The bottom levels.
    pub fn bottoms(&self) -> &[BottomLevel] {
        &self.bottoms
    }

    /// The top-level tree.
    pub fn top(&self) -> &CustomAccel {
        &self.top
    }

    /// World boxes of the instances. An instance of an empty bottom level gets the point
    /// box at its origin, which keeps the builders' input finite (it is never hit: its
    /// bottom level has nothing to hit).
    fn world_boxes(&self) -> Vec<Aabb> {
        self.instances
            .iter()
            .map(|inst| {
                let b = self.bottoms[inst.bottom as usize].bounds;
                if b.is_empty() {
                    Aabb::from_point(inst.transform.point_to_world(Vec3::ZERO))
                } else {
                    inst.transform.aabb_to_world(&b)
                }
            })
            .collect()
    }

    /// Builds the top level anew over the current world boxes (after motion large
    /// enough that refitting has loosened the tree).
    pub fn rebuild(&mut self) -> Result<(), TraceError> {
        let builder = bvh::SweepSahBuilder {
            max_leaf_size: 1,
            ..Default::default()
        };
        let tree = builder
            .build(&self.world_boxes())
            .map_err(|e| TraceError::Config(format!("cannot build the top level: {e}")))?;
        self.top = CustomAccel::new(tree)?;
        Ok(())
    }

    /// Refits the top level to the current world boxes.
    fn refit_top(&mut self) -> Result<(), TraceError> {
        let boxes = self.world_boxes();
        self.top.refit(&boxes)
    }

    /// Sets every instance's transform (`transforms[i]` for instance `i`, animated
    /// instances) and refits the top level in place. Fails, changing nothing, on a list
    /// of another length.
    pub fn set_transforms(&mut self, transforms: &[Transform]) -> Result<(), TraceError> {
        if transforms.len() != self.instances.len() {
            return Err(TraceError::Config(format!(
                "{} transforms given for {} instances",
                transforms.len(),
                self.instances.len()
            )));
        }
        for (inst, t) in self.instances.iter_mut().zip(transforms) {
            inst.transform = *t;
        }
        self.refit_top()
    }

    /// Refits bottom level `bottom` to `triangles` (a deformed mesh, see
    /// [`BottomLevel::refit`]) and the top level to its new box. Returns false, changing
    /// nothing, for a CBVH.
    pub fn refit_bottom(
        &mut self,
        bottom: usize,
        triangles: &[Triangle],
    ) -> Result<bool, TraceError> {
        let count = self.bottoms.len();
        let b = self.bottoms.get_mut(bottom).ok_or_else(|| {
            TraceError::Config(format!("no bottom level {bottom} (there are {count})"))
        })?;
        if !b.refit(triangles)? {
            return Ok(false);
        }
        self.refit_top()?;
        Ok(true)
    }

    /// The closest hit along `ray`. Adds the counters of the top-level ray and of every
    /// bottom-level trace to `stats` (`rays` and `hits` count the world ray only).
    pub fn closest_hit(
        &self,
        ray: &Ray,
        stack: &mut InstanceStack,
        stats: &mut RayStats,
    ) -> Option<InstanceHit> {
        self.trace(ray, Query::Closest, stack, stats)
    }

    /// The first hit found along `ray` (occlusion).
    pub fn any_hit(
        &self,
        ray: &Ray,
        stack: &mut InstanceStack,
        stats: &mut RayStats,
    ) -> Option<InstanceHit> {
        self.trace(ray, Query::Any, stack, stats)
    }

    /// Traces `ray` for `query` through both levels.
    pub fn trace(
        &self,
        ray: &Ray,
        query: Query,
        stack: &mut InstanceStack,
        stats: &mut RayStats,
    ) -> Option<InstanceHit> {
        let InstanceStack { top, bottom } = stack;
        let mut inner = RayStats::default();
        let mut enter = |instance: u32, ray: &Ray, t_max: f32| {
            let inst = self.instances.get(instance as usize)?;
            let b = self.bottoms.get(inst.bottom as usize)?;
            let mut r = inst.transform.ray_to_object(ray);
            r.t_max = t_max;
            b.accel
                .trace_observed(&r, query, bottom, &mut inner, &mut ())
                .map(|h| (h.t, (h.prim, h.bary)))
        };
        let hit = self.top.trace(ray, query, top, stats, &mut enter);
        inner.rays = 0;
        inner.hits = 0;
        stats.add(&inner);
        hit.map(|h| InstanceHit {
            t: h.t,
            instance: h.prim,
            prim: h.data.0,
            bary: h.data.1,
        })
    }
}
