//! The map store as a storage engine (issue 15, items 1–4), through the library: one writer per
//! map (a second is refused naming the holder; a dead holder's lock is recovered); readers keep
//! the files of their manifest while a writer commits; a writer's cleanup removes only provable
//! leftovers; every read checks the file against its manifest entry (a swapped chunk is refused by
//! reads, `verify` and regularization); a lost manifest is refused by every opener and rebuilt by
//! `repair` with the same entries; an interrupted regularization pass keeps the last complete pass
//! readable whole until it completes; format-1 maps still open. The same through the CLI, with
//! real processes: `tests/cli_engine.rs`.

use denser::grid::{encode_tsdf, Block, BlockIndex, GridParams, Layer, OMEGA_BIT};
use denser::map::codec::{encode_chunk, ChunkHeader};
use denser::map::layout::{CHUNKS_DIR, LOCK_FILE, MANIFEST_FILE};
use denser::map::lock::WriterLock;
use denser::map::manifest::{chunk_file_name, encode_manifest};
use denser::map::repair::repair;
use denser::map::store::MapStore;
use denser::map::{group_by_chunk, ChunkIndex};
use denser::outofcore::regional::{regularize_map, RegionalOptions};
use denser::regularize::TvParams;
use denser::Error;
use std::path::Path;

pub(crate) const CHUNK_BLOCKS: u32 = 2;

pub(crate) fn grid() -> GridParams {
    GridParams {
        voxel_size_m: 0.1,
        truncation_m: 0.4,
    }
}

/// A wavy, noisy surface through `nx × ny` chunks (blocks around z = 0): every block has Ω voxels.
pub(crate) fn surface_layer(nx: i32, ny: i32, seed: u64) -> Layer {
    let mut layer = Layer::new(grid());
    let mut s = seed;
    let side = (nx * CHUNK_BLOCKS as i32) * 8;
    let side_y = (ny * CHUNK_BLOCKS as i32) * 8;
    for bz in -1..=0 {
        for by in 0..side_y / 8 {
            for bx in 0..side / 8 {
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

pub(crate) fn write_layer(store: &mut MapStore, layer: &Layer) {
    for (c, blocks) in group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS) {
        let refs: Vec<(BlockIndex, &Block)> = blocks
            .iter()
            .map(|b| (*b, layer.get(b).expect("block")))
            .collect();
        store.write_chunk(c, &refs, 0).expect("write");
    }
    store.commit().expect("commit");
}

pub(crate) fn store_layer(store: &MapStore) -> Layer {
    let mut layer = Layer::new(store.grid());
    for c in store.chunk_indices() {
        let d = store.read_chunk(c).expect("read").expect("present");
        layer.put_blocks(d.blocks);
    }
    layer
}

pub(crate) fn assert_layers_identical(a: &Layer, b: &Layer) {
    assert_eq!(a.indices_sorted(), b.indices_sorted(), "block sets differ");
    for i in a.indices_sorted() {
        assert!(a.get(&i) == b.get(&i), "block {i:?} differs");
    }
}

pub(crate) fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir.join(CHUNKS_DIR))
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Shard `shard` of a sharded pass with `params` over the local map at `path` (a reader),
/// solved on the CPU to the end.
pub(crate) fn run_local_shard(
    path: &std::path::Path,
    params: &TvParams,
    shard: denser::outofcore::shards::Shard,
) -> denser::outofcore::regional::MapRegularizeStats {
    let mut r = MapStore::open_read_only(path).expect("reader");
    denser::outofcore::regional::regularize_shard(
        &mut r,
        params,
        &options(),
        shard,
        |_, _| true,
        |p, prm| {
            p.solve(prm);
            Ok(())
        },
    )
    .expect("shard")
}

pub(crate) fn options() -> RegionalOptions {
    RegionalOptions {
        region_chunks: 1,
        budget_bytes: 1 << 30,
        halo_blocks: None,
        sweep_iterations: None,
    }
}

pub(crate) fn params(lambda: f32) -> TvParams {
    TvParams {
        lambda,
        iterations: 6,
        ..TvParams::paper(0.1)
    }
}

#[test]
fn a_second_writer_is_refused_at_once_naming_the_holder() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &surface_layer(2, 1, 1));
    let before = files(&root);
    // flock locks belong to an open file, so a second open in this process conflicts as another
    // process's would.
    let t = std::time::Instant::now();
    let err = MapStore::open(&root).expect_err("second writer refused");
    assert!(
        t.elapsed().as_secs_f64() < 1.0,
        "refused at once, not after waiting"
    );
    match &err {
        Error::MapLocked { dir, holder } => {
            assert_eq!(dir, &root);
            assert!(
                holder.contains(&format!("pid {}", std::process::id())),
                "{holder}"
            );
            assert!(holder.contains(&denser::map::lock::host_name()), "{holder}");
            // The command is this test binary's (`tiles-<hash>`).
            let exe = std::env::current_exe().expect("exe");
            let name = exe.file_name().expect("name").to_string_lossy();
            assert!(
                holder.contains("this process") && holder.contains(name.as_ref()),
                "{holder}"
            );
        }
        other => panic!("expected MapLocked, got {other}"),
    }
    let msg = err.to_string();
    assert!(msg.contains("locked by another writer"), "{msg}");
    // create and repair are writers too.
    assert!(matches!(
        MapStore::create(&root, grid(), CHUNK_BLOCKS),
        Err(Error::MapLocked { .. })
    ));
    assert!(matches!(repair(&root), Err(Error::MapLocked { .. })));
    // Readers are not locked out, and nothing was deleted or added.
    let r = MapStore::open_read_only(&root).expect("reader");
    assert!(r.verify().is_empty());
    assert_eq!(files(&root), before);
    drop(r);
    // Dropping the writer releases the lock and empties the lock file.
    drop(w);
    assert_eq!(
        std::fs::read_to_string(root.join(LOCK_FILE)).expect("lock file"),
        ""
    );
    let w2 = MapStore::open(&root).expect("lock released on drop");
    assert!(w2.verify().is_empty());
}

