//! Rendering: primary rays, diffuse path tracing and shadow rays over image tiles, in
//! parallel, with per-bounce counters and an optional traversal log.
//!
//! - `primary`: one closest-hit ray through each pixel centre, shaded with a headlight
//!   (`albedo * (0.15 + 0.85 |cos|)`).
//! - `diffuse`: path tracing with one sample per pixel ([P2] §6.4 uses 3 bounces, [P4]
//!   §3.2 four): the primary ray, then up to `bounces` cosine-weighted diffuse bounces, no
//!   next event estimation; a bounce that escapes sees a white sky (radiance 1 straight
//!   up, 0.4 straight down: [`sky`], so that surfaces facing up are lighter), and each
//!   bounce multiplies the throughput by the surface albedo (a primary ray that misses
//!   sees the dim backdrop of the other modes, so that the lit scene stands out). Secondary rays are traced
//!   when the preceding ray of their path is complete, as in [P4] §3.2.
//! - `shadow`: primary rays plus one any-hit (occlusion) ray per hit towards a fixed
//!   directional light.
//!
//! Sampling is seeded per pixel (see [`crate::sampling`]), so the image, the depth buffer,
//! the counters and the log are the same for any thread count. Because the closest hit
//! does not depend on the tree (see [`crate::Hit`]), every tree of either width gives the
//! same image and depth buffer; only the counters differ.
//!
//! Tiles of [`TILE`] x [`TILE`] pixels are rendered in parallel in batches; each batch's
//! log is written in tile order before the next batch starts, so a log never has to be
//! held in memory whole. Log order: tile by tile (row-major over tiles), pixel by pixel
//! (row-major in the tile), and each pixel's rays in path order.

use crate::accel::{Hit, TraversalStack, Traverse};
use crate::camera::PinholeCamera;
use crate::log::{LogEncoder, LogWriter};
use crate::observer::{Observer, Query};
use crate::sampling::{cosine_hemisphere, offset_origin, Pcg32};
use crate::stats::RayStats;
use crate::TraceError;
use geom::{Ray, Triangle, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

pub use crate::log::LogRays as RayKind;

/// Tile side in pixels.
pub const TILE: u32 = 16;
/// Largest bounce limit accepted.
pub const MAX_BOUNCES: u32 = 64;
/// Tiles rendered per batch per worker thread (bounds the memory of a batch's log).
const TILES_PER_THREAD: usize = 8;

/// What to render.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Image width in pixels (default 1280).
    pub width: u32,
    /// Image height in pixels (default 720).
    pub height: u32,
    /// Ray kind.
    pub rays: RayKind,
    /// Diffuse bounces after the primary hit (diffuse rendering only).
    pub bounces: u32,
    /// Sampling seed.
    pub seed: u64,
    /// The camera.
    pub camera: scene::Camera,
}

impl RenderSettings {
    /// 1280x720 primary rays with `camera` ([P4] §3.2's resolution), 4 bounces for
    /// diffuse ([P4] §3.2), seed 1.
    pub fn new(camera: scene::Camera) -> Self {
        Self {
            width: 1280,
            height: 720,
            rays: RayKind::Primary,
            bounces: 4,
            seed: 1,
            camera,
        }
    }
}

/// Counters of a render.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RenderStats {
    /// Counters of each bounce: index 0 primary rays, 1 the first bounce (or the shadow
    /// rays), and so on.
    pub per_bounce: Vec<RayStats>,
    /// Counters over all rays.
    pub total: RayStats,
    /// Wall time of tracing and shading (tree building excluded).
    pub seconds: f64,
    /// Rays per second, in millions.
    pub mrays_per_s: f64,
    /// Worker threads.
    pub threads: usize,
}

