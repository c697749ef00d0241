//! What a reconstruction did: the [`Report`] a run returns, printed as the command's summary
//! (one line per stage with the device it ran on) and written as `map_report.json`.

use super::super::{mib, EvaluationTable, Written};
use denser::eval::EvaluationReport;
use denser::mesh::Field;
use denser::reconstruct::RegularizeOutcome;
use denser::store::SurfaceOutput;
use std::fmt;
use std::path::PathBuf;

/// What a reconstruction did (printed as the command's summary).
pub(crate) struct Report {
    pub input: String,
    pub device: String,
    pub fusion_device: String,
    pub mesh_device: String,
    pub stereo_device: Option<String>,
    pub frames: usize,
    pub resumed_from_frame: u64,
    pub timings: denser::reconstruct::StageTimings,
    pub summary: denser::store::StoreSummary,
    pub gpu: Option<denser::gpu::ResidentStats>,
    pub gpu_traffic: Option<denser::backend::StageTraffic>,
    pub gpu_kernels: Option<denser::gpu::KernelCompilation>,
    /// `--kernel-times`: the run's kernels' device times (a Markdown table) or why there are
    /// none.
    pub kernel_times: Option<String>,
    pub regularize: Option<RegularizeOutcome>,
    pub surfaces: Vec<SurfaceOutput>,
    pub evaluation: Option<EvaluationReport>,
    pub written: Vec<PathBuf>,
    pub peak_rss_bytes: Option<u64>,
}

/// The GPU traffic of a run, per stage: a line per stage that ran, then the whole run.
struct TrafficLines<'a>(&'a denser::backend::StageTraffic);

impl fmt::Display for TrafficLines<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let g = self.0;
        for (what, n, t) in [
            ("stereo pair", g.stereo_pairs, &g.stereo),
            ("depth frame", g.depth_frames, &g.depth),
            ("LiDAR scan", g.lidar_scans, &g.lidar),
            ("TV solve", g.tv_solves, &g.tv),
            ("write-back to RAM", g.write_backs, &g.write_back),
            ("mesh", g.meshes, &g.mesh),
        ] {
            if n > 0 {
                writeln!(f, "GPU traffic per {what} ({n}): {}", t.describe_per(n))?;
            }
        }
        writeln!(f, "GPU traffic, whole run: {}", g.total.describe_per(1))
    }
}