#[test]
fn a_stale_lock_is_recovered_and_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    drop(MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create"));
    // What a writer killed with SIGKILL leaves: its record in the lock file, no lock held (the
    // kernel released it with the process).
    std::fs::write(
        root.join(LOCK_FILE),
        "pid=999999\nhost=elsewhere\nsince_unix_s=1\ncommand=denser regularize map --lambda 0.7\n",
    )
    .expect("stale record");
    let lock = WriterLock::acquire(&root).expect("a stale lock does not block");
    let stale = lock.stale.clone().expect("the dead holder is reported");
    assert_eq!(
        (stale.pid, stale.host.as_str(), stale.command.as_str()),
        (999999, "elsewhere", "denser regularize map --lambda 0.7")
    );
    let now = std::fs::read_to_string(root.join(LOCK_FILE)).expect("lock file");
    assert!(
        now.contains(&format!("pid={}\n", std::process::id())),
        "{now}"
    );
}

#[test]
fn readers_keep_the_files_of_their_manifest_while_a_writer_commits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(1, 1, 2);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    let c = w.chunk_indices()[0];
    let old_name = chunk_file_name(c, w.manifest().chunks[&c].file_seq);
    let reader = MapStore::open_read_only(&root).expect("reader");
    // The writer replaces the chunk with fewer blocks and commits.
    let blocks = group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS)[&c].clone();
    let refs: Vec<(BlockIndex, &Block)> = blocks[..1]
        .iter()
        .map(|b| (*b, layer.get(b).expect("block")))
        .collect();
    w.write_chunk(c, &refs, 0).expect("write");
    w.commit().expect("commit");
    let new_name = chunk_file_name(c, w.manifest().chunks[&c].file_seq);
    // The reader's file is still there and reads as the reader's manifest says.
    assert!(files(&root).contains(&old_name), "deleted under a reader");
    let d = reader.read_chunk(c).expect("read").expect("present");
    assert_eq!(d.blocks.len(), blocks.len());
    assert!(reader.verify().is_empty());
    // A new reader sees the new commit.
    let r2 = MapStore::open_read_only(&root).expect("reader 2");
    assert_eq!(
        r2.read_chunk(c)
            .expect("read")
            .expect("present")
            .blocks
            .len(),
        1
    );
    drop(r2);
    drop(reader);
    // With no reader left, the next commit deletes the superseded file.
    w.commit().expect("commit");
    let now = files(&root);
    assert!(
        !now.contains(&old_name) && now.contains(&new_name),
        "{now:?}"
    );
    // A reader cannot commit.
    let mut r3 = MapStore::open_read_only(&root).expect("reader 3");
    assert!(r3.commit().is_err() && r3.write_chunk(c, &refs, 0).is_err());
}

