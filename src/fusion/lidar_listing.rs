//! A LiDAR scan's blocks listed on the device, so that the host never walks a scan's rays when
//! a GPU fuses it: the rays go up once (16 bytes each, [`super::lidar_device::record_rays`]),
//! `shaders/lidar_blocks.wgsl` walks each ray's band through the blocks exactly as the host's
//! listing does (`shared/lidar_traverse.wgsl`) and puts each block crossed in a hash table keyed
//! by its offset from the sensor's block, counting its pairs, and `shaders/lidar_found.wgsl`
//! lists the table; the host reads back 8 bytes per block (its packed offset and pair count),
//! sorts them, pages the blocks in and fuses the scan from the rays the device kept
//! ([`super::integrate_lidar_resident`]). One submit, or none of its own: a pipelined run
//! (`Reconstructor::fuse_lidar` with frames in flight) records scan N+1's listing into scan N's
//! fusion submit ([`record_lidar_listing`], `super::fuse_lidar_then_list`). The results come
//! back through a ring of staging buffers ([`crate::gpu::readback`]), collected when the scan
//! is fused, a call later, so the host reads the next scan meanwhile and waits only where the
//! device has not finished (a second wait where a scan has more blocks than the last one's
//! readback was sized for).
//!
//! Where the device cannot list a scan (a block more than 512 blocks from the sensor's, a table
//! too full, arithmetic the exact f64 cannot do), the kernels count it and the host lists the
//! scan itself: the same plan either way (`tests/gpu/lidar_listing.rs`).

use super::lidar_device::{record_rays, scan_words, sensor_block, RaysFrom};
use super::LidarPlan;
use crate::gpu::kept::Kept;
use crate::gpu::readback::{LateReadback, ReadbackRing};
use crate::gpu::resident::{FrameParts, ResidentMap};
use crate::gpu::{shaders, ErrorScopes, GpuContext};
use crate::grid::{BlockIndex, GridParams};
use crate::Result;
use std::sync::Arc;

/// Offsets from the sensor's block that pack (`FOUND_HALF` in `shaders/shared/lidar_scan.wgsl`).
const FOUND_HALF: i32 = 512;

/// What a listing keeps between scans: how many listings ran (each one's number names the rays
/// it leaves on the device) and how many blocks the last scan had (which sizes the next one's
/// table and readback).
#[derive(Debug, Default)]
pub(crate) struct LidarListings {
    listings: u64,
    last_blocks: usize,
    /// The staging buffers the listings' results come back through.
    ring: ReadbackRing,
    /// The staging buffer of a second readback.
    kept: Kept,
}

/// Entries of the table: a power of two, at least four times the blocks expected (the last
/// scan's, or one per eight rays, at least 1 024).
fn table_entries(rays: usize, last_blocks: usize) -> usize {
    (4 * last_blocks.max(rays / 8).max(1024)).next_power_of_two()
}

/// The block at `word`, an offset packed by `shaders/lidar_blocks.wgsl` from `origin`.
fn unpack_found(origin: [i32; 3], word: u32) -> BlockIndex {
    let axis = |a: u32| ((word >> (10 * a)) & 1023) as i32 - FOUND_HALF;
    BlockIndex([0, 1, 2].map(|a| origin[a as usize] + axis(a)))
}

/// A scan whose blocks are being listed on the device: its listing submitted, the results on
/// their way back ([`begin_lidar_listing`], [`finish_lidar_listing`]).
pub(crate) struct LidarListing {
    plan: LidarPlan,
    /// The device listing it.
    ctx: Arc<GpuContext>,
    readback: LateReadback,
    /// The listing's number (which names the rays it leaves on the device).
    number: u64,
    /// The entries of its table.
    entries: u32,
    /// The sensor's block, from which the listed blocks' offsets pack.
    origin: [i32; 3],
    /// The list's entries read back with the counters: sized by the last scan's blocks.
    guess: usize,
    /// The listed blocks (where a scan has more than `guess`, read again).
    list: wgpu::Buffer,
}

