//! Issue 12 through the library: regions as an array job on a local map (shards, a shard stopped
//! midway and run again, the committing run adopting every record: the same blocks as one
//! process), shard files kept by a writer's cleanup while their plan is open; and, against a real
//! S3 server (moto, started here on the loopback address), a map written to S3 equal to the same
//! map on disk, the manifest's compare-and-swap with one winner among simultaneous committers, and
//! a writer whose lease expired unable to commit after another took over. The same with the
//! `denser` binary: `tests/cli/scaleout.rs`.

use crate::common::Moto;
use denser::grid::{encode_tsdf, Block, BlockIndex, GridParams, Layer, OMEGA_BIT};
use denser::map::files::{Conditional, MapFiles};
use denser::map::layout::{CHUNKS_DIR, MANIFEST_FILE};
use denser::map::s3::S3Files;
use denser::map::store::MapStore;
use denser::map::MapLocation;
use denser::map::{group_by_chunk, ChunkIndex};
use denser::outofcore::regional::{
    regularize_map, regularize_shard, MapRegularizeStats, RegionalOptions,
};
use denser::outofcore::shards::Shard;
use denser::regularize::TvParams;
use std::sync::Arc;

const CHUNK_BLOCKS: u32 = 2;

fn grid() -> GridParams {
    GridParams {
        voxel_size_m: 0.1,
        truncation_m: 0.4,
    }
}