#[test]
fn a_writer_removes_only_what_it_can_prove_is_its_leftover() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let other = dir.path().join("other");
    let layer = surface_layer(2, 1, 3);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    let committed = files(&root);
    let c = w.chunk_indices()[0];
    // A version written after the last commit by a writer that then dies.
    let blocks = group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS)[&c].clone();
    let refs: Vec<(BlockIndex, &Block)> = blocks
        .iter()
        .map(|b| (*b, layer.get(b).expect("block")))
        .collect();
    w.write_chunk(c, &refs, 0).expect("uncommitted write");
    let uncommitted = chunk_file_name(c, w.manifest().chunks[&c].file_seq);
    let uncommitted_tmp = format!("{}.tmp", uncommitted.trim_end_matches(".dchk"));
    let next = w.manifest().header.next_file_seq;
    drop(w); // the writer stops without committing: its file stays, numbered after the commit
    let copy = root.clone();
    std::fs::write(copy.join(CHUNKS_DIR).join(&uncommitted_tmp), b"partial").expect("tmp");
    std::fs::write(copy.join("manifest.tmp"), b"partial").expect("tmp");
    // Files that nothing proves to be leftovers of this map: another map's chunk numbered after
    // the last commit, an unknown file, and a chunk the manifest does not list.
    let mut o = MapStore::create(&other, grid(), CHUNK_BLOCKS).expect("other map");
    for _ in 0..next + 3 {
        o.allocate_seq();
    }
    o.write_chunk(c, &refs, 0).expect("other's chunk");
    o.commit().expect("commit");
    let foreign_src = o.chunk_path(c).expect("path");
    let foreign = chunk_file_name(c, next + 3);
    std::fs::copy(&foreign_src, copy.join(CHUNKS_DIR).join(&foreign)).expect("copy");
    std::fs::write(copy.join(CHUNKS_DIR).join("notes.txt"), b"mine").expect("notes");
    let unlisted = chunk_file_name(ChunkIndex([40, 40, 40]), 1);
    std::fs::copy(&foreign_src, copy.join(CHUNKS_DIR).join(&unlisted)).expect("copy");

    let (s, cleanup) = MapStore::open_with_cleanup(&copy).expect("open");
    let mut want_removed = vec![uncommitted_tmp, uncommitted];
    want_removed.sort();
    assert_eq!(cleanup.removed_uncommitted, want_removed);
    assert!(cleanup.removed_superseded.is_empty());
    let left: Vec<&str> = cleanup
        .left_alone
        .iter()
        .map(|l| l.split(':').next().expect("name"))
        .collect();
    let mut want = vec![foreign.as_str(), "notes.txt", unlisted.as_str()];
    want.sort();
    assert_eq!(left, want, "{:?}", cleanup.left_alone);
    assert!(cleanup
        .left_alone
        .iter()
        .any(|l| l.contains("not this map's")));
    let mut expect = committed.clone();
    expect.extend([foreign.clone(), "notes.txt".into(), unlisted.clone()]);
    expect.sort();
    assert_eq!(files(&copy), expect);
    assert!(!copy.join("manifest.tmp").exists());
    assert!(s.verify().is_empty());
}