/// A rendered image and its buffers, row-major with row 0 at the top.
#[derive(Clone, Debug)]
pub struct Render {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Linear RGB radiance per pixel.
    pub color: Vec<[f32; 3]>,
    /// Distance `t` of the primary hit along the unit-length camera ray (+inf for a miss).
    pub depth: Vec<f32>,
    /// Primitive id of the primary hit (`u32::MAX` for a miss).
    pub prim: Vec<u32>,
    /// Inner-node visits of all the pixel's rays.
    pub node_visits: Vec<u32>,
    /// Triangle tests of all the pixel's rays.
    pub tri_tests: Vec<u32>,
    /// Counters.
    pub stats: RenderStats,
}

/// What shading needs of the scene: each primitive's triangle and material.
#[derive(Clone, Copy, Debug)]
pub struct Shading<'a> {
    /// Triangles by primitive id.
    pub triangles: &'a [Triangle],
    /// Material id per primitive (empty: all 0).
    pub material_ids: &'a [u32],
}

impl Shading<'_> {
    fn albedo(&self, prim: u32) -> Vec3 {
        let m = self.material_ids.get(prim as usize).copied().unwrap_or(0);
        material_color(m)
    }
}

/// A soft colour per material id (a fixed hash, so the same scene looks the same).
pub fn material_color(material: u32) -> Vec3 {
    if material == 0 {
        return Vec3::splat(0.75);
    }
    let h = crate::sampling::mix64(material as u64);
    let c = |s: u32| 0.45 + 0.45 * (((h >> s) & 0xFF) as f32 / 255.0);
    Vec3::new(c(0), c(8), c(16))
}

/// Direction towards the light of `shadow` renders (from above, front right, relative to
/// the world axes).
pub fn sun_direction() -> Vec3 {
    Vec3::new(0.4, 1.0, 0.6).normalize()
}

/// An [`Observer`] that one tile's rays report to, told each ray's identity first. The
/// renderer makes one per tile and hands them back in tile order.
pub trait RayObserver: Observer + Send {
    /// The next ray traced is bounce `bounce` (0 = primary) of pixel `pixel`'s path.
    #[inline(always)]
    fn set_ray(&mut self, pixel: u32, bounce: u8) {
        let _ = (pixel, bounce);
    }
}

impl RayObserver for () {}

impl RayObserver for LogEncoder {
    fn set_ray(&mut self, pixel: u32, bounce: u8) {
        LogEncoder::set_ray(self, pixel, bounce)
    }
}

/// A [`RayObserver`] that records every ray traced (the ray sets of benchmarks).
#[derive(Clone, Debug, Default)]
pub struct RayRecorder {
    /// The rays, in order, with their bounce number and query.
    pub rays: Vec<(Ray, u8, Query)>,
    bounce: u8,
}

impl Observer for RayRecorder {
    fn begin(&mut self, ray: &Ray, query: Query) {
        self.rays.push((*ray, self.bounce, query));
    }
}

impl RayObserver for RayRecorder {
    fn set_ray(&mut self, _pixel: u32, bounce: u8) {
        self.bounce = bounce;
    }
}

/// Renders `settings` with `accel` and returns every ray traced, in log order, with its
/// bounce and query (a [`RayRecorder`] per tile): the ray set of a render, to trace the
/// very same rays through other trees.
pub fn record_rays<T: Traverse>(
    accel: &T,
    shading: Shading<'_>,
    settings: &RenderSettings,
) -> Result<Vec<(Ray, u8, Query)>, TraceError> {
    let mut rays = Vec::new();
    render_observed(
        accel,
        shading,
        settings,
        RayRecorder::default,
        |r| {
            rays.extend(r.rays);
            Ok(())
        },
        None,
    )?;
    Ok(rays)
}

/// Everything one tile produces.
struct TileOut<O> {
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    color: Vec<[f32; 3]>,
    depth: Vec<f32>,
    prim: Vec<u32>,
    nodes: Vec<u32>,
    tris: Vec<u32>,
    per_bounce: Vec<RayStats>,
    obs: O,
}