/// A wavy, noisy surface through `nx × ny` chunks (as `engine.rs`'s).
fn surface_layer(nx: i32, ny: i32, seed: u64) -> Layer {
    let mut layer = Layer::new(grid());
    let mut s = seed;
    for bz in -1..=0 {
        for by in 0..ny * CHUNK_BLOCKS as i32 {
            for bx in 0..nx * CHUNK_BLOCKS as i32 {
                let mut b = Block::new_boxed();
                for i in 0..512 {
                    let (x, y, z) = (i % 8, (i / 8) % 8, i / 64);
                    let (gx, gy, gz) = (bx * 8 + x as i32, by * 8 + y as i32, bz * 8 + z as i32);
                    let h = 2.0 * ((gx as f32) * 0.2).sin() + 1.5 * ((gy as f32) * 0.15).cos();
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let noise = ((s >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 1.5;
                    let sdf_vox = gz as f32 - h + noise;
                    if sdf_vox.abs() < 4.0 {
                        b.tsdf[i] = encode_tsdf((sdf_vox / 4.0).clamp(-1.0, 1.0));
                        b.weight_omega[i] = OMEGA_BIT | (1 + (s % 9) as u8);
                        b.color[i] = [(gx * 3) as u8, (gy * 5) as u8, 120];
                    }
                }
                if b.observed_count() > 0 {
                    layer.insert(BlockIndex([bx, by, bz]), b);
                }
            }
        }
    }
    layer
}

fn write_layer(store: &mut MapStore, layer: &Layer) {
    for (c, blocks) in group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS) {
        let refs: Vec<(BlockIndex, &Block)> = blocks
            .iter()
            .map(|b| (*b, layer.get(b).expect("block")))
            .collect();
        store.write_chunk(c, &refs, 0).expect("write");
    }
    store.commit().expect("commit");
}

fn store_layer(store: &MapStore) -> Layer {
    let mut layer = Layer::new(store.grid());
    for c in store.chunk_indices() {
        let d = store.read_chunk(c).expect("read").expect("present");
        layer.put_blocks(d.blocks);
    }
    layer
}

fn assert_layers_identical(a: &Layer, b: &Layer) {
    assert_eq!(a.indices_sorted(), b.indices_sorted(), "block sets differ");
    for i in a.indices_sorted() {
        assert!(a.get(&i) == b.get(&i), "block {i:?} differs");
    }
}

/// The maps `one` (regularized by one process with [`params`] and [`options`]) and `sharded`
/// (as written) of `layer` in `dir`, and the one-process pass's counters.
fn one_and_sharded(
    dir: &std::path::Path,
    layer: &Layer,
) -> (std::path::PathBuf, std::path::PathBuf, MapRegularizeStats) {
    let one = dir.join("one");
    let sharded = dir.join("sharded");
    for d in [&one, &sharded] {
        let mut s = MapStore::create(d, grid(), CHUNK_BLOCKS).expect("create");
        write_layer(&mut s, layer);
    }
    let mut w = MapStore::open(&one).expect("open");
    let single = regularize_map(&mut w, &params(), &options(), |_, _| true).expect("one process");
    (one, sharded, single)
}

fn options() -> RegionalOptions {
    RegionalOptions {
        region_chunks: 1,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: None,
    }
}

fn params() -> TvParams {
    TvParams {
        iterations: 6,
        ..TvParams::paper(0.1)
    }
}

#[test]
fn shard_and_location_arguments_parse() {
    let none = |_: &str| None::<String>;
    assert_eq!(
        Shard::parse_with_env("2/4", none).expect("2/4"),
        Shard { index: 2, count: 4 }
    );
    for bad in ["4/4", "1", "a/2", "1/0", "auto/3"] {
        assert!(Shard::parse_with_env(bad, none).is_err(), "{bad}");
    }
    let k8s = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "3".to_string());
    assert_eq!(Shard::parse_with_env("auto/8", k8s).expect("k8s").index, 3);
    let slurm = |k: &str| match k {
        "SLURM_ARRAY_TASK_ID" => Some("5".to_string()),
        "SLURM_ARRAY_TASK_MIN" => Some("1".to_string()),
        _ => None,
    };
    assert_eq!(
        Shard::parse_with_env("auto/8", slurm).expect("slurm").index,
        4
    );
    let batch = |k: &str| (k == "AWS_BATCH_JOB_ARRAY_INDEX").then(|| "9".to_string());
    assert!(Shard::parse_with_env("auto/8", batch).is_err(), "9 ≥ 8");

    assert_eq!(
        MapLocation::parse("s3://bucket/a/b/").expect("s3"),
        MapLocation::S3 {
            bucket: "bucket".into(),
            prefix: "a/b".into()
        }
    );
    assert_eq!(
        MapLocation::parse("maps/x").expect("dir"),
        MapLocation::Dir("maps/x".into())
    );
    assert!(MapLocation::parse("gs://bucket/x").is_err());
    // Issue 36: relative segments were written as literal keys (`%2E%2E/x`).
    for bad in ["s3://city/../x", "s3://city/a/./b", "s3://city/a//b"] {
        let e = MapLocation::parse(bad).expect_err(bad).to_string();
        assert!(e.contains("segments"), "{bad}: {e}");
    }
    assert_eq!(
        MapLocation::parse("s3://city").expect("bucket only"),
        MapLocation::S3 {
            bucket: "city".into(),
            prefix: String::new()
        }
    );
    assert_eq!(
        MapLocation::parse("s3://bucket/p").expect("s3").to_string(),
        "s3://bucket/p"
    );
}

