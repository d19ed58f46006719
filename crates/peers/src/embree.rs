//! Adapter for Embree 3's generic BVH builder (`rtcBuildBVH`), feature `embree`.
//!
//! Quality `LOW` is Embree's Morton-code builder and `MEDIUM` its binned SAH builder (the
//! peers the issue names). Embree builds the tree through our callbacks: nodes and leaves
//! are allocated in Embree's thread-local allocator (so allocation cost is Embree's, as
//! in its own use), inner nodes record two child pointers and boxes, leaves the `primID`s
//! of their primitives. After the build the pointer tree is converted to Arbor's
//! [`Bvh2`](bvh::Bvh2) and the Embree BVH (with its memory) is released.
//!
//! SAH weights: Embree's defaults are `traversalCost = intersectionCost = 1`; this adapter
//! passes the thesis's ratio (1.2 : 1, \[P2\] §6.2) by default so that Embree optimizes the
//! same cost that Arbor's builders and the reported SAH use. `maxDepth` is 64, not the
//! header's default of 32: with 32, `MEDIUM` fails (`RTC_ERROR_UNKNOWN`) on 1000 points on
//! a line with leaves of 1, whose zero-area boxes make every SAH split cost the same and
//! the tree deeper than 32 (a test covers it).

use crate::convert::{to_bvh2, PeerNode};
use crate::embree_ffi::*;
use crate::{check_input, BuildProbe, NoProbe, PeerBuild, PeerError};
use geom::{Aabb, Vec3};
use std::ffi::{c_void, CString};
use std::time::Instant;

/// Embree's build quality, i.e. which of its builders runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EmbreeQuality {
    /// `RTC_BUILD_QUALITY_LOW`: the Morton-code builder.
    #[default]
    Low,
    /// `RTC_BUILD_QUALITY_MEDIUM`: the binned SAH builder.
    Medium,
}

/// Configuration of an Embree build (binary tree).
#[derive(Clone, Debug, PartialEq)]
pub struct EmbreeBuilder {
    /// Which Embree builder runs.
    pub quality: EmbreeQuality,
    /// Largest leaf (1..=32, Embree's `RTC_BUILD_MAX_PRIMITIVES_PER_LEAF`).
    pub max_leaf_size: u32,
    /// SAH cost of a traversal step (Embree's `traversalCost`).
    pub traversal_cost: f32,
    /// SAH cost of a primitive intersection (Embree's `intersectionCost`).
    pub intersection_cost: f32,
}

impl Default for EmbreeBuilder {
    fn default() -> Self {
        Self {
            quality: EmbreeQuality::Low,
            max_leaf_size: 8,
            traversal_cost: 1.2,
            intersection_cost: 1.0,
        }
    }
}

/// An Embree device (its worker threads); create once and reuse across builds, so that
/// thread start-up is not part of a measured build.
///
/// The device counts the memory Embree allocates itself (its build buffers and the node
/// memory of its allocator) through `rtcSetDeviceMemoryMonitorFunction`: see
/// [`EmbreeDevice::reset_memory_peak`] and [`EmbreeDevice::memory_peak_bytes`]. Memory
/// that Rust allocates is not part of it.
#[derive(Debug)]
pub struct EmbreeDevice {
    raw: RtcDevice,
    /// Embree's live and peak bytes, updated by [`memory_monitor`]; boxed so that its
    /// address, handed to Embree, stays fixed.
    memory: Box<MemoryCount>,
}

/// Live and peak bytes that Embree reported to its memory monitor.
#[derive(Debug, Default)]
struct MemoryCount {
    live: std::sync::atomic::AtomicI64,
    peak: std::sync::atomic::AtomicI64,
}

/// Embree's memory monitor callback: `bytes` > 0 before an allocation, < 0 after a free.
/// Never refuses an allocation.
unsafe extern "C" fn memory_monitor(user: *mut c_void, bytes: isize, _post: bool) -> bool {
    use std::sync::atomic::Ordering::Relaxed;
    // SAFETY: `user` is the `MemoryCount` of the device, which outlives the device.
    let m = &*(user as *const MemoryCount);
    let now = m.live.fetch_add(bytes as i64, Relaxed) + bytes as i64;
    m.peak.fetch_max(now, Relaxed);
    true
}