/// The geometric normal of a hit, facing against the ray direction `d` (zero for a
/// degenerate triangle, which has no orientation and ends a diffuse path).
pub fn facing_normal(tri: &Triangle, d: Vec3) -> Vec3 {
    let n = tri.normal().normalize_or_zero();
    if n.dot(d) > 0.0 {
        -n
    } else {
        n
    }
}

/// The hit point from barycentrics (closer to the surface than `o + t d`).
fn hit_point(tri: &Triangle, h: &Hit) -> Vec3 {
    tri.v[0] * h.bary[0] + tri.v[1] * h.bary[1] + tri.v[2] * h.bary[2]
}

struct Tracer<'a, T: Traverse> {
    accel: &'a T,
    shading: Shading<'a>,
    settings: &'a RenderSettings,
    camera: PinholeCamera,
}

impl<T: Traverse> Tracer<'_, T> {
    /// Traces one ray, reporting it to `obs`.
    #[allow(clippy::too_many_arguments)]
    fn trace<O: RayObserver>(
        &self,
        ray: &Ray,
        query: Query,
        bounce: usize,
        pixel: u32,
        stack: &mut TraversalStack,
        per_bounce: &mut [RayStats],
        counts: &mut (u32, u32),
        obs: &mut O,
    ) -> Option<Hit> {
        let s = &mut per_bounce[bounce];
        let (n0, t0) = (s.node_visits, s.tri_tests);
        obs.set_ray(pixel, bounce as u8);
        let hit = self.accel.trace_observed(ray, query, stack, s, obs);
        counts.0 = counts.0.saturating_add((s.node_visits - n0) as u32);
        counts.1 = counts.1.saturating_add((s.tri_tests - t0) as u32);
        hit
    }

    fn tile<O: RayObserver>(&self, tx: u32, ty: u32, obs: O) -> TileOut<O> {
        let st = self.settings;
        let (x0, y0) = (tx * TILE, ty * TILE);
        let (w, h) = (TILE.min(st.width - x0), TILE.min(st.height - y0));
        let n = (w * h) as usize;
        let mut out = TileOut {
            x0,
            y0,
            w,
            h,
            color: Vec::with_capacity(n),
            depth: Vec::with_capacity(n),
            prim: Vec::with_capacity(n),
            nodes: Vec::with_capacity(n),
            tris: Vec::with_capacity(n),
            per_bounce: vec![RayStats::default(); 1 + bounce_slots(st) as usize],
            obs,
        };
        let mut stack = TraversalStack::new();
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                let pixel = y * st.width + x;
                let mut counts = (0u32, 0u32);
                let ray = self.camera.pixel_ray(x, y);
                let first = self.trace(
                    &ray,
                    Query::Closest,
                    0,
                    pixel,
                    &mut stack,
                    &mut out.per_bounce,
                    &mut counts,
                    &mut out.obs,
                );
                out.depth.push(first.map_or(f32::INFINITY, |h| h.t));
                out.prim.push(first.map_or(u32::MAX, |h| h.prim));
                let color = match (st.rays, first) {
                    (_, None) => self.miss_color(ray.dir),
                    (RayKind::Primary, Some(h)) => {
                        let tri = &self.shading.triangles[h.prim as usize];
                        let cos = facing_normal(tri, ray.dir).dot(-ray.dir).abs();
                        self.shading.albedo(h.prim) * (0.15 + 0.85 * cos)
                    }
                    (RayKind::Shadow, Some(h)) => {
                        let tri = &self.shading.triangles[h.prim as usize];
                        let n = facing_normal(tri, ray.dir);
                        let l = sun_direction();
                        let lambert = n.dot(l).max(0.0);
                        let lit = lambert > 0.0 && {
                            let o = offset_origin(hit_point(tri, &h), n);
                            let shadow = Ray::new(o, l);
                            self.trace(
                                &shadow,
                                Query::Any,
                                1,
                                pixel,
                                &mut stack,
                                &mut out.per_bounce,
                                &mut counts,
                                &mut out.obs,
                            )
                            .is_none()
                        };
                        self.shading.albedo(h.prim) * (0.2 + 0.8 * lambert * lit as u32 as f32)
                    }
                    (RayKind::Diffuse, Some(h)) => self.path(
                        ray,
                        h,
                        pixel,
                        &mut stack,
                        &mut out.per_bounce,
                        &mut counts,
                        &mut out.obs,
                    ),
                };
                out.color.push(color.to_array());
                out.nodes.push(counts.0);
                out.tris.push(counts.1);
            }
        }
        out
    }

    /// Colour of a primary ray that hits nothing: a dim backdrop, lighter towards the top,
    /// in every mode (diffuse paths are lit by a white sky, but a white backdrop would
    /// hide a lit figure).
    fn miss_color(&self, d: Vec3) -> Vec3 {
        Vec3::splat(0.05 + 0.1 * (0.5 + 0.5 * d.y))
    }

    /// A diffuse path after its primary hit `first`.
    #[allow(clippy::too_many_arguments)]
    fn path<O: RayObserver>(
        &self,
        mut ray: Ray,
        first: Hit,
        pixel: u32,
        stack: &mut TraversalStack,
        per_bounce: &mut [RayStats],
        counts: &mut (u32, u32),
        obs: &mut O,
    ) -> Vec3 {
        let mut rng = Pcg32::new(self.settings.seed, pixel as u64);
        let mut throughput = Vec3::ONE;
        let mut hit = first;
        for bounce in 1..=self.settings.bounces as usize {
            let tri = &self.shading.triangles[hit.prim as usize];
            let n = facing_normal(tri, ray.dir);
            if n == Vec3::ZERO {
                return Vec3::ZERO; // a degenerate triangle has no orientation
            }
            throughput *= self.shading.albedo(hit.prim);
            ray = bounce_ray(tri, n, &hit, &mut rng);
            match self.trace(
                &ray,
                Query::Closest,
                bounce,
                pixel,
                stack,
                per_bounce,
                counts,
                obs,
            ) {
                None => return throughput * sky(ray.dir),
                Some(h) => hit = h,
            }
        }
        Vec3::ZERO
    }
}