/// Three shards on a local map, the second stopped after its first region and its record lost
/// (files written, record not: a kill between the two), then run again; the committing run adopts
/// every record, solves nothing itself, and leaves exactly the blocks of a one-process pass.
#[test]
fn sharded_regularization_equals_one_process_on_disk() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (one, sharded, single) = one_and_sharded(dir.path(), &surface_layer(4, 3, 7));
    let regions = single.regions;
    assert!(regions >= 6, "{regions} regions");

    let run_shard = |index: u32, stop_after: Option<usize>| {
        let mut r = MapStore::open_read_only(&sharded).expect("reader");
        let mut solved = 0;
        regularize_shard(
            &mut r,
            &params(),
            &options(),
            Shard { index, count: 3 },
            |_, _| {
                solved += 1;
                stop_after.is_none_or(|n| solved < n)
            },
            |p, prm| {
                p.solve(prm);
                Ok(())
            },
        )
        .expect("shard")
    };
    let s0 = run_shard(0, None);
    let s1 = run_shard(1, Some(1));
    assert_eq!(s1.regions, 1, "stopped after one region");
    // The record of that region is lost (killed between the files and the record).
    let records: Vec<_> = std::fs::read_dir(sharded.join("shards"))
        .expect("shards/")
        .flat_map(|k| std::fs::read_dir(k.expect("key").path().join("regions")).expect("regions"))
        .map(|e| e.expect("record").path())
        .collect();
    assert_eq!(records.len(), s0.regions + 1);
    let lost = records
        .iter()
        .find(|p| {
            std::fs::read_to_string(p)
                .expect("read")
                .contains("\"1/3\"")
        })
        .expect("shard 1's record");
    std::fs::remove_file(lost).expect("lose the record");
    // A writer opening the map meanwhile keeps the shards' files (their plan is open).
    let (w, cleanup) = MapStore::open_with_cleanup(&sharded).expect("writer");
    assert!(cleanup.removed_uncommitted.is_empty(), "{cleanup:?}");
    assert!(cleanup.shard_files_kept > 0, "{cleanup:?}");
    drop(w);
    let s1 = run_shard(1, None);
    let s2 = run_shard(2, None);
    assert_eq!(s0.regions + s1.regions + s2.regions, regions);

    let mut w = MapStore::open(&sharded).expect("committer");
    let fin = regularize_map(&mut w, &params(), &options(), |_, _| true).expect("final");
    assert_eq!(fin.regions_adopted, regions, "{fin:?}");
    assert_eq!(fin.regions, 0, "nothing left to solve");
    let m = w.manifest();
    assert!(m.chunks.values().all(|e| e.reg_pass == fin.pass));
    assert_eq!(m.header.complete_pass, fin.pass);
    let a = MapStore::open_read_only(&one).expect("one");
    assert_layers_identical(&store_layer(&a), &store_layer(&w));
    assert!(w.verify().is_empty(), "{:?}", w.verify());
    // The plans are closed and no chunk file is left that the manifest does not name.
    assert!(!sharded.join("shards").exists(), "plans left");
    drop(w);
    let n_files = std::fs::read_dir(sharded.join(CHUNKS_DIR))
        .expect("ls")
        .filter(|e| {
            e.as_ref()
                .expect("e")
                .file_name()
                .to_string_lossy()
                .ends_with(".dchk")
        })
        .count();
    assert_eq!(n_files, a.chunk_indices().len(), "one file per chunk");
}

/// Issue 36 item 3: a shard's chunk file with one payload byte flipped (its header intact) was
/// adopted, the pass committed and the chunk's previous file deleted: the chunk was lost. Adoption
/// now reads every recorded file as the engine reads a committed one; the damaged region is
/// refused and solved again, and the map ends equal to a one-process pass.
#[test]
fn a_shard_file_with_a_flipped_payload_byte_is_not_adopted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (one, sharded, single) = one_and_sharded(dir.path(), &surface_layer(4, 3, 11));
    let shard = super::engine::run_local_shard(&sharded, &params(), Shard { index: 0, count: 1 });
    assert_eq!(shard.regions, single.regions);
    // One of the shard's files (numbered in its plan's reserved range, far above the
    // manifest's) gets one payload byte flipped; its header and CRC fields stay as written.
    let before = MapStore::open_read_only(&sharded).expect("reader");
    let next = before.manifest().header.next_file_seq;
    drop(before);
    let mut shard_files: Vec<_> = std::fs::read_dir(sharded.join(CHUNKS_DIR))
        .expect("ls")
        .map(|e| e.expect("entry").path())
        .filter(|p| {
            let name = p.file_name().expect("name").to_string_lossy().into_owned();
            denser::map::manifest::parse_chunk_file_name(&name).is_some_and(|(_, seq)| seq >= next)
        })
        .collect();
    shard_files.sort();
    assert!(!shard_files.is_empty(), "the shard wrote its files");
    let victim = &shard_files[shard_files.len() / 2];
    let mut bytes = std::fs::read(victim).expect("read");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x5a;
    std::fs::write(victim, &bytes).expect("flip a payload byte");

    let mut w = MapStore::open(&sharded).expect("committer");
    let fin = regularize_map(&mut w, &params(), &options(), |_, _| true).expect("final");
    assert_eq!(fin.regions_adopted, single.regions - 1, "{fin:?}");
    assert_eq!(
        fin.regions, 1,
        "the damaged region is solved again: {fin:?}"
    );
    assert!(w.verify().is_empty(), "{:?}", w.verify());
    assert_eq!(
        w.chunk_indices(),
        MapStore::open_read_only(&one).expect("one").chunk_indices()
    );
    let a = MapStore::open_read_only(&one).expect("one");
    assert_layers_identical(&store_layer(&a), &store_layer(&w));
}