/// A LiDAR scan's plan, or its listing on the device on the way to one.
pub(crate) enum PendingLidarPlan {
    /// Planned (on the host, or a device listing finished).
    Planned(LidarPlan),
    /// Listed on the device, not collected yet.
    Listing(Box<LidarListing>),
}

impl PendingLidarPlan {
    /// The scan's usable rays.
    pub(crate) fn ray_count(&self) -> usize {
        match self {
            PendingLidarPlan::Planned(plan) => plan.ray_count(),
            PendingLidarPlan::Listing(l) => l.plan.ray_count(),
        }
    }
}

/// Whether the device of `ctx` can list the blocks of `plan`: it has rays and they fit one
/// binding (else the host lists its pairs when asked).
pub(crate) fn listable(ctx: &GpuContext, plan: &LidarPlan) -> bool {
    plan.ray_count() > 0 && super::lidar_device::rays_fit(ctx, plan)
}

/// Records and submits the listing of the blocks of `plan` (its rays alone:
/// [`LidarPlan::rays_only`]) on the device of `map`, its results read back late (a ring of
/// staging buffers kept by `listings`: [`finish_lidar_listing`] collects them), the rays left on
/// the device for the scan's fusion. Where the device cannot take the rays, the plan as it came,
/// whose pairs the host lists when asked.
pub(crate) fn begin_lidar_listing(
    map: &mut ResidentMap,
    listings: &mut LidarListings,
    plan: LidarPlan,
) -> Result<PendingLidarPlan> {
    if !listable(map.context(), &plan) {
        return Ok(PendingLidarPlan::Planned(plan));
    }
    let device = map.context().clone();
    let FrameParts {
        ctx, grid, kept, ..
    } = map.frame_parts();
    let scope = ErrorScopes::push(&ctx.device);
    let mut encoder = ctx.encoder("lidar_listing");
    let listing = record_lidar_listing((&device, grid, kept), listings, plan, &mut encoder)?;
    ctx.submit(encoder);
    listing.submitted();
    scope.pop("listing a LiDAR scan's blocks on the GPU")?;
    map.set_lidar_rays_of(Some(listing.rays_of()));
    Ok(PendingLidarPlan::Listing(Box::new(listing)))
}

/// Records into `encoder` the listing of the blocks of `plan` ([`listable`]) on `device`, with
/// the copy of its results into the next staging buffer of `listings`' ring: the caller submits
/// `encoder` (after work that still reads the rays and table of the scan listed before, which
/// the listing overwrites: a scan's fusion), then calls [`LidarListing::submitted`] and
/// [`ResidentMap::set_lidar_rays_of`] with [`LidarListing::rays_of`]. What goes up by queue
/// write (the scan's words and rays) lands in buffers of the listing's own, which no fusion
/// reads, so it may share a submit with one.
pub(crate) fn record_lidar_listing(
    (device, grid, kept): (&Arc<GpuContext>, GridParams, &mut Kept),
    listings: &mut LidarListings,
    plan: LidarPlan,
    encoder: &mut wgpu::CommandEncoder,
) -> Result<LidarListing> {
    let ctx = &**device;
    let rays = plan.ray_count();
    let entries = table_entries(rays, listings.last_blocks);
    let origin = sensor_block(&grid, &plan);
    let words = scan_words((&grid, &plan), [0, 0, entries - 1], (origin, 1, 0));
    let buf_scan = kept.storage_with(ctx, "lidar_listing_words", bytemuck::cast_slice(&words));
    let buf_counters = kept.scratch(ctx, "lidar_listing_counters", 16);
    let table_bytes = entries as u64 * 8;
    let buf_table = kept.scratch(ctx, "lidar_found_table", table_bytes);
    let buf_list = kept.scratch(ctx, "lidar_found_list", table_bytes);
    encoder.clear_buffer(&buf_counters, 0, Some(16));
    encoder.clear_buffer(&buf_table, 0, Some(table_bytes));
    let (buf_rays_f64, _) = record_rays(
        (ctx, &mut *kept, &mut *encoder),
        &plan,
        (&buf_scan, &buf_counters),
        RaysFrom::Listing,
    )?;
    let blocks = ctx.kernel(&shaders::LIDAR_BLOCKS)?;
    let buffers = [&buf_scan, &buf_table, &buf_rays_f64, &buf_counters];
    let bind = kept.bind_group(ctx, "lidar_blocks", &blocks.layout, &buffers);
    ctx.record_dispatch(encoder, &blocks, &bind, rays as u64)?;
    let found = ctx.kernel(&shaders::LIDAR_FOUND)?;
    let buffers = [&buf_scan, &buf_table, &buf_list, &buf_counters];
    let bind = kept.bind_group(ctx, "lidar_found", &found.layout, &buffers);
    ctx.record_dispatch(encoder, &found, &bind, entries as u64)?;
    // The readback sized by the last scan's blocks, and a quarter more.
    let guess = (listings.last_blocks + listings.last_blocks / 4 + 256).min(entries);
    let parts = [(&buf_counters, 16), (&buf_list, 8 * guess)];
    let readback = listings.ring.record(ctx, encoder, &parts);
    listings.listings += 1;
    Ok(LidarListing {
        plan,
        ctx: device.clone(),
        readback,
        number: listings.listings,
        entries: entries as u32,
        origin,
        guess,
        list: buf_list,
    })
}