#[test]
fn every_read_checks_the_file_against_its_manifest_entry() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(2, 2, 4);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    let c = w.chunk_indices()[1];
    let path = w.chunk_path(c).expect("path");
    let name = path
        .file_name()
        .expect("name")
        .to_string_lossy()
        .into_owned();
    let entry = w.manifest().chunks[&c];

    // 1. The same chunk of another map of the same place (other noise): valid checksums.
    let other_dir = dir.path().join("older");
    let mut other = MapStore::create(&other_dir, grid(), CHUNK_BLOCKS).expect("other");
    write_layer(&mut other, &surface_layer(2, 2, 99));
    let good = std::fs::read(&path).expect("read");
    std::fs::copy(other.chunk_path(c).expect("path"), &path).expect("swap");
    let err = w
        .read_chunk(c)
        .err()
        .expect("swapped chunk refused")
        .to_string();
    assert!(err.contains(&name), "{err}");
    assert!(err.contains("does not match its manifest entry"), "{err}");
    assert!(
        err.contains("payload CRC") && err.contains("map id"),
        "{err}"
    );
    assert!(
        err.contains(&format!("(manifest: {:#010x})", entry.payload_crc32)),
        "{err}"
    );
    let problems = w.verify();
    assert_eq!(problems.len(), 1, "{problems:?}");
    assert!(problems[0].contains(&name));
    // Regularization stops at the swapped chunk; the chunk is never rewritten (laundered).
    let gen = w.manifest().header.generation;
    let r = regularize_map(&mut w, &params(0.5), &options(), |_, _| true);
    let err = r.expect_err("regularize refuses").to_string();
    assert!(err.contains(&name), "{err}");
    let after = MapStore::open_read_only(&root).expect("reader");
    assert_eq!(after.manifest().chunks[&c], entry, "the entry is untouched");
    assert!(after.manifest().header.generation >= gen);
    assert_eq!(
        after.verify().len(),
        1,
        "still reported after the failed pass"
    );
    drop(after);

    // 2. An older version of the same chunk of this map, renamed to the current name.
    std::fs::write(&path, &good).expect("restore");
    drop(w);
    let mut w = MapStore::open(&root).expect("open");
    let old_bytes = std::fs::read(w.chunk_path(c).expect("path")).expect("read");
    let old_seq = w.manifest().chunks[&c].file_seq;
    let blocks = group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS)[&c].clone();
    let refs: Vec<(BlockIndex, &Block)> = blocks
        .iter()
        .map(|b| (*b, layer.get(b).expect("block")))
        .collect();
    w.write_chunk(c, &refs, 0).expect("rewrite");
    w.commit().expect("commit");
    let new_path = w.chunk_path(c).expect("path");
    let new_seq = w.manifest().chunks[&c].file_seq;
    std::fs::write(&new_path, &old_bytes).expect("stale copy");
    let err = w
        .read_chunk(c)
        .err()
        .expect("stale version refused")
        .to_string();
    assert!(
        err.contains(&format!("file number {old_seq} (manifest: {new_seq})")),
        "{err}"
    );
    // 3. A format-1 file (no origin) with other content is caught by size, CRC and counts.
    let h = ChunkHeader {
        voxel_size_m: 0.1,
        truncation_m: 0.4,
        chunk: c,
        chunk_blocks: CHUNK_BLOCKS,
        block_count: 0,
        flags: 0,
        payload_raw_bytes: 0,
        payload_zstd_bytes: 0,
        payload_crc32: 0,
    };
    std::fs::write(&new_path, encode_chunk(&h, &refs[..1], 3)).expect("v1 file");
    let err = w
        .read_chunk(c)
        .err()
        .expect("v1 impostor refused")
        .to_string();
    assert!(
        err.contains(&format!("blocks 1 (manifest: {})", refs.len())),
        "{err}"
    );
}

