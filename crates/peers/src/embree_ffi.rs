//! Hand-written bindings to the part of Embree 3's C API that the BVH-builder adapter uses
//! (`rtcore_device.h`, `rtcore_builder.h`, `rtcore_common.h` of Embree 3.13).
//!
//! Only what `rtcBuildBVH` needs is declared. The structs mirror the header exactly
//! (field order, types, `RTC_ALIGN`); the size/alignment assertions below pin them to the
//! header's layout on 64-bit targets. Linking (`-l embree3`) is done by `build.rs` when the
//! `embree` feature is on.

use std::ffi::{c_char, c_void};

/// `RTCDevice`: an opaque device handle.
pub type RtcDevice = *mut c_void;
/// `RTCBVH`: an opaque BVH (allocator) handle.
pub type RtcBvh = *mut c_void;
/// `RTCThreadLocalAllocator`: an opaque per-thread allocator handle.
pub type RtcThreadLocalAllocator = *mut c_void;

/// `enum RTCError` (`RTC_ERROR_NONE` = 0 ... `RTC_ERROR_CANCELLED` = 6).
pub type RtcError = u32;

/// `enum RTCBuildQuality`: `LOW` = 0 (Morton), `MEDIUM` = 1 (binned SAH), `HIGH` = 2.
pub type RtcBuildQuality = u32;
/// `RTC_BUILD_QUALITY_LOW`.
pub const RTC_BUILD_QUALITY_LOW: RtcBuildQuality = 0;
/// `RTC_BUILD_QUALITY_MEDIUM`.
pub const RTC_BUILD_QUALITY_MEDIUM: RtcBuildQuality = 1;
/// `enum RTCBuildFlags`: `RTC_BUILD_FLAG_NONE` = 0.
pub type RtcBuildFlags = u32;
/// `RTC_BUILD_FLAG_NONE`.
pub const RTC_BUILD_FLAG_NONE: RtcBuildFlags = 0;
/// `RTC_BUILD_MAX_PRIMITIVES_PER_LEAF`.
pub const RTC_BUILD_MAX_PRIMITIVES_PER_LEAF: u32 = 32;

/// `struct RTC_ALIGN(32) RTCBuildPrimitive`.
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RtcBuildPrimitive {
    pub lower_x: f32,
    pub lower_y: f32,
    pub lower_z: f32,
    pub geom_id: u32,
    pub upper_x: f32,
    pub upper_y: f32,
    pub upper_z: f32,
    pub prim_id: u32,
}

/// `struct RTC_ALIGN(16) RTCBounds`.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default)]
pub struct RtcBounds {
    pub lower_x: f32,
    pub lower_y: f32,
    pub lower_z: f32,
    pub align0: f32,
    pub upper_x: f32,
    pub upper_y: f32,
    pub upper_z: f32,
    pub align1: f32,
}

/// `RTCCreateNodeFunction`.
pub type RtcCreateNodeFunction = Option<
    unsafe extern "C" fn(
        alloc: RtcThreadLocalAllocator,
        child_count: u32,
        user: *mut c_void,
    ) -> *mut c_void,
>;
/// `RTCSetNodeChildrenFunction`.
pub type RtcSetNodeChildrenFunction = Option<
    unsafe extern "C" fn(
        node: *mut c_void,
        children: *mut *mut c_void,
        child_count: u32,
        user: *mut c_void,
    ),
>;
/// `RTCSetNodeBoundsFunction`.
pub type RtcSetNodeBoundsFunction = Option<
    unsafe extern "C" fn(
        node: *mut c_void,
        bounds: *mut *const RtcBounds,
        child_count: u32,
        user: *mut c_void,
    ),
>;
/// `RTCCreateLeafFunction`.
pub type RtcCreateLeafFunction = Option<
    unsafe extern "C" fn(
        alloc: RtcThreadLocalAllocator,
        prims: *const RtcBuildPrimitive,
        count: usize,
        user: *mut c_void,
    ) -> *mut c_void,
