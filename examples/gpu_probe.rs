//! What the primitives under every GPU call cost on this machine's adapter: a round trip, a
//! dispatch, uploads and readbacks of a buffer the size of the KITTI cost volume (60 MB), the
//! copy out of mapped memory, and the same copy between two host buffers. `docs/bench/gpu.md`
//! reads the GPU paths' times against these. Plain wgpu on the adapter `GpuContext` would open;
//! no denser code is timed.
//!
//! `cargo run --release --example gpu_probe [MIB]` (default 60 MiB; medians of 9 after 2 warm-ups).

use std::time::Instant;
use wgpu::util::DeviceExt;

const KERNEL: &str = r#"
@group(0) @binding(0) var<storage, read_write> buf: array<u32>;
@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) n: vec3<u32>,
        @builtin(local_invocation_index) l: u32) {
    let i = (wg.x + wg.y * n.x) * 256u + l;
    if (i < arrayLength(&buf)) {
        buf[i] = buf[i] + 1u;
    }
}
"#;

fn median_ms(mut f: impl FnMut()) -> f64 {
    for _ in 0..2 {
        f();
    }
    let mut t: Vec<f64> = (0..9)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[4]
}

fn main() {
    let mib: u64 = std::env::args()
        .nth(1)
        .map_or(60, |a| a.parse().expect("size in MiB"));
    let bytes = mib << 20;
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter =
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
            .expect("no GPU adapter");
    let info = adapter.get_info();
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("probe"),
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .expect("device");
    println!(
        "adapter: {} ({:?}, {:?}), buffer {mib} MiB",
        info.name, info.device_type, info.backend
    );
    let wait = || {
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .expect("poll");
    };
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("add"),
        source: wgpu::ShaderSource::Wgsl(KERNEL.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("add"),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    let host: Vec<u8> = (0..bytes).map(|i| i as u8).collect();
    let storage_usage =
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
    let big = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("big"),
        contents: &host,
        usage: storage_usage,
    });
    let small = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("small"),
        contents: &[0u8; 1024],
        usage: storage_usage,
    });
    let bind = |b: &wgpu::Buffer| {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: b.as_entire_binding(),
            }],
        })
    };
    let (bind_big, bind_small) = (bind(&big), bind(&small));
    let groups = (bytes / 4).div_ceil(256) as u32;
    let (gx, gy) = (groups.min(65535), groups.div_ceil(65535));
    let dispatch = |passes: usize, bg: &wgpu::BindGroup, x: u32, y: u32| {
        let mut enc = device.create_command_encoder(&Default::default());
        for _ in 0..passes {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, bg, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        queue.submit([enc.finish()]);
        wait();
    };
    let staging = |size: u64| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("staging"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    };
    let read_into = |s: &wgpu::Buffer, copy_out: bool| -> f64 {
        let mut enc = device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&big, 0, s, 0, bytes);
        queue.submit([enc.finish()]);
        s.slice(..)
            .map_async(wgpu::MapMode::Read, |r| r.expect("map"));
        wait();
        let t = Instant::now();
        if copy_out {
            let v = s.slice(..).get_mapped_range().expect("mapped").to_vec();
            std::hint::black_box(v);
        }
        let ms = t.elapsed().as_secs_f64() * 1e3;
        s.unmap();
        ms
    };
    let reused = staging(bytes);
    let mut rows: Vec<(&str, f64)> = vec![
        (
            "round trip: empty submit + wait",
            median_ms(|| {
                queue.submit([device.create_command_encoder(&Default::default()).finish()]);
                wait();
            }),
        ),
        (
            "one dispatch of 1 workgroup + wait",
            median_ms(|| dispatch(1, &bind_small, 1, 1)),
        ),
        (
            "100 dispatches of 1 workgroup, one submit + wait",
            median_ms(|| dispatch(100, &bind_small, 1, 1)),
        ),
        (
            "one dispatch over the buffer (+1 per u32) + wait",
            median_ms(|| dispatch(1, &bind_big, gx, gy)),
        ),
        (
            "upload: create_buffer_init + wait",
            median_ms(|| {
                let b = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: None,
                    contents: &host,
                    usage: storage_usage,
                });
                queue.submit([]);
                wait();
                drop(b);
            }),
        ),
        (
            "upload: write_buffer into a kept buffer + wait",
            median_ms(|| {
                queue.write_buffer(&big, 0, &host);
                queue.submit([]);
                wait();
            }),
        ),
        (
            "readback into a fresh staging buffer, copied out",
            median_ms(|| {
                read_into(&staging(bytes), true);
            }),
        ),
        (
            "readback into a kept staging buffer, copied out",
            median_ms(|| {
                read_into(&reused, true);
            }),
        ),
        (
            "readback into a kept staging buffer, not copied out",
            median_ms(|| {
                read_into(&reused, false);
            }),
        ),
    ];
    let mut copy_fresh = Vec::new();
    let mut copy_kept = Vec::new();
    for _ in 0..9 {
        copy_fresh.push(read_into(&staging(bytes), true));
        copy_kept.push(read_into(&reused, true));
    }
    copy_fresh.sort_by(f64::total_cmp);
    copy_kept.sort_by(f64::total_cmp);
    rows.push(("of which the copy out of a fresh mapping", copy_fresh[4]));
    rows.push(("of which the copy out of a kept mapping", copy_kept[4]));
    rows.push((
        "host memcpy of the same size (Vec clone)",
        median_ms(|| {
            std::hint::black_box(host.clone());
        }),
    ));
    for (what, ms) in rows {
        let gbs = bytes as f64 / (ms * 1e-3) / 1e9;
        println!("{what:<56} {ms:>9.3} ms  ({gbs:.1} GB/s at the buffer's size)");
    }
}