#[test]
fn a_lost_manifest_is_refused_by_every_opener_and_repair_rebuilds_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(3, 2, 5);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    regularize_map(&mut w, &params(0.5), &options(), |_, _| true).expect("pass 1");
    let original = w.manifest().clone();
    let reference = store_layer(&w);
    drop(w);
    std::fs::remove_file(root.join(MANIFEST_FILE)).expect("rm manifest");
    let before = files(&root);
    for (what, r) in [
        ("open", MapStore::open(&root).err()),
        ("open_read_only", MapStore::open_read_only(&root).err()),
        (
            "create",
            MapStore::create(&root, grid(), CHUNK_BLOCKS).err(),
        ),
    ] {
        let msg = r
            .unwrap_or_else(|| panic!("{what} accepted a map without manifest"))
            .to_string();
        assert!(
            msg.contains("manifest is lost")
                && msg.contains(&format!("{} chunk files", before.len()))
                && msg.contains("denser repair"),
            "{what}: {msg}"
        );
    }
    assert_eq!(files(&root), before, "nothing deleted");
    assert!(!root.join(MANIFEST_FILE).exists(), "nothing created");

    let report = repair(&root).expect("repair");
    assert_eq!(report.chunks, original.chunks.len());
    assert!(
        report.not_kept.is_empty() && report.older_versions_used.is_empty(),
        "{report:?}"
    );
    let s = MapStore::open_read_only(&root).expect("repaired map opens");
    let m = s.manifest();
    assert_eq!(m.chunks, original.chunks, "every entry rebuilt exactly");
    assert_eq!(m.header.map_id, original.header.map_id);
    assert_eq!(
        (
            m.header.reg_pass,
            m.header.reg_params,
            m.header.complete_pass
        ),
        (1, params(0.5), 1)
    );
    assert_eq!(m.header.next_file_seq, original.header.next_file_seq);
    // The fusion cursor, from the commit mark: the map rebuilt is exactly its last commit.
    assert_eq!(m.header.frames_committed, original.header.frames_committed);
    assert_eq!(
        report.frames_committed,
        Some(original.header.frames_committed)
    );
    assert!(s.verify().is_empty());
    assert_layers_identical(&reference, &store_layer(&s));
    drop(s);
    // A second repair refuses: the manifest is intact now.
    let err = repair(&root).expect_err("nothing to repair").to_string();
    assert!(err.contains("is intact"), "{err}");
}