// Embree devices are thread-safe objects (its API may be called from any thread).
unsafe impl Send for EmbreeDevice {}
unsafe impl Sync for EmbreeDevice {}

impl EmbreeDevice {
    /// A device with `threads` worker threads (0: Embree's default, all hardware threads).
    pub fn new(threads: usize) -> Result<Self, PeerError> {
        let config = CString::new(if threads == 0 {
            String::new()
        } else {
            format!("threads={threads}")
        })
        .expect("no NUL in a formatted number");
        // SAFETY: `config` is a valid NUL-terminated string that outlives the call.
        let raw = unsafe { rtcNewDevice(config.as_ptr()) };
        if raw.is_null() {
            // SAFETY: a NULL device asks for the error of the failed device creation.
            let code = unsafe { rtcGetDeviceError(std::ptr::null_mut()) };
            return Err(embree_error(format!(
                "rtcNewDevice failed ({})",
                error_name(code)
            )));
        }
        let memory = Box::<MemoryCount>::default();
        // SAFETY: `raw` is a live device; the callback's user pointer is the boxed counter,
        // which is dropped only after `Drop::drop` has released the device.
        unsafe {
            rtcSetDeviceMemoryMonitorFunction(
                raw,
                Some(memory_monitor),
                &*memory as *const MemoryCount as *mut c_void,
            )
        };
        Ok(Self { raw, memory })
    }

    /// Sets the peak of Embree's own allocations to what is allocated now.
    pub fn reset_memory_peak(&self) {
        use std::sync::atomic::Ordering::Relaxed;
        self.memory
            .peak
            .store(self.memory.live.load(Relaxed), Relaxed);
    }

    /// Embree's own allocated bytes at their peak since the last
    /// [`EmbreeDevice::reset_memory_peak`], above what was allocated at that reset.
    pub fn memory_peak_bytes(&self) -> usize {
        use std::sync::atomic::Ordering::Relaxed;
        // Only called between builds, when live is what it was at the reset (or lower).
        (self.memory.peak.load(Relaxed) - self.memory.live.load(Relaxed)).max(0) as usize
    }

    /// The raw device handle, for the other Embree adapters of this crate.
    pub(crate) fn raw(&self) -> RtcDevice {
        self.raw
    }
}

impl Drop for EmbreeDevice {
    fn drop(&mut self) {
        // SAFETY: `raw` is a live device owned by this value.
        unsafe { rtcReleaseDevice(self.raw) }
    }
}

fn embree_error(message: String) -> PeerError {
    PeerError::Peer {
        peer: "embree",
        message,
    }
}

fn error_name(code: RtcError) -> &'static str {
    match code {
        0 => "RTC_ERROR_NONE",
        1 => "RTC_ERROR_UNKNOWN",
        2 => "RTC_ERROR_INVALID_ARGUMENT",
        3 => "RTC_ERROR_INVALID_OPERATION",
        4 => "RTC_ERROR_OUT_OF_MEMORY",
        5 => "RTC_ERROR_UNSUPPORTED_CPU",
        6 => "RTC_ERROR_CANCELLED",
        _ => "unknown error code",
    }
}

/// Tag (first word) of an inner node.
const INNER: u32 = 1;
/// Tag (first word) of a leaf.
const LEAF: u32 = 2;

/// An inner node in Embree's allocator.
#[repr(C)]
struct InnerNode {
    tag: u32,
    children: [*const u8; 2],
    bounds: [Aabb; 2],
}

/// Header of a leaf in Embree's allocator; `count` `u32` primitive ids follow it.
#[repr(C)]
struct LeafHeader {
    tag: u32,
    count: u32,
}

unsafe extern "C" fn create_node(
    alloc: RtcThreadLocalAllocator,
    _child_count: u32,
    _user: *mut c_void,
) -> *mut c_void {
    let p = rtcThreadLocalAlloc(
        alloc,
        std::mem::size_of::<InnerNode>(),
        std::mem::align_of::<InnerNode>(),
    ) as *mut InnerNode;
    if !p.is_null() {
        p.write(InnerNode {
            tag: INNER,
            children: [std::ptr::null(); 2],
            bounds: [Aabb::EMPTY; 2],
        });
    }
    p as *mut c_void
}