impl Report {
    pub(crate) fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "input": self.input,
            "device": self.device,
            "mesh_device": self.mesh_device,
            "frames": self.frames,
            "resumed_from_frame": self.resumed_from_frame,
            "timings": self.timings,
            "map": self.summary,
            "gpu": self.gpu,
            "gpu_traffic": self.gpu_traffic,
            "gpu_kernels": self.gpu_kernels,
            "regularize": self.regularize,
            "surfaces": self.surfaces.iter().map(|s| serde_json::json!({
                "field": format!("{:?}", s.field).to_lowercase(),
                "path": s.mesh_path,
                "vertices": s.vertices,
                "triangles": s.triangles,
                "area_m2": s.area_m2,
                "seconds": s.seconds,
            })).collect::<Vec<_>>(),
            "peak_rss_bytes": self.peak_rss_bytes,
        })
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let t = &self.timings;
        let s = &self.summary;
        if self.resumed_from_frame > 0 {
            writeln!(
                f,
                "resumed after {} committed frames",
                self.resumed_from_frame
            )?;
        }
        if let Some(dev) = &self.stereo_device {
            writeln!(
                f,
                "stereo on {dev}: {:.1} ms per frame (reading and matching)",
                1e3 * t.input_s / t.frames_fused.max(1) as f64
            )?;
        }
        writeln!(
            f,
            "fused {} frame{} of {} on {}: {:.1} ms/frame, {:.2} M voxel updates/s; {} blocks, {} voxels in Ω",
            t.frames_fused,
            if t.frames_fused == 1 { "" } else { "s" },
            self.input,
            self.fusion_device,
            t.fusion_ms_per_frame(),
            t.voxel_updates_per_s() / 1e6,
            s.blocks,
            s.observed_voxels,
        )?;
        match &s.paging {
            None => writeln!(
                f,
                "map in RAM: {:.1} MiB, {:.2} bytes/voxel",
                mib(s.ram_bytes),
                s.ram_bytes_per_voxel
            )?,
            Some(p) => {
                writeln!(
                    f,
                    "map on disk: {:.1} MiB, {:.3} bytes/voxel; paging {:.1} ms/frame ({:.1} % of fusion)",
                    mib(s.disk_bytes),
                    s.disk_bytes as f64 / s.voxels().max(1) as f64,
                    1e3 * t.paging_s / t.frames_fused.max(1) as f64,
                    100.0 * t.paging_s / t.fusion_s.max(1e-9)
                )?;
                writeln!(
                    f,
                    "pager: {} MiB of the budget for blocks, peak {:.1} MiB resident+writing, {} chunks evicted, {} written ({:.1} MiB), {} read back, {} over budget",
                    p.budget_bytes >> 20,
                    mib(p.peak_bytes),
                    p.chunks_evicted,
                    p.chunks_written,
                    mib(p.bytes_written),
                    p.chunks_read,
                    p.budget_overruns
                )?;
            }
        }
        if let Some(g) = &self.gpu {
            writeln!(
                f,
                "GPU tier: pool {} blocks (max {}), peak {} resident, {} uploaded, {} created on the GPU ({} inserted there, into {} slots reserved for them; {} kept empty for the next frame), {} read back, {} spilled to RAM, {} grows, {} oversize frames, {} frames submitted while others were in flight ({} blocks listed for frames in flight), {} table writes",
                g.capacity_blocks,
                g.max_blocks,
                g.peak_resident_blocks,
                g.blocks_uploaded,
                g.blocks_created,
                g.blocks_inserted_on_gpu,
                g.slots_reserved,
                g.empty_blocks_kept,
                g.blocks_downloaded,
                g.blocks_spilled,
                g.grows,
                g.oversize_frames,
                g.frames_overlapped,
                g.blocks_listed_in_flight,
                g.table_writes
            )?;
            let per = |s: f64| 1e3 * s / g.frames.max(1) as f64;
            writeln!(
                f,
                "GPU tier per frame: host CPU {:.2} ms (the fusing thread's own work), listing blocks (CPU) {:.1} ms, residency {:.1} ms, kernels {:.1} ms (inputs {:.1}, submit and wait {:.1}), write-back {:.1} ms",
                per(g.host_cpu_s),
                per(g.list_s),
                per(g.residency_s),
                per(g.kernel_s),
                per(g.inputs_s),
                per(g.kernel_s - g.inputs_s),
                per(g.download_s)
            )?;
        }
        if let Some(g) = &self.gpu_traffic {
            write!(f, "{}", TrafficLines(g))?;
        }
        if let Some(k) = &self.gpu_kernels {
            writeln!(
                f,
                "GPU kernels compiled: {} in {:.2} s (a stage's kernels together, before its first frame)",
                k.kernels, k.seconds
            )?;
        }
        match &self.regularize {
            None => writeln!(
                f,
                "regularization skipped (run `denser regularize` on the map)"
            )?,
            Some(r) => write!(f, "{}", RegularizeLine(r, &self.device, t))?,
        }
        let surface = |field: Field| self.surfaces.iter().find(|s| s.field == field);
        if let Some(raw) = surface(Field::Raw) {
            write!(
                f,
                "meshes: raw {} triangles, {:.1} m²",
                raw.triangles, raw.area_m2
            )?;
            if let Some(reg) = surface(Field::Regularized) {
                write!(
                    f,
                    "; regularized {} triangles, {:.1} m²",
                    reg.triangles, reg.area_m2
                )?;
            }
            writeln!(
                f,
                " (marching cubes on {}, {:.1} s)",
                self.mesh_device, t.mesh_s
            )?;
        }
        if let Some(e) = &self.evaluation {
            write!(f, "{}", EvaluationTable(e))?;
        }
        write!(f, "{}", Written(&self.written))?;
        if let Some(rss) = self.peak_rss_bytes {
            writeln!(f, "peak RSS {:.1} MiB", mib(rss))?;
        }
        if let Some(table) = &self.kernel_times {
            write!(f, "\n{table}\n")?;
        }
        Ok(())
    }
}

/// The regularization summary line: which device solved how much, how fast.
pub(crate) struct RegularizeLine<'a>(
    pub &'a RegularizeOutcome,
    pub &'a str,
    pub &'a denser::reconstruct::StageTimings,
);

impl fmt::Display for RegularizeLine<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (r, device, t) = (self.0, self.1, self.2);
        let s = &r.summary;
        let on = if r.devices.gpu > 0 && r.devices.cpu > 0 {
            format!(
                "{device} ({} solves; {} too large for it on the CPU)",
                r.devices.gpu, r.devices.cpu
            )
        } else if r.devices.gpu > 0 {
            device.to_string()
        } else {
            "CPU".to_string()
        };
        write!(
            f,
            "regularized on {on}: {} iterations over {} Ω voxels in {:.1} s, {:.1} M voxel-iterations/s",
            s.iterations,
            s.omega_voxels,
            r.seconds,
            t.voxel_iterations_per_s() / 1e6
        )?;
        if let Some((a, b)) = s.energy {
            write!(f, ", energy {a:.4e} → {b:.4e}")?;
        }
        if s.halo_blocks > 0 {
            write!(
                f,
                "; {} regions ({} already done), halo {} blocks, {:.2}× blocks solved",
                s.regions,
                s.regions_skipped,
                s.halo_blocks,
                s.solved_blocks as f64 / s.blocks.max(1) as f64
            )?;
        }
        writeln!(f)
    }
}
