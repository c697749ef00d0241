//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// Says that the running test skips (part of) its checks, on a line of its own that the test
/// harness does not capture, so a reader of `cargo test`'s output can count them:
/// `SKIPPED <test name>: <reason>` (`.ci/run` prints the count).
pub fn skip(reason: &str) {
    use std::io::Write;
    let thread = std::thread::current();
    let name = thread.name().unwrap_or("?");
    // Written to the process's stderr directly: libtest captures `eprintln!`, not this.
    let _ = writeln!(std::io::stderr().lock(), "SKIPPED {name}: {reason}");
}

/// `../shared/data/<sub>` relative to the project root, or `None` (with a counted [`skip`]
/// message) when that folder is absent, as on a fresh clone.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(sub);
    if p.exists() {
        Some(p)
    } else {
        skip(&format!(
            "{} is absent (real data lives in ../shared/data)",
            p.display()
        ));
        None
    }
}

use denser::camera::PinholeIntrinsics;
use denser::frame::{DepthFrame, Image, LidarScan};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// SplitMix64 with uniform and Gaussian draws: a deterministic generator for tests.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box–Muller).
    pub fn gaussian(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// A camera pose at `eye` looking at `target`, y-down world (x right, y down, z forward).
pub fn look_at(eye: [f64; 3], target: [f64; 3]) -> Isometry3<f64> {
    let eye = Vector3::from(eye);
    let z = (Vector3::from(target) - eye).normalize();
    let x = Vector3::new(0.0, 1.0, 0.0).cross(&z).normalize();
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(eye),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// The analytic test scene: a sphere above a floor (y-down world: the floor is the plane y = floor_y,
/// free space at y < floor_y).
#[derive(Clone, Copy, Debug)]
pub struct SphereScene {
    pub center: [f64; 3],
    pub radius: f64,
    pub floor_y: f64,
}

impl SphereScene {
    pub fn standard() -> Self {
        SphereScene {
            center: [0.0, 0.0, 0.0],
            radius: 1.0,
            floor_y: 1.0,
        }
    }

    /// Exact signed distance, positive in free space.
    pub fn sdf(&self, p: [f64; 3]) -> f64 {
        let d = Vector3::from(p) - Vector3::from(self.center);
        (d.norm() - self.radius).min(self.floor_y - p[1])
    }

    /// Nearest hit along `origin + t·dir` (t > 0), in units of `dir`.
    pub fn cast(&self, origin: Vector3<f64>, dir: Vector3<f64>) -> Option<f64> {
        let mut best = f64::INFINITY;
        let oc = origin - Vector3::from(self.center);
        let (a, b, c) = (
            dir.dot(&dir),
            2.0 * oc.dot(&dir),
            oc.dot(&oc) - self.radius * self.radius,
        );
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            let t = (-b - disc.sqrt()) / (2.0 * a);
            if t > 1e-9 {
                best = t;
            }
        }
        if dir[1] > 1e-12 {
            let t = (self.floor_y - origin[1]) / dir[1];
            if t > 1e-9 && t < best {
                best = t;
            }
        }
        best.is_finite().then_some(best)
    }

    /// A depth frame seen from `world_from_camera`; Gaussian depth noise of `noise_m` (0 for none).
    /// Pixels farther than `max_depth_m` are NaN. Colour encodes the hit position.
    pub fn render(
        &self,
        k: &PinholeIntrinsics,
        world_from_camera: Isometry3<f64>,
        noise_m: f64,
        max_depth_m: f64,
        rng: &mut Rng,
    ) -> DepthFrame {
        let mut depth = Image::filled(k.width, k.height, f32::NAN);
        let mut color = Image::filled(k.width, k.height, [0u8; 3]);
        let origin = world_from_camera.translation.vector;
        for v in 0..k.height {
            for u in 0..k.width {
                let dir = world_from_camera.rotation * k.ray(u as f64, v as f64);
                if let Some(t) = self.cast(origin, dir) {
                    if t <= max_depth_m {
                        *depth.at_mut(u, v) = (t + noise_m * rng.gaussian()) as f32;
                        let p = origin + dir * t;
                        *color.at_mut(u, v) = if p[1] > self.floor_y - 1e-6 {
                            [90, 90, 90]
                        } else {
                            [200, 40, 40]
                        };
                    }
                }
            }
        }
        DepthFrame {
            intrinsics: *k,
            world_from_camera,
            depth_m: depth,
            color: Some(color),
        }
    }

    /// A LiDAR sweep from a sensor at `origin` (axes aligned with the world): `rings` elevations
    /// in [−30°, +10°] (negative looks down, towards +y) × `steps` azimuths.
    pub fn lidar(
        &self,
        origin: [f64; 3],
        rings: usize,
        steps: usize,
        noise_m: f64,
        rng: &mut Rng,
    ) -> LidarScan {
        let mut scan = LidarScan {
            world_from_sensor: Isometry3::translation(origin[0], origin[1], origin[2]),
            ..Default::default()
        };
        for r in 0..rings {
            let elev = (-30.0 + 40.0 * r as f64 / (rings - 1) as f64).to_radians();
            for s in 0..steps {
                let az = 2.0 * std::f64::consts::PI * s as f64 / steps as f64;
                let dir = Vector3::new(elev.cos() * az.cos(), -elev.sin(), elev.cos() * az.sin());
                if let Some(t) = self.cast(Vector3::from(origin), dir) {
                    let t = t + noise_m * rng.gaussian();
                    let p = dir * t;
                    scan.points_sensor_m
                        .push([p[0] as f32, p[1] as f32, p[2] as f32]);
                    scan.intensity.push(0.5);
                }
            }
        }
        scan
    }
}

/// Intrinsics of a 640×480 RGB-D-like camera (fx = fy = 525).
pub fn vga() -> PinholeIntrinsics {
    PinholeIntrinsics {
        fx: 525.0,
        fy: 525.0,
        cx: 319.5,
        cy: 239.5,
        width: 640,
        height: 480,
    }
}

/// `n` camera poses on a circle of radius `r` around the scene centre, at height `y` (y-down).
pub fn orbit(n: usize, r: f64, y: f64, target: [f64; 3]) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|k| {
            let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            look_at(
                [target[0] + r * a.cos(), y, target[2] + r * a.sin()],
                target,
            )
        })
        .collect()
}