>;
/// `RTCSplitPrimitiveFunction` (only used by `HIGH` quality; always `None` here).
pub type RtcSplitPrimitiveFunction = Option<
    unsafe extern "C" fn(
        prim: *const RtcBuildPrimitive,
        dim: u32,
        pos: f32,
        left: *mut RtcBounds,
        right: *mut RtcBounds,
        user: *mut c_void,
    ),
>;
/// `RTCProgressMonitorFunction`.
pub type RtcProgressMonitorFunction =
    Option<unsafe extern "C" fn(user: *mut c_void, n: f64) -> bool>;

/// `struct RTCBuildArguments`, field for field.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct RtcBuildArguments {
    pub byte_size: usize,
    pub build_quality: RtcBuildQuality,
    pub build_flags: RtcBuildFlags,
    pub max_branching_factor: u32,
    pub max_depth: u32,
    pub sah_block_size: u32,
    pub min_leaf_size: u32,
    pub max_leaf_size: u32,
    pub traversal_cost: f32,
    pub intersection_cost: f32,
    pub bvh: RtcBvh,
    pub primitives: *mut RtcBuildPrimitive,
    pub primitive_count: usize,
    pub primitive_array_capacity: usize,
    pub create_node: RtcCreateNodeFunction,
    pub set_node_children: RtcSetNodeChildrenFunction,
    pub set_node_bounds: RtcSetNodeBoundsFunction,
    pub create_leaf: RtcCreateLeafFunction,
    pub split_primitive: RtcSplitPrimitiveFunction,
    pub build_progress: RtcProgressMonitorFunction,
    pub user_ptr: *mut c_void,
}

const _: () = assert!(std::mem::size_of::<RtcBuildPrimitive>() == 32);
const _: () = assert!(std::mem::align_of::<RtcBuildPrimitive>() == 32);
const _: () = assert!(std::mem::size_of::<RtcBounds>() == 32);
const _: () = assert!(std::mem::align_of::<RtcBounds>() == 16);
// 8 + 9 * 4 (+ 4 padding) + 8 (bvh) + 8 + 8 + 8 + 6 * 8 + 8 = 136 on 64-bit targets.
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<RtcBuildArguments>() == 136);

extern "C" {
    /// `RTCDevice rtcNewDevice(const char* config)`.
    pub fn rtcNewDevice(config: *const c_char) -> RtcDevice;
    /// `enum RTCError rtcGetDeviceError(RTCDevice device)` (NULL: errors of device creation).
    pub fn rtcGetDeviceError(device: RtcDevice) -> RtcError;
    /// `void rtcReleaseDevice(RTCDevice device)`.
    pub fn rtcReleaseDevice(device: RtcDevice);
    /// `RTCBVH rtcNewBVH(RTCDevice device)`.
    pub fn rtcNewBVH(device: RtcDevice) -> RtcBvh;
    /// `void* rtcBuildBVH(const struct RTCBuildArguments* args)`.
    pub fn rtcBuildBVH(args: *const RtcBuildArguments) -> *mut c_void;
    /// `void* rtcThreadLocalAlloc(RTCThreadLocalAllocator allocator, size_t bytes, size_t align)`.
    pub fn rtcThreadLocalAlloc(
        alloc: RtcThreadLocalAllocator,
        bytes: usize,
        align: usize,
    ) -> *mut c_void;
    /// `void rtcReleaseBVH(RTCBVH bvh)`.
    pub fn rtcReleaseBVH(bvh: RtcBvh);
    /// `void rtcSetDeviceMemoryMonitorFunction(RTCDevice device,
    /// RTCMemoryMonitorFunction memoryMonitor, void* userPtr)`.
    pub fn rtcSetDeviceMemoryMonitorFunction(
        device: RtcDevice,
        monitor: RtcMemoryMonitorFunction,
        user: *mut c_void,
    );
}

/// `bool (*RTCMemoryMonitorFunction)(void* ptr, ssize_t bytes, bool post)`: `bytes` > 0
/// announces an allocation, < 0 a free; returning false makes the allocation fail.
pub type RtcMemoryMonitorFunction =
    Option<unsafe extern "C" fn(user: *mut c_void, bytes: isize, post: bool) -> bool>;