pub(crate) fn s3_files(
    moto: &Moto,
    bucket: &str,
    prefix: &str,
    extra: &[(&str, &str)],
) -> Arc<dyn MapFiles> {
    let opts = moto.options();
    let mut all: Vec<(&str, &str)> = opts.iter().map(|(k, v)| (*k, v.as_str())).collect();
    all.extend_from_slice(extra);
    Arc::new(S3Files::with_options(bucket, prefix, all).expect("S3 client"))
}

/// A map written to S3 decodes to the same blocks as the same map on disk; a sharded pass over
/// it equals the one-process pass on disk; superseded files wait for the retention period.
#[test]
fn a_map_on_s3_equals_the_map_on_disk() {
    let Some(moto) = Moto::start() else { return };
    moto.create_bucket("maps");
    let dir = tempfile::tempdir().expect("tempdir");
    let layer = surface_layer(3, 2, 11);
    let mut disk = MapStore::create(&dir.path().join("m"), grid(), CHUNK_BLOCKS).expect("disk");
    write_layer(&mut disk, &layer);
    let files = s3_files(&moto, "maps", "city/a", &[]);
    let mut s3 = MapStore::create_files(files.clone(), grid(), CHUNK_BLOCKS).expect("s3 map");
    write_layer(&mut s3, &layer);
    assert_eq!(s3.chunk_indices(), disk.chunk_indices());
    assert_layers_identical(&store_layer(&s3), &store_layer(&disk));
    assert!(s3
        .dir()
        .display()
        .to_string()
        .starts_with("s3://maps/city/a"));
    drop(s3);
    // Reopened by a reader, and by a writer (which commits once: fencing).
    let r = MapStore::open_read_only_files(files.clone()).expect("reader");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    let g = r.manifest().header.generation;
    assert_layers_identical(&store_layer(&r), &layer_of(&disk));
    drop(r);

    let mut w = MapStore::open_files(files.clone()).expect("writer");
    assert_eq!(w.manifest().header.generation, g + 1, "fencing commit");
    let one = regularize_map(&mut disk, &params(), &options(), |_, _| true).expect("disk pass");
    // Two shards on S3, then the committing run.
    drop(w);
    for index in 0..2 {
        let mut r = MapStore::open_read_only_files(files.clone()).expect("shard reader");
        regularize_shard(
            &mut r,
            &params(),
            &options(),
            Shard { index, count: 2 },
            |_, _| true,
            |p, prm| {
                p.solve(prm);
                Ok(())
            },
        )
        .expect("shard");
    }
    w = MapStore::open_files(files.clone()).expect("committer");
    let fin = regularize_map(&mut w, &params(), &options(), |_, _| true).expect("final");
    assert_eq!(fin.regions_adopted, one.regions);
    assert_layers_identical(&store_layer(&w), &store_layer(&disk));
    // The fused files the pass superseded are listed for deletion after the retention period,
    // not deleted: a reader that opened before the pass still reads them.
    let gc = files.list("gc").expect("gc/");
    assert!(!gc.is_empty(), "deletion records");
    let listed = files.list(CHUNKS_DIR).expect("chunks/");
    assert_eq!(
        listed.len(),
        2 * w.chunk_indices().len(),
        "old and new versions"
    );
}