unsafe extern "C" fn set_node_children(
    node: *mut c_void,
    children: *mut *mut c_void,
    child_count: u32,
    _user: *mut c_void,
) {
    let node = &mut *(node as *mut InnerNode);
    // More than two children cannot happen with maxBranchingFactor 2; were it to, the
    // missing primitives make the conversion fail instead of a silent wrong tree.
    for i in 0..(child_count as usize).min(2) {
        node.children[i] = *children.add(i) as *const u8;
    }
}

unsafe extern "C" fn set_node_bounds(
    node: *mut c_void,
    bounds: *mut *const RtcBounds,
    child_count: u32,
    _user: *mut c_void,
) {
    let node = &mut *(node as *mut InnerNode);
    for i in 0..(child_count as usize).min(2) {
        let b = &**bounds.add(i);
        node.bounds[i] = Aabb::new(
            Vec3::new(b.lower_x, b.lower_y, b.lower_z),
            Vec3::new(b.upper_x, b.upper_y, b.upper_z),
        );
    }
}

unsafe extern "C" fn create_leaf(
    alloc: RtcThreadLocalAllocator,
    prims: *const RtcBuildPrimitive,
    count: usize,
    _user: *mut c_void,
) -> *mut c_void {
    let bytes = std::mem::size_of::<LeafHeader>() + 4 * count;
    let p = rtcThreadLocalAlloc(alloc, bytes, std::mem::align_of::<LeafHeader>()) as *mut u8;
    if p.is_null() {
        return p as *mut c_void;
    }
    (p as *mut LeafHeader).write(LeafHeader {
        tag: LEAF,
        count: count as u32,
    });
    let ids = p.add(std::mem::size_of::<LeafHeader>()) as *mut u32;
    for i in 0..count {
        ids.add(i).write((*prims.add(i)).prim_id);
    }
    p as *mut c_void
}

/// An Embree BVH handle, released on drop (which frees every node of the tree).
struct BvhHandle(RtcBvh);

impl Drop for BvhHandle {
    fn drop(&mut self) {
        // SAFETY: a live BVH owned by this value.
        unsafe { rtcReleaseBVH(self.0) }
    }
}

impl EmbreeBuilder {
    /// Builds over `aabbs` on a new device of `threads` threads (0: all). For repeated
    /// measurements use [`EmbreeBuilder::build_on`] with one device.
    pub fn build(&self, aabbs: &[Aabb], threads: usize) -> Result<PeerBuild, PeerError> {
        let device = EmbreeDevice::new(threads)?;
        self.build_on(&device, aabbs)
    }

    /// Builds over `aabbs` on `device`; `build_time` is the `rtcBuildBVH` call alone.
    pub fn build_on(&self, device: &EmbreeDevice, aabbs: &[Aabb]) -> Result<PeerBuild, PeerError> {
        self.build_on_probed(device, aabbs, &NoProbe)
    }

