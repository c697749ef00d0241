//! Help texts of flags that several commands share, written once (a test checks that a flag
//! has one help text wherever it appears).

/// `--gt`.
pub const GT: &str = "Ground truth: a .las/.laz/.ply file, or a KITTI sequence folder, a folder \
    of scans or a ROS 2 bag whose scans are merged in the world frame (reconstruct's default for \
    LiDAR input: the input's own scans, as the paper)";
/// `--poses`.
pub const POSES: &str = "Poses: a KITTI sequence's poses file (when not at \
    `<root>/poses/NN.txt`), or a folder of scans' trajectory (TUM `t x y z qx qy qz qw` or KITTI \
    3×4 lines) [default for a folder of scans: trajectory.tum, trajectory.txt or poses.txt in it]";
/// `--method`.
pub const METHOD: &str = "Stereo matcher";
/// `--num-disparities`.
pub const NUM_DISPARITIES: &str =
    "Disparity search range from 0, pixels (128 sees down to ~3 m on KITTI)";
/// `--seed`.
pub const SEED: &str = "Seed of the city (same seed, same bytes)";
/// `--out`.
pub const OUT: &str = "Where the command writes: a folder (reconstruct, demo, evaluate, \
    synth), the disparity file (stereo: PFM) or the new map (merge); see the command's help";
/// `--mesh`.
pub const MESH: &str = "A mesh (binary PLY): the meshes evaluate scores (`LABEL=PATH.ply` or \
    `PATH.ply`, the first the baseline), or the mesh export writes";
/// `--memory-budget`.
pub const MEMORY_BUDGET: &str = "Memory budget of the process (e.g. 1GiB, 512MiB): a \
    quarter of it, at most 64 MiB, is kept for the process itself, the rest holds the \
    command's data (resident voxel blocks, one regularization region, the chunks being \
    merged or meshed, the COPC octree before it spills to disk, the evaluation's index and \
    pictures). In reconstruct --map (its evaluation included), regularize, merge, export and \
    evaluate, peak RSS stays within this + 64 MiB (docs/bench/memory.md)";
/// `--shard`.
pub const SHARD: &str = "Do only this task's share of the work (regularize: regions; \
    export: chunks) as task I of an array job of N, or auto/N (the index from \
    JOB_COMPLETION_INDEX, SLURM_ARRAY_TASK_ID or AWS_BATCH_JOB_ARRAY_INDEX). Shards take no \
    lock and commit nothing; the same command without --shard afterwards adopts their \
    results, does what is missing and finishes";
/// `--json`.
pub const JSON: &str = "Print JSON instead of text";
/// `--device`.
pub const DEVICE: &str = "Where stereo (every method), fusion, regularization and meshing \
    (an in-memory run's, and export's chunks) run (`auto`: each where it was measured faster, \
    docs/bench/gpu.md) [default: auto; bench's: cpu, so its recorded figures stay comparable; export's: cpu, \
    chunk-by-chunk meshing not yet measured faster on a GPU]";
/// `--max-depth-m`.
pub const MAX_DEPTH_M: &str = "Ignore depths (and LiDAR returns) beyond this, metres \
    [reconstruct's default: 40 for depth maps, 80 for LiDAR; bench's: 10]";

/// `--kernel-times` (`reconstruct`, `stereo`).
pub(crate) const KERNEL_TIMES: &str = "With the GPU: time each kernel on the device (timestamp queries, where the adapter has them) and print the table. Timing adds a wait per submit, so the stages' times grow";
