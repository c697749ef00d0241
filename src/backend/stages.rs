//! Which stages a GPU backend runs on the device: every stage with `--device gpu`, and with
//! `--device auto` those the records show faster than the same machine's CPU.

use crate::gpu::shaders::{self, ShaderSource};

/// Which stages a backend with a GPU runs there (the others run on the CPU).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct GpuStages {
    /// Depth and LiDAR fusion (with their blocks resident on the GPU).
    pub fusion: bool,
    /// TV regularization.
    pub tv: bool,
    /// The variational stereo matchers' kernels.
    pub stereo: bool,
    /// Marching cubes of the meshes a run writes from RAM.
    pub mesh: bool,
}

impl GpuStages {
    /// Every stage that has a kernel (`--device gpu`).
    pub const ALL: GpuStages = GpuStages {
        fusion: true,
        tv: true,
        stereo: true,
        mesh: true,
    };

    /// What `--device auto` runs on a hardware GPU: the rule applied to the project's records
    /// ([`RECORDED_FASTER`]), today TV, stereo and marching cubes.
    pub const MEASURED_FASTER: GpuStages =
        GpuStages::auto_rule(AdapterClass::Hardware, RECORDED_FASTER);

    /// No stage on the GPU.
    pub const NONE: GpuStages = GpuStages {
        fusion: false,
        tv: false,
        stereo: false,
        mesh: false,
    };

    /// `--device auto`'s rule: a stage runs on an adapter only where `records` show it faster
    /// on that class of adapter than on the same machine's CPU; every other stage runs on the
    /// CPU.
    pub const fn auto_rule(class: AdapterClass, records: &[StageRecord]) -> GpuStages {
        let mut stages = GpuStages::NONE;
        let mut k = 0;
        while k < records.len() {
            let r = &records[k];
            if r.class as u8 == class as u8 {
                match r.stage {
                    Stage::Fusion => stages.fusion = true,
                    Stage::Tv => stages.tv = true,
                    Stage::Stereo => stages.stereo = true,
                    Stage::Mesh => stages.mesh = true,
                }
            }
            k += 1;
        }
        stages
    }

    /// The kernels of the stages on the GPU, for compiling them ahead of a run
    /// ([`GpuContext::compile_kernels`]).
    pub fn kernels(&self) -> Vec<&'static ShaderSource> {
        let mut out = Vec::new();
        if self.fusion {
            out.extend([
                &shaders::FUSE_DEPTH_RESIDENT,
                &shaders::BLOCK_LOOKUP,
                &shaders::FRAME_KEYS,
                &shaders::CLEAR_UPDATED,
                &shaders::FILL_SLOTS,
                &shaders::TABLE_SCATTER,
                &shaders::BAND_SLICES,
                &shaders::FUSE_LIDAR,
                &shaders::FUSE_LIDAR_RESIDENT,
            ]);
        }
        if self.tv {
            out.extend([
                &shaders::TV_DUAL,
                &shaders::TV_PRIMAL,
                &shaders::TV_RESIDENT_SLOTS,
                &shaders::TV_RESIDENT_LIST,
                &shaders::TV_RESIDENT_LINKS,
                &shaders::TV_RESIDENT_GATHER,
                &shaders::TV_RESIDENT_ENCODE,
            ]);
        }
        if self.stereo {
            out.extend([
                &shaders::DISPARITY_DEPTH,
                &shaders::BAND_SLICES,
                &shaders::CENSUS,
                &shaders::CENSUS_COST,
                &shaders::SGM_PATHS,
                &shaders::SGM_RIGHT,
                &shaders::SGM_SELECT,
                &shaders::SGM_MEDIAN,
                &shaders::SGM_SPECKLE_RUNS,
                &shaders::SGM_SPECKLE_JOIN,
                &shaders::SGM_SPECKLE_COUNT,
                &shaders::SGM_SPECKLE_CLEAR,
                &shaders::TGV_FILL_ROWS,
                &shaders::TGV_FILL_COLUMNS,
                &shaders::COST_WINDOW,
                &shaders::TGV_TENSORS,
                &shaders::TGV_COST_AT,
                &shaders::TGV_OCCLUDED,
                &shaders::TGV_INVALIDATE,
                &shaders::TGV_POINTWISE,
                &shaders::TGV_DUAL,
                &shaders::TGV_PRIMAL,
                &shaders::TGV_INIT,
            ]);
        }
        if self.mesh {
            out.extend([
                &shaders::MC_SAMPLES,
                &shaders::MC_COUNT,
                &shaders::MC_EMIT,
                &shaders::MC_FIRST,
                &shaders::MC_SCAN,
                &shaders::MC_ASSIGN,
                &shaders::MC_LINK,
            ]);
        }
        out
    }

    /// Whether any stage runs on the GPU.
    pub fn any(&self) -> bool {
        self.fusion || self.tv || self.stereo || self.mesh
    }

    /// The stages on the GPU in words ("TV", "fusion and TV", …).
    pub fn describe(&self) -> String {
        let names: Vec<&str> = [
            (self.fusion, "fusion"),
            (self.tv, "TV"),
            (self.stereo, "stereo"),
            (self.mesh, "meshing"),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .map(|(_, n)| *n)
        .collect();
        if names.is_empty() {
            "no stage".into()
        } else {
            names.join(" and ")
        }
    }
}

/// A class of adapter, as far as the records tell them apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterClass {
    /// A hardware GPU (discrete or integrated).
    Hardware,
    /// A software rasteriser (Mesa's lavapipe/llvmpipe: the CPU behind wgpu).
    Software,
}

impl AdapterClass {
    /// The class of an adapter that is, or is not, a software one.
    pub fn of(software: bool) -> AdapterClass {
        if software {
            AdapterClass::Software
        } else {
            AdapterClass::Hardware
        }
    }
}

/// A stage that has a GPU kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Depth and LiDAR fusion.
    Fusion,
    /// TV regularization.
    Tv,
    /// The variational stereo matchers.
    Stereo,
    /// Marching cubes.
    Mesh,
}

/// A stage the records show faster on a class of adapter than on the same machine's CPU.
#[derive(Clone, Copy, Debug)]
pub struct StageRecord {
    /// The stage.
    pub stage: Stage,
    /// The adapter class it was measured on.
    pub class: AdapterClass,
    /// Where the measurement is recorded.
    pub record: &'static str,
}

/// The records `--device auto` follows. TV: 1.7–2.1× an H100 machine's 16 cores; marching
/// cubes 8–10×; stereo 1.5–2.8× an H200 machine's; not depth fusion (1.8× slower) or LiDAR
/// fusion (1.6× slower); a software adapter is slower than
/// the CPU code at every stage (`benches/gpu.rs`).
pub const RECORDED_FASTER: &[StageRecord] = &[
    StageRecord {
        stage: Stage::Tv,
        class: AdapterClass::Hardware,
        record: "docs/bench/gpu.md, run 11 (NVIDIA H100: 2045 against 1184 M voxel-iterations/s)",
    },
    StageRecord {
        stage: Stage::Mesh,
        class: AdapterClass::Hardware,
        record: "docs/bench/gpu.md, run 14 (NVIDIA H100, `denser bench`: 7.2 against 60.5 ms at \
                 10 cm, 19.8 against 192.9 ms at 5 cm)",
    },
    StageRecord {
        stage: Stage::Stereo,
        class: AdapterClass::Hardware,
        record: "docs/bench/gpu.md, run 16 (NVIDIA H200, 1241×376 pairs: SGM 39.9 against 112.9 \
                 ms per frame, TGV-tensor 124.7 against 184.9 ms)",
    },
];