    /// [`EmbreeBuilder::build_on`] with `probe` run around the `rtcBuildBVH` call.
    pub fn build_on_probed(
        &self,
        device: &EmbreeDevice,
        aabbs: &[Aabb],
        probe: &dyn BuildProbe,
    ) -> Result<PeerBuild, PeerError> {
        check_input(aabbs)?;
        if !(1..=RTC_BUILD_MAX_PRIMITIVES_PER_LEAF).contains(&self.max_leaf_size) {
            return Err(PeerError::Input(bvh::BuildError::InvalidConfig(format!(
                "Embree max_leaf_size {} is outside 1..={RTC_BUILD_MAX_PRIMITIVES_PER_LEAF}",
                self.max_leaf_size
            ))));
        }
        if aabbs.is_empty() {
            return Ok(PeerBuild {
                bvh: bvh::Bvh2::empty(),
                build_time: std::time::Duration::ZERO,
                convert_time: std::time::Duration::ZERO,
            });
        }
        let mut prims: Vec<RtcBuildPrimitive> = aabbs
            .iter()
            .enumerate()
            .map(|(i, b)| RtcBuildPrimitive {
                lower_x: b.min.x,
                lower_y: b.min.y,
                lower_z: b.min.z,
                geom_id: 0,
                upper_x: b.max.x,
                upper_y: b.max.y,
                upper_z: b.max.z,
                prim_id: i as u32,
            })
            .collect();
        // SAFETY: `device.raw` is a live device.
        let handle = BvhHandle(unsafe { rtcNewBVH(device.raw) });
        if handle.0.is_null() {
            return Err(embree_error("rtcNewBVH failed".into()));
        }
        let args = RtcBuildArguments {
            byte_size: std::mem::size_of::<RtcBuildArguments>(),
            build_quality: match self.quality {
                EmbreeQuality::Low => RTC_BUILD_QUALITY_LOW,
                EmbreeQuality::Medium => RTC_BUILD_QUALITY_MEDIUM,
            },
            build_flags: RTC_BUILD_FLAG_NONE,
            max_branching_factor: 2,
            max_depth: 64,
            sah_block_size: 1,
            min_leaf_size: 1,
            max_leaf_size: self.max_leaf_size,
            traversal_cost: self.traversal_cost,
            intersection_cost: self.intersection_cost,
            bvh: handle.0,
            primitives: prims.as_mut_ptr(),
            primitive_count: prims.len(),
            primitive_array_capacity: prims.len(),
            create_node: Some(create_node),
            set_node_children: Some(set_node_children),
            set_node_bounds: Some(set_node_bounds),
            create_leaf: Some(create_leaf),
            split_primitive: None,
            build_progress: None,
            user_ptr: std::ptr::null_mut(),
        };
        probe.before_build();
        let start = Instant::now();
        // SAFETY: `args` matches the header's struct; `prims` (capacity = count) and the
        // BVH outlive the call; the callbacks only write the memory they allocate.
        let root = unsafe { rtcBuildBVH(&args) } as *const u8;
        let build_time = start.elapsed();
        probe.after_build();
        // SAFETY: `device.raw` is a live device.
        let code = unsafe { rtcGetDeviceError(device.raw) };
        if code != 0 || root.is_null() {
            return Err(embree_error(format!(
                "rtcBuildBVH failed ({})",
                error_name(code)
            )));
        }
        let start = Instant::now();
        // SAFETY: `root` and every node below it were written by our callbacks and live in
        // the BVH's memory until `handle` is dropped, after the conversion.
        let bvh = unsafe { convert(root, aabbs) }?;
        drop(handle);
        Ok(PeerBuild {
            bvh,
            build_time,
            convert_time: start.elapsed(),
        })
    }
}

/// The `primID`s of a leaf written by [`create_leaf`].
///
/// # Safety
/// `p` must point to a leaf written by [`create_leaf`] that outlives `'a`.
unsafe fn leaf_ids<'a>(p: *const u8) -> &'a [u32] {
    let h = &*(p as *const LeafHeader);
    std::slice::from_raw_parts(
        p.add(std::mem::size_of::<LeafHeader>()) as *const u32,
        h.count as usize,
    )
}