#[test]
fn repair_keeps_the_newest_intact_version_and_reports_the_rest() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(3, 1, 6);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    let c = w.chunk_indices()[0];
    let v1 = w.chunk_path(c).expect("path");
    let v1_bytes = std::fs::read(&v1).expect("read");
    regularize_map(&mut w, &params(0.5), &options(), |_, _| true).expect("pass 1");
    let v2 = w.chunk_path(c).expect("path");
    let n = w.chunk_indices().len();
    drop(w);
    assert!(!v1.exists(), "superseded by pass 1 and deleted");
    // The older version comes back (a backup), the newest gets a flipped bit, and another map's
    // file of a new chunk is dropped in.
    std::fs::write(&v1, &v1_bytes).expect("restore v1");
    let mut bytes = std::fs::read(&v2).expect("read");
    let k = bytes.len() - 5;
    bytes[k] ^= 0x04;
    std::fs::write(&v2, &bytes).expect("corrupt v2");
    let other = dir.path().join("other");
    let mut o = MapStore::create(&other, grid(), CHUNK_BLOCKS).expect("other");
    let ol = surface_layer(1, 1, 7);
    let (oc, ob) = group_by_chunk(ol.indices_sorted(), CHUNK_BLOCKS)
        .into_iter()
        .next()
        .expect("a chunk");
    let shift = 9 * CHUNK_BLOCKS as i32;
    let moved: Vec<(BlockIndex, &Block)> = ob
        .iter()
        .map(|b| {
            (
                BlockIndex([b.0[0] + shift, b.0[1] + shift, b.0[2]]),
                ol.get(b).expect("block"),
            )
        })
        .collect();
    let far = ChunkIndex([oc.0[0] + 9, oc.0[1] + 9, oc.0[2]]);
    o.write_chunk(far, &moved, 0).expect("write");
    o.commit().expect("commit");
    let foreign = o
        .chunk_path(far)
        .expect("path")
        .file_name()
        .expect("name")
        .to_string_lossy()
        .into_owned();
    std::fs::copy(
        o.chunk_path(far).expect("path"),
        root.join(CHUNKS_DIR).join(&foreign),
    )
    .expect("copy");
    // An unreadable manifest is moved aside, not trusted.
    std::fs::write(root.join(MANIFEST_FILE), b"DNSRMANI garbage").expect("bad manifest");

    let r = repair(&root).expect("repair");
    assert!(r.unreadable_manifest_moved_to.is_some());
    assert_eq!(r.chunks, n, "{r:?}");
    let v1_name = v1.file_name().expect("n").to_string_lossy().into_owned();
    let v2_name = v2.file_name().expect("n").to_string_lossy().into_owned();
    assert_eq!(r.older_versions_used.len(), 1, "{r:?}");
    assert!(
        r.older_versions_used[0].contains(&v2_name)
            && r.older_versions_used[0].contains("payload checksum mismatch")
            && r.older_versions_used[0].contains(&format!("kept {v1_name} (pass 0)")),
        "{:?}",
        r.older_versions_used
    );
    assert_eq!(r.not_kept.len(), 2, "{:?}", r.not_kept);
    assert!(r.not_kept.iter().any(|l| l.starts_with(&v2_name)));
    assert!(r
        .not_kept
        .iter()
        .any(|l| l.starts_with(&foreign) && l.contains("belongs to another map")));
    // The rebuilt passes: pass 1 reached all chunks but the one kept at its fusion version.
    assert_eq!(
        (r.passes.pass, r.passes.done_chunks, r.passes.total_chunks),
        (1, n - 1, n)
    );
    assert_eq!(r.passes.complete_pass, 0);
    let s = MapStore::open_read_only(&root).expect("open");
    assert!(s.verify().is_empty());
    assert_eq!(s.manifest().chunks[&c].file_seq, {
        let (_, seq) = denser::map::manifest::parse_chunk_file_name(&v1_name).expect("name");
        seq
    });
}

#[test]
fn an_interrupted_pass_keeps_the_last_complete_pass_readable_until_it_completes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(3, 2, 8);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    regularize_map(&mut w, &params(0.8), &options(), |_, _| true).expect("pass 1");
    let pass1 = store_layer(&w);
    let n = w.chunk_indices().len();
    assert_eq!(files(&root).len(), n);
    // Pass 2 with another λ, stopped after 2 regions (what a kill leaves: committed regions).
    let st = regularize_map(&mut w, &params(0.3), &options(), |done, _| done < 2).expect("part");
    assert!(st.interrupted && st.regions == 2, "{st:?}");
    let status = w.manifest().pass_status();
    assert!(!status.is_complete());
    assert_eq!((status.pass, status.complete_pass), (2, 1));
    let k = status.done_chunks;
    assert!(k >= 2 && k < n, "{status:?}");
    assert_eq!(status.kept_chunks, k);
    assert_eq!(status.by_pass[&1].len(), n - k);
    assert_eq!(
        status.describe().split(" (").next().expect("head"),
        format!("pass 2, λ 0.3: {k} of {n} chunks")
    );
    assert_eq!(
        files(&root).len(),
        n + k,
        "pass-1 files of rewritten chunks are kept"
    );
    drop(w);
    // Readers: the last complete pass reads whole and bit-identical to what pass 1 wrote; the
    // current files mix the passes.
    let r = MapStore::open_read_only(&root).expect("reader");
    assert!(r.verify().is_empty(), "kept files verify too");
    let view = r.complete_pass_view().expect("pass 1 view");
    assert_layers_identical(&pass1, &store_layer(&view));
    assert_ne!(
        store_layer(&r)
            .get(&layer.indices_sorted()[0])
            .expect("b")
            .regularized,
        pass1
            .get(&layer.indices_sorted()[0])
            .expect("b")
            .regularized,
        "the current file of a rewritten chunk is pass 2's"
    );
    drop(view);
    drop(r);
    // Resuming pass 2 completes it: the kept files go, pass 2 is the complete one.
    let mut w = MapStore::open(&root).expect("open");
    let st = regularize_map(&mut w, &params(0.3), &options(), |_, _| true).expect("resume");
    assert_eq!((st.pass, st.regions_skipped), (2, 2), "{st:?}");
    let status = w.manifest().pass_status();
    assert!(status.is_complete());
    assert_eq!((status.complete_pass, status.kept_chunks), (2, 0));
    assert_eq!(files(&root).len(), n, "kept files deleted at completion");
    // Same result as an uninterrupted pass 2.
    let dir2 = tempfile::tempdir().expect("tempdir");
    let mut whole = MapStore::create(&dir2.path().join("m"), grid(), CHUNK_BLOCKS).expect("c");
    write_layer(&mut whole, &layer);
    regularize_map(&mut whole, &params(0.3), &options(), |_, _| true).expect("whole");
    assert_layers_identical(&store_layer(&whole), &store_layer(&w));
}