/// Radiance of the sky that lights diffuse paths, seen in direction `d` (unit): white, 1
/// straight up (+y) and 0.4 straight down.
pub fn sky(d: Vec3) -> f32 {
    0.7 + 0.3 * d.y.clamp(-1.0, 1.0)
}

/// The next ray of a diffuse path: from the hit `hit` on `tri` (whose normal facing the
/// incoming ray is `n`, non-zero), a cosine-weighted direction drawn from `rng`. The one
/// rule for diffuse bounces, shared by the renderer and the accelerator model's ray
/// generator (`sim::rtunit`), so both trace the very same rays.
pub fn bounce_ray(tri: &Triangle, n: Vec3, hit: &Hit, rng: &mut Pcg32) -> Ray {
    let dir = cosine_hemisphere(n, rng.next_f32(), rng.next_f32());
    Ray::new(offset_origin(hit_point(tri, hit), n), dir)
}

/// Bounce counter slots after the primary ray: `bounces` for diffuse, 1 for shadow.
fn bounce_slots(s: &RenderSettings) -> u32 {
    match s.rays {
        RayKind::Primary => 0,
        RayKind::Shadow => 1,
        RayKind::Diffuse => s.bounces,
    }
}

/// Renders `settings` with `accel` (built over `shading.triangles`). With `log`, every
/// ray's traversal is appended to it (the caller finishes the writer). `progress` is
/// called with (tiles done, tiles in all) after each batch.
pub fn render<T: Traverse>(
    accel: &T,
    shading: Shading<'_>,
    settings: &RenderSettings,
    log: Option<&mut LogWriter>,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> Result<Render, TraceError> {
    match log {
        Some(w) => render_observed(
            accel,
            shading,
            settings,
            || LogEncoder::new(accel.width()),
            |mut e| {
                let (bytes, rays) = e.take();
                w.write_chunk(&bytes, rays)
            },
            progress,
        ),
        None => render_observed(accel, shading, settings, || (), |_| Ok(()), progress),
    }
}

/// [`render`] with an observer per tile: `make` creates each tile's observer, and `sink`
/// receives them in tile order (row-major over tiles) after each batch.
pub fn render_observed<T, O, M, S>(
    accel: &T,
    shading: Shading<'_>,
    settings: &RenderSettings,
    make: M,
    mut sink: S,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> Result<Render, TraceError>
where
    T: Traverse,
    O: RayObserver,
    M: Fn() -> O + Sync,
    S: FnMut(O) -> Result<(), TraceError>,
{
    let camera = PinholeCamera::new(&settings.camera, settings.width, settings.height)?;
    if settings.bounces > MAX_BOUNCES {
        return Err(TraceError::Config(format!(
            "{} bounces is more than the limit of {MAX_BOUNCES}",
            settings.bounces
        )));
    }
    if shading.triangles.len() != accel.source_triangles() {
        return Err(TraceError::Config(format!(
            "the tree was built over {} triangles but {} were given for shading",
            accel.source_triangles(),
            shading.triangles.len()
        )));
    }
    if !shading.material_ids.is_empty() && shading.material_ids.len() != shading.triangles.len() {
        return Err(TraceError::Config(format!(
            "{} material ids for {} triangles",
            shading.material_ids.len(),
            shading.triangles.len()
        )));
    }
    let tracer = Tracer {
        accel,
        shading,
        settings,
        camera,
    };
    let (tiles_x, tiles_y) = (
        settings.width.div_ceil(TILE),
        settings.height.div_ceil(TILE),
    );
    let tiles: Vec<(u32, u32)> = (0..tiles_y)
        .flat_map(|y| (0..tiles_x).map(move |x| (x, y)))
        .collect();
    let pixels = settings.width as usize * settings.height as usize;
    let mut img = Render {
        width: settings.width,
        height: settings.height,
        color: vec![[0.0; 3]; pixels],
        depth: vec![f32::INFINITY; pixels],
        prim: vec![u32::MAX; pixels],
        node_visits: vec![0; pixels],
        tri_tests: vec![0; pixels],
        stats: RenderStats {
            per_bounce: vec![RayStats::default(); 1 + bounce_slots(settings) as usize],
            threads: rayon::current_num_threads(),
            ..Default::default()
        },
    };
    let batch = TILES_PER_THREAD * rayon::current_num_threads().max(1);
    let start = Instant::now();
    let mut done = 0u64;
    for group in tiles.chunks(batch) {
        let outs: Vec<TileOut<O>> = group
            .par_iter()
            .map(|&(tx, ty)| tracer.tile(tx, ty, make()))
            .collect();
        for t in outs {
            for row in 0..t.h {
                let src = (row * t.w) as usize..((row + 1) * t.w) as usize;
                let dst = ((t.y0 + row) * settings.width + t.x0) as usize;
                let dst = dst..dst + t.w as usize;
                img.color[dst.clone()].copy_from_slice(&t.color[src.clone()]);
                img.depth[dst.clone()].copy_from_slice(&t.depth[src.clone()]);
                img.prim[dst.clone()].copy_from_slice(&t.prim[src.clone()]);
                img.node_visits[dst.clone()].copy_from_slice(&t.nodes[src.clone()]);
                img.tri_tests[dst].copy_from_slice(&t.tris[src]);
            }
            for (a, b) in img.stats.per_bounce.iter_mut().zip(&t.per_bounce) {
                a.add(b);
            }
            sink(t.obs)?;
        }
        done += group.len() as u64;
        if let Some(p) = progress {
            p(done, tiles.len() as u64);
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    for b in &img.stats.per_bounce {
        img.stats.total.add(b);
    }
    img.stats.seconds = seconds;
    img.stats.mrays_per_s = if seconds > 0.0 {
        img.stats.total.rays as f64 / seconds / 1e6
    } else {
        0.0
    };
    Ok(img)
}