/// Converts the pointer tree under `root` to Arbor's format.
///
/// # Safety
/// Every node reachable from `root` must have been written by our callbacks and stay
/// alive for the call.
unsafe fn convert(root: *const u8, aabbs: &[Aabb]) -> Result<bvh::Bvh2, PeerError> {
    let view = |p: *const u8| -> PeerNode<'_, *const u8> {
        // A NULL child (never set) reads as an empty leaf, which the converter rejects.
        if p.is_null() {
            return PeerNode::Leaf(&[]);
        }
        if *(p as *const u32) == LEAF {
            PeerNode::Leaf(leaf_ids(p))
        } else {
            let n = &*(p as *const InnerNode);
            PeerNode::Inner([(n.children[0], n.bounds[0]), (n.children[1], n.bounds[1])])
        }
    };
    let root_box = if *(root as *const u32) == LEAF {
        leaf_ids(root)
            .iter()
            .filter_map(|&i| aabbs.get(i as usize))
            .fold(Aabb::EMPTY, |a, b| a.union(*b))
    } else {
        Aabb::EMPTY // unused: an inner root's box is the union of its children's
    };
    to_bvh2("embree", aabbs.len(), root, root_box, view)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testinputs::{adversarial, soup};

    #[test]
    fn low_and_medium_give_valid_trees_on_a_10k_soup() {
        let prims = soup(10_000, 2.0, 11);
        let sweep = bvh::SweepSahBuilder::default().build(&prims).unwrap();
        for threads in [1, 2] {
            let device = EmbreeDevice::new(threads).unwrap();
            for quality in [EmbreeQuality::Low, EmbreeQuality::Medium] {
                let b = EmbreeBuilder {
                    quality,
                    ..Default::default()
                };
                let t = b.build_on(&device, &prims).unwrap();
                assert_eq!(bvh::validate(&t.bvh, &prims, 8), Ok(()), "{quality:?}");
                let ratio = t.bvh.sah_vs(&sweep);
                // A sane SAH: not better than the sweep reference by more than binning
                // noise, and not wildly worse (Morton trees are ~10-40% worse).
                assert!(
                    (0.95..2.0).contains(&ratio),
                    "{quality:?} SAH ratio {ratio}"
                );
            }
        }
    }

    #[test]
    fn small_and_adversarial_inputs_give_valid_trees() {
        let device = EmbreeDevice::new(2).unwrap();
        for (name, prims) in adversarial() {
            for quality in [EmbreeQuality::Low, EmbreeQuality::Medium] {
                for max_leaf_size in [1, 8] {
                    let b = EmbreeBuilder {
                        quality,
                        max_leaf_size,
                        ..Default::default()
                    };
                    let t = b
                        .build_on(&device, &prims)
                        .unwrap_or_else(|e| panic!("{name} {quality:?} leaf {max_leaf_size}: {e}"));
                    assert_eq!(
                        bvh::validate(&t.bvh, &prims, max_leaf_size),
                        Ok(()),
                        "{name} {quality:?} leaf {max_leaf_size}"
                    );
                }
            }
        }
        let empty = EmbreeBuilder::default().build_on(&device, &[]).unwrap();
        assert_eq!(empty.bvh, bvh::Bvh2::empty());
    }

    #[test]
    fn bad_leaf_size_is_a_config_error() {
        let b = EmbreeBuilder {
            max_leaf_size: 33,
            ..Default::default()
        };
        assert!(matches!(
            b.build(&soup(10, 1.0, 1), 1),
            Err(PeerError::Input(bvh::BuildError::InvalidConfig(_)))
        ));
    }

    /// The memory monitor sees Embree's own allocations: at least the node memory of
    /// the tree (our `InnerNode`s live in Embree's allocator), and the probe runs around
    /// the build call alone.
    #[test]
    fn memory_monitor_counts_embree_allocations_and_probe_brackets_the_build() {
        use std::sync::atomic::{AtomicUsize, Ordering::SeqCst};
        struct Count(AtomicUsize, AtomicUsize);
        impl BuildProbe for Count {
            fn before_build(&self) {
                self.0.fetch_add(1, SeqCst);
            }
            fn after_build(&self) {
                self.1.fetch_add(1, SeqCst);
            }
        }
        let prims = soup(50_000, 2.0, 3);
        let device = EmbreeDevice::new(1).unwrap();
        for quality in [EmbreeQuality::Low, EmbreeQuality::Medium] {
            device.reset_memory_peak();
            assert_eq!(device.memory_peak_bytes(), 0);
            let probe = Count(AtomicUsize::new(0), AtomicUsize::new(0));
            let b = EmbreeBuilder {
                quality,
                ..Default::default()
            };
            let t = b.build_on_probed(&device, &prims, &probe).unwrap();
            assert_eq!((probe.0.load(SeqCst), probe.1.load(SeqCst)), (1, 1));
            let nodes = t.bvh.nodes.len() * std::mem::size_of::<InnerNode>();
            let peak = device.memory_peak_bytes();
            assert!(
                peak >= nodes,
                "{quality:?}: peak {peak} below the nodes' {nodes}"
            );
            // Not wildly more than a tree's worth plus build buffers per primitive.
            assert!(peak < 1000 * prims.len(), "{quality:?}: {peak}");
        }
    }
}