impl LidarListing {
    /// The device listing the scan.
    pub(crate) fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The listing's number and its table's entries, which name the rays and table it leaves
    /// on the device ([`ResidentMap::set_lidar_rays_of`]).
    pub(crate) fn rays_of(&self) -> (u64, u32) {
        (self.number, self.entries)
    }

    /// Asks for its results to be mapped, once the encoder it was recorded into is submitted.
    pub(crate) fn submitted(&self) {
        self.readback.submitted();
    }
}

/// The plan of a scan whose listing [`begin_lidar_listing`] submitted: its blocks as the device
/// listed them ([`LidarPlan::with_listed_blocks`]), or, where the device could not list them,
/// the plan as it came (`Err`), whose pairs the host lists when asked. Waits (one counted wait)
/// only where the device has not finished the listing, and a second time where the scan has
/// more blocks than were read back.
pub(crate) fn finish_lidar_listing(
    listings: &mut LidarListings,
    listing: LidarListing,
) -> Result<std::result::Result<LidarPlan, LidarPlan>> {
    let ctx = &*listing.ctx;
    let mut counters = [0u32; 4];
    let mut list = vec![0u32; 2 * listing.guess];
    ctx.poll_finished()?;
    listing.readback.collect(
        ctx,
        &mut [
            bytemuck::cast_slice_mut(&mut counters),
            bytemuck::cast_slice_mut(&mut list),
        ],
    )?;
    let [_, failed, count, _] = counters.map(|c| c as usize);
    let plan = listing.plan;
    if failed > 0 {
        tracing::debug!("{failed} crossings the GPU could not list: the host lists the scan");
        listings.last_blocks = plan.blocks().len();
        return Ok(Err(plan));
    }
    if count > listing.guess {
        list = vec![0u32; 2 * count];
        let encoder = ctx.encoder("lidar_listing_rest");
        let target = bytemuck::cast_slice_mut(&mut list);
        let kept = &mut listings.kept;
        ctx.submit_and_read_back(encoder, kept, &mut [(&listing.list, target)])?;
    }
    listings.last_blocks = count;
    let found: Vec<(BlockIndex, u32)> = list[..2 * count]
        .chunks_exact(2)
        .map(|e| (unpack_found(listing.origin, e[0]), e[1]))
        .collect();
    Ok(Ok(plan.with_listed_blocks(found, listing.number)))
}