fn layer_of(s: &MapStore) -> Layer {
    store_layer(s)
}

/// Eight threads commit the manifest at once against the version they all read: exactly one
/// compare-and-swap succeeds.
#[test]
fn simultaneous_manifest_commits_on_s3_have_one_winner() {
    let Some(moto) = Moto::start() else { return };
    moto.create_bucket("cas");
    let files = s3_files(&moto, "cas", "m", &[]);
    let s = MapStore::create_files(files.clone(), grid(), CHUNK_BLOCKS).expect("create");
    drop(s);
    let (bytes, v0) = files
        .read_versioned(MANIFEST_FILE)
        .expect("read")
        .expect("manifest");
    let barrier = Arc::new(std::sync::Barrier::new(8));
    let handles: Vec<_> = (0..8)
        .map(|k| {
            let (files, barrier, v0) = (files.clone(), barrier.clone(), v0.clone());
            let mut b = bytes.clone();
            b.push(k as u8);
            std::thread::spawn(move || {
                barrier.wait();
                files
                    .write_if(MANIFEST_FILE, &b, Some(&v0))
                    .expect("request")
            })
        })
        .collect();
    let won = handles
        .into_iter()
        .map(|h| h.join().expect("thread"))
        .filter(|r| matches!(r, Conditional::Written(_)))
        .count();
    assert_eq!(won, 1, "exactly one compare-and-swap wins");
    // Create-only on an existing object is refused too.
    assert_eq!(
        files
            .write_if(MANIFEST_FILE, &bytes, None)
            .expect("request"),
        Conditional::Conflict
    );
}

/// A writer paused past its lease: another writer takes the lease over, fences with a commit and
/// commits; the paused writer's commit is then refused, and its chunk file is not in the map.
#[test]
fn a_writer_whose_lease_expired_cannot_commit_on_s3() {
    let Some(moto) = Moto::start() else { return };
    moto.create_bucket("lease");
    let no_renew = [("denser_lease_s", "3"), ("denser_lease_renew", "false")];
    let files_a = s3_files(&moto, "lease", "m", &no_renew);
    let mut a = MapStore::create_files(files_a, grid(), CHUNK_BLOCKS).expect("create");
    let files_b = s3_files(&moto, "lease", "m", &[]);
    // While A's lease runs, B is refused at once, naming A.
    let refused = MapStore::open_files(files_b.clone()).expect_err("lease held");
    assert!(
        refused.to_string().contains("locked by another writer"),
        "{refused}"
    );
    let layer = surface_layer(2, 1, 3);
    let blocks = layer.indices_sorted();
    let (c0, c1) = (ChunkIndex([0, 0, -1]), ChunkIndex([1, 0, -1]));
    let part = |c: ChunkIndex| -> Vec<(BlockIndex, &Block)> {
        blocks
            .iter()
            .filter(|b| ChunkIndex::of_block(**b, CHUNK_BLOCKS) == c)
            .map(|b| (*b, layer.get(b).expect("block")))
            .collect()
    };
    a.write_chunk(c0, &part(c0), 0).expect("A writes");
    std::thread::sleep(std::time::Duration::from_millis(4500));
    let mut b = MapStore::open_files(files_b.clone()).expect("B takes the expired lease");
    b.write_chunk(c1, &part(c1), 0).expect("B writes");
    b.commit().expect("B commits");
    let err = a.commit().expect_err("A's commit is refused");
    assert!(matches!(err, denser::Error::CommitConflict { .. }), "{err}");
    let committed = MapStore::open_read_only_files(files_b).expect("reader");
    assert_eq!(committed.chunk_indices(), vec![c1], "only B's chunk");
    assert!(committed.verify().is_empty());
}