/// A format-1 manifest (the same header up to byte 80, no kept table) over format-1 chunk files.
fn v1_manifest(m: &denser::map::manifest::Manifest) -> Vec<u8> {
    let mut b = encode_manifest(m);
    b[8] = 1;
    b[80..124].iter_mut().for_each(|x| *x = 0);
    let crc = crc32fast::hash(&b[0..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
    b
}

#[test]
fn maps_of_format_1_still_open_and_are_upgraded_by_their_next_commit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let layer = surface_layer(2, 1, 9);
    // Build the same map with this build, then rewrite it in format 1.
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &layer);
    let mut m = w.manifest().clone();
    drop(w);
    for (c, e) in m.chunks.iter_mut() {
        let path = root.join(CHUNKS_DIR).join(chunk_file_name(*c, e.file_seq));
        let written = std::fs::read(&path).expect("read");
        assert_eq!(&written[8..10], &[4, 0], "this build writes chunk format 4");
        let d = denser::map::store::read_chunk_file(&path).expect("read");
        let refs: Vec<(BlockIndex, &Block)> = d.blocks.iter().map(|(i, b)| (*i, &**b)).collect();
        let bytes = encode_chunk(&d.header, &refs, 3);
        e.file_bytes = bytes.len() as u64;
        // Format 1's payload differs from format 3's: its CRC is the one a format-1 map records.
        e.payload_crc32 = crc32fast::hash(&bytes[64..]);
        std::fs::write(&path, bytes).expect("v1 chunk");
    }
    m.header.map_id = 0;
    std::fs::write(root.join(MANIFEST_FILE), v1_manifest(&m)).expect("v1 manifest");
    assert_eq!(std::fs::read(root.join(MANIFEST_FILE)).expect("r")[8], 1);

    let r = MapStore::open_read_only(&root).expect("v1 map opens");
    assert_eq!(r.manifest().header.map_id, 0);
    assert!(r.verify().is_empty());
    assert_layers_identical(&layer, &store_layer(&r));
    drop(r);
    let mut w = MapStore::open(&root).expect("open for writing");
    regularize_map(&mut w, &params(0.5), &options(), |_, _| true).expect("regularize");
    drop(w);
    let bytes = std::fs::read(root.join(MANIFEST_FILE)).expect("r");
    assert_eq!(bytes[8], 2, "the next commit writes format 2");
    let r = MapStore::open_read_only(&root).expect("open");
    assert_ne!(
        r.manifest().header.map_id,
        0,
        "and gives the map an identity"
    );
    assert!(r.verify().is_empty());
    assert!(r.manifest().pass_status().is_complete());
    for (c, e) in &r.manifest().chunks {
        let path = root.join(CHUNKS_DIR).join(chunk_file_name(*c, e.file_seq));
        let head = std::fs::read(&path).expect("read");
        assert_eq!(&head[8..10], &[4, 0], "rewritten in chunk format 4");
    }
}