#[allow(unused)]
pub fn point(p: [f32; 3]) -> Point3<f64> {
    Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// The GPU of a GPU test: `None` (saying the test is skipped) where no adapter exists; a panic
/// where one exists but fails to open.
pub fn gpu() -> Option<denser::gpu::GpuContext> {
    match denser::gpu::GpuContext::new() {
        Ok(Some(ctx)) => {
            eprintln!("GPU: {}", ctx.describe());
            Some(ctx)
        }
        Ok(None) => {
            skip("no GPU adapter (tools/setup.sh installs lavapipe)");
            None
        }
        Err(e) => panic!("a GPU adapter exists but failed: {e}"),
    }
}

/// The GPU of a benchmark: `None`, saying the GPU half is skipped, without a working adapter.
pub fn bench_gpu() -> Option<denser::gpu::GpuContext> {
    match denser::gpu::GpuContext::new() {
        Ok(Some(ctx)) => {
            eprintln!("GPU: {}", ctx.describe());
            Some(ctx)
        }
        Ok(None) => {
            eprintln!("no GPU adapter: GPU benchmarks skipped");
            None
        }
        Err(e) => {
            eprintln!("GPU failed, GPU benchmarks skipped: {e}");
            None
        }
    }
}

/// Per-call GPU depth fusion of one frame, planned as the CPU plans it
/// ([`denser::fusion::DepthPlan`]).
pub fn fuse_depth_gpu(
    ctx: &denser::gpu::GpuContext,
    layer: &mut denser::grid::Layer,
    frame: &DepthFrame,
    params: &denser::fusion::DepthFusionParams,
) -> denser::Result<(denser::grid::TouchedBlocks, denser::fusion::FusionStats)> {
    let plan = denser::fusion::DepthPlan::new(&layer.params(), frame, params);
    denser::fusion::integrate_depth_gpu(ctx, layer, frame, params, &plan)
}

/// GPU depth fusion of one frame into the blocks resident in `map`.
pub fn fuse_depth_resident(
    map: &mut denser::gpu::ResidentMap,
    layer: &mut denser::grid::Layer,
    frame: &DepthFrame,
    params: &denser::fusion::DepthFusionParams,
) -> denser::Result<(denser::grid::TouchedBlocks, denser::fusion::FusionStats)> {
    let plan = denser::fusion::DepthPlan::new(&layer.params(), frame, params);
    denser::fusion::integrate_depth_resident(map, layer, frame, params, &plan)
}

/// A reconstructor over `layer` (in RAM) with the stages of `backend`.
pub fn reconstructor_over(
    config: denser::reconstruct::ReconstructionConfig,
    layer: denser::grid::Layer,
    backend: denser::backend::Backend,
) -> denser::reconstruct::Reconstructor {
    denser::reconstruct::Reconstructor::with_store(
        config,
        Box::new(denser::store::MemoryStore::from_layer(layer)),
        backend,
        0,
    )
    .expect("reconstructor")
}

/// An S3-compatible server (moto's server mode, installed by `tools/setup.sh`) on a free port of
/// the loopback address, for one test; killed when dropped, a panicking test included.
pub struct Moto {
    child: std::process::Child,
    /// Its port.
    pub port: u16,
}

impl Moto {
    /// Starts `moto_server -H 127.0.0.1 -p PORT` and waits until it answers; `None` (with a
    /// counted [`skip`]) when moto is not installed or does not start.
    pub fn start() -> Option<Moto> {
        use std::io::Read;
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .ok()?;
        let child = std::process::Command::new("moto_server")
            .args(["-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn();
        let mut child = match child {
            Ok(c) => c,
            Err(e) => {
                skip(&format!(
                    "moto_server cannot start ({e}): `pip install 'moto[server]'` (tools/setup.sh)"
                ));
                return None;
            }
        };
        let t0 = std::time::Instant::now();
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                let mut err = String::new();
                if let Some(mut e) = child.stderr.take() {
                    let _ = e.read_to_string(&mut err);
                }
                skip(&format!("moto_server exited ({status}): {err}"));
                return None;
            }
            if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
                break;
            }
            if t0.elapsed() > std::time::Duration::from_secs(60) {
                let _ = child.kill();
                let _ = child.wait();
                skip("moto_server did not answer within 60 s");
                return None;
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        // Its log goes nowhere: a full pipe must not block it.
        drop(child.stderr.take());
        Some(Moto { child, port })
    }

    /// `http://127.0.0.1:PORT`.
    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// Creates a bucket (moto accepts an unsigned `PUT /bucket`).
    pub fn create_bucket(&self, name: &str) {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(("127.0.0.1", self.port)).expect("connect moto");
        write!(
            s,
            "PUT /{name} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
            self.port
        )
        .expect("send");
        let mut reply = String::new();
        let _ = s.read_to_string(&mut reply);
        assert!(
            reply.starts_with("HTTP/1.1 200") || reply.starts_with("HTTP/1.0 200"),
            "creating bucket {name}: {reply}"
        );
    }

    /// The `AWS_*` environment of a `denser` child process using this server.
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            ("AWS_ENDPOINT_URL", self.endpoint()),
            ("AWS_ACCESS_KEY_ID", "testing".into()),
            ("AWS_SECRET_ACCESS_KEY", "testing".into()),
            ("AWS_REGION", "us-east-1".into()),
            ("AWS_ALLOW_HTTP", "true".into()),
        ]
    }

    /// The same settings as `object_store` configuration keys, for the library in this process
    /// (`S3Files::with_options`) without touching the test process's environment.
    pub fn options(&self) -> Vec<(&'static str, String)> {
        vec![
            ("aws_endpoint", self.endpoint()),
            ("aws_access_key_id", "testing".into()),
            ("aws_secret_access_key", "testing".into()),
            ("aws_region", "us-east-1".into()),
            ("aws_allow_http", "true".into()),
        ]
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The grids the band tests use: (voxel, μ) of 10 cm and 5 cm voxels with wide and narrow
/// truncations.
pub const BAND_GRIDS: [denser::grid::GridParams; 4] = [
    band_grid(0.1, 0.8),
    band_grid(0.05, 0.4),
    band_grid(0.1, 0.3),
    band_grid(0.05, 0.2),
];

const fn band_grid(voxel_size_m: f32, truncation_m: f32) -> denser::grid::GridParams {
    denser::grid::GridParams {
        voxel_size_m,
        truncation_m,
    }
}

/// The truncations of [`BAND_GRIDS`], metres (what [`band_test_frame`] takes).
pub fn band_test_mus() -> Vec<f64> {
    BAND_GRIDS.iter().map(|g| g.truncation_m as f64).collect()
}

/// A depth frame that exercises every decision of the band's tile lister
/// (`denser::fusion::band_slices`): a floor seen at grazing angles out to 30 m, a box in front
/// of a wall (gaps inside tiles), holes, infinities, negative and out-of-range depths, a width
/// and height that are no multiples of 8 (tiles cut at the borders), and, for each μ of `mus`,
/// tiles holding just two depths whose f32 difference lies within a few ULPs of 2μ or of μ/2
/// (the thresholds, where rounding decides).
pub fn band_test_frame(seed: u64, mus: &[f64]) -> DepthFrame {
    let (w, h) = (203u32, 157u32);
    let k = PinholeIntrinsics {
        fx: 180.0,
        fy: 180.0,
        cx: 101.0,
        cy: 60.0,
        width: w,
        height: h,
    };
    let mut rng = Rng(seed);
    let mut data: Vec<f32> = (0..w * h)
        .map(|p| {
            let (u, v) = ((p % w) as f32, (p / w) as f32);
            let r = rng.uniform();
            match () {
                _ if r < 0.02 => f32::NAN,
                _ if r < 0.03 => [f32::INFINITY, -2.0, 0.05, 55.0, -0.0][(r * 1e4) as usize % 5],
                _ if (60.0..130.0).contains(&u) && (20.0..70.0).contains(&v) => 2.0 + 0.003 * u,
                // The floor: depth grows without bound towards the horizon (row 60).
                _ if v > 64.0 => (1.5 * 180.0 / (v - 60.0)).min(30.0),
                _ => 6.0 + 0.01 * u + 0.1 * (r as f32),
            }
        })
        .collect();
    // Threshold tiles along the top four rows: two depths, the rest unusable.
    let thresholds: Vec<f64> = mus.iter().flat_map(|&mu| [2.0 * mu, 0.5 * mu]).collect();
    let tiles_x = w / 8;
    for t in 0..tiles_x * 4 {
        let (u0, v0) = ((t % tiles_x) * 8, (t / tiles_x) * 8);
        for dv in 0..8 {
            for du in 0..8 {
                data[((v0 + dv) * w + u0 + du) as usize] = f32::NAN;
            }
        }
        let gap = thresholds[t as usize % thresholds.len()];
        // A near depth in [0.25, 0.5) m and a far one 2μ or μ/2 further, give or take up to
        // three ULPs: across binades, so that the f32 difference rounds (ties included).
        let lo = (0.25 + 0.25 * rng.uniform()) as f32;
        let ulps = (rng.next_u64() % 7) as i32 - 3;
        let hi = f32::from_bits(
            ((lo as f64 + gap) as f32)
                .to_bits()
                .wrapping_add_signed(ulps),
        );
        data[(v0 * w + u0) as usize] = lo;
        data[((v0 + 1 + t % 7) * w + u0 + t % 5) as usize] = hi;
    }
    let pose = Isometry3::new(Vector3::new(0.3, -1.2, 0.7), Vector3::new(0.2, 0.1, 0.05));
    DepthFrame {
        intrinsics: k,
        world_from_camera: pose,
        depth_m: Image {
            width: w,
            height: h,
            data,
        },
        color: None,
    }
}
