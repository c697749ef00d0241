//! A map survives its users (issue 36), in the storage engine: a rolled-back manifest is refused
//! by every opener and rebuilt by `repair` with nothing lost; `repair` keeps each chunk's version
//! of the latest commit, not the highest-numbered file; a writer whose lock file was removed stops
//! before its next commit.

use super::engine::{
    assert_layers_identical, files, grid, params, store_layer, surface_layer, write_layer,
    CHUNK_BLOCKS,
};
use denser::grid::Layer;
use denser::map::layout::{COMMIT_MARK, LOCK_FILE, MANIFEST_FILE, MANIFEST_NEXT};
use denser::map::repair::repair;
use denser::map::store::MapStore;
use denser::outofcore::shards::Shard;
use denser::Error;
use std::path::Path;

/// `layer` with every TSDF value of every third block nudged by `k` steps and its colour
/// changed: a later fusion's version of the same chunks.
fn changed(layer: &Layer, k: i16) -> Layer {
    let mut out = Layer::new(grid());
    for (n, b) in layer.indices_sorted().into_iter().enumerate() {
        let mut block = Box::new(layer.get(&b).expect("block").clone());
        if n % 3 == 0 {
            for t in block.tsdf.iter_mut() {
                *t = t.saturating_add(k * 97);
            }
            block
                .color
                .iter_mut()
                .for_each(|c| c[2] = c[2].wrapping_add(k as u8));
        }
        out.insert(b, block);
    }
    out
}

fn rolled_back(e: Error) -> (u64, u64) {
    match e {
        Error::MapRolledBack {
            manifest_generation,
            newer_generation,
            ..
        } => (manifest_generation, newer_generation),
        other => panic!("expected a rolled-back manifest, got {other}"),
    }
}

fn manifest_bytes(root: &Path) -> Vec<u8> {
    std::fs::read(root.join(MANIFEST_FILE)).expect("manifest")
}

/// Item 1: an older manifest of the same map copied over the current one made the next writer
/// delete every chunk file written after it ("removed 160 chunk files…"). Now every opener
/// refuses it, nothing is deleted, and `repair` rebuilds the latest map.
#[test]
fn a_rolled_back_manifest_is_refused_and_repair_restores_the_latest_map() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let a = surface_layer(3, 2, 5);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &a);
    let backup_gen = w.manifest().header.generation;
    let backup = manifest_bytes(&root);
    let b = changed(&a, 1);
    write_layer(&mut w, &b);
    let c = changed(&b, 2);
    write_layer(&mut w, &c);
    let latest_gen = w.manifest().header.generation;
    drop(w);
    let before = files(&root);

    // Several generations back: the commit mark and the chunk files both tell.
    std::fs::write(root.join(MANIFEST_FILE), &backup).expect("restore an old manifest");
    let (m, newer) = rolled_back(MapStore::open(&root).expect_err("writer"));
    assert_eq!((m, newer), (backup_gen, latest_gen));
    rolled_back(MapStore::open_read_only(&root).expect_err("reader"));
    assert_eq!(files(&root), before, "nothing deleted");
    // Without the commit mark, the chunk files written after the old manifest still tell.
    let mark = std::fs::read(root.join(COMMIT_MARK)).expect("mark");
    std::fs::remove_file(root.join(COMMIT_MARK)).expect("lose the mark");
    let (m, newer) = rolled_back(MapStore::open(&root).expect_err("writer without mark"));
    assert!(m == backup_gen && newer > backup_gen, "{m} {newer}");
    assert_eq!(files(&root), before, "nothing deleted");
    std::fs::write(root.join(COMMIT_MARK), mark).expect("mark back");

    let report = repair(&root).expect("repair");
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("older than the map")),
        "{:?}",
        report.notes
    );
    assert!(root
        .join(format!("{MANIFEST_FILE}.rolled-back-{backup_gen}"))
        .exists());
    let r = MapStore::open_read_only(&root).expect("repaired");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_layers_identical(&c, &store_layer(&r));
    assert!(r.manifest().header.generation > latest_gen);
    drop(r);
    // The next writer removes only the superseded versions, and the map stays the latest.
    let w = MapStore::open(&root).expect("writer after repair");
    assert_layers_identical(&c, &store_layer(&w));
}

/// One generation back: no chunk file can tell a committed generation from a dead writer's
/// leftovers, but the commit mark can.
#[test]
fn a_manifest_one_commit_old_is_refused_too() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let a = surface_layer(2, 2, 6);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &a);
    let backup = manifest_bytes(&root);
    let b = changed(&a, 3);
    write_layer(&mut w, &b);
    drop(w);
    let before = files(&root);
    std::fs::write(root.join(MANIFEST_FILE), &backup).expect("restore");
    rolled_back(MapStore::open(&root).expect_err("writer"));
    assert_eq!(files(&root), before, "nothing deleted");
    repair(&root).expect("repair");
    let r = MapStore::open_read_only(&root).expect("repaired");
    assert_layers_identical(&b, &store_layer(&r));
}

/// Item 2: after a shard wrote its files (numbered far above the writer's), the resumed writer
/// committed newer versions, and the manifest was lost, `repair` kept the shard's stale files by
/// their higher numbers. It orders versions by commit generation now.
#[test]
fn repair_keeps_the_latest_commit_not_the_highest_file_number() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let a = surface_layer(3, 2, 7);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &a);
    drop(w);
    let shard = super::engine::run_local_shard(&root, &params(0.8), Shard { index: 0, count: 1 });
    assert!(shard.regions > 0);
    // The writer resumes fusion (the shard's files stay: their plan is open) and commits newer
    // versions of every chunk.
    let mut w = MapStore::open(&root).expect("writer");
    let b = changed(&a, 4);
    write_layer(&mut w, &b);
    let newest = changed(&b, 5);
    write_layer(&mut w, &newest);
    drop(w);
    std::fs::remove_file(root.join(MANIFEST_FILE)).expect("lose the manifest");
    let report = repair(&root).expect("repair");
    assert_eq!(report.chunks, store_chunks(&newest));
    let r = MapStore::open_read_only(&root).expect("repaired");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_layers_identical(&newest, &store_layer(&r));
    assert!(
        r.manifest().chunks.values().all(|e| e.reg_pass == 0),
        "no shard file kept"
    );
}

/// A kill in the middle of a checkpoint leaves chunk files written after the last commit; with
/// the manifest then lost (or rolled back), `repair` mixed them with the committed files and
/// could not tell how many frames the map held. It rebuilds the last commit the commit mark names,
/// reports the later files (left in place), and restores the fusion cursor from the mark.
#[test]
fn repair_rebuilds_the_last_commit_and_its_fusion_cursor() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let a = surface_layer(3, 2, 5);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    w.header_mut().frames_committed = 7;
    write_layer(&mut w, &a);
    // The next checkpoint, cut short before its commit: every chunk written again.
    let b = changed(&a, 3);
    let chunks = denser::map::group_by_chunk(b.indices_sorted(), CHUNK_BLOCKS);
    for (c, blocks) in &chunks {
        let refs: Vec<_> = blocks
            .iter()
            .map(|i| (*i, b.get(i).expect("block")))
            .collect();
        w.write_chunk(*c, &refs, 0).expect("write");
    }
    drop(w);
    std::fs::remove_file(root.join(MANIFEST_FILE)).expect("lose the manifest");
    let report = repair(&root).expect("repair");
    assert_eq!(report.frames_committed, Some(7), "{report:?}");
    let later = report
        .not_kept
        .iter()
        .filter(|l| l.contains("written after the last commit"))
        .count();
    assert_eq!(later, chunks.len(), "{report:?}");
    let r = MapStore::open_read_only(&root).expect("repaired");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_eq!(r.manifest().header.frames_committed, 7);
    assert_layers_identical(&a, &store_layer(&r));
}

/// A map of two commits after its creation, `a` (4 frames) then `b` (9 frames), left as a kill
/// just after the second commit's commit point leaves it: the manifest and the mark still of the
/// first. Returns the creation's manifest, the second commit's generation, `a` and `b`.
fn a_commit_cut_short(root: &Path) -> (Vec<u8>, u64, Layer, Layer) {
    let a = surface_layer(3, 2, 5);
    let mut w = MapStore::create(root, grid(), CHUNK_BLOCKS).expect("create");
    let created = manifest_bytes(root);
    w.header_mut().frames_committed = 4;
    write_layer(&mut w, &a);
    let (manifest, mark) = (
        manifest_bytes(root),
        std::fs::read(root.join(COMMIT_MARK)).expect("mark"),
    );
    let b = changed(&a, 2);
    w.header_mut().frames_committed = 9;
    // A reader open meanwhile: the files the commit supersedes stay, as they do until its mark.
    let reader = MapStore::open_read_only(root).expect("reader");
    write_layer(&mut w, &b);
    let generation = w.manifest().header.generation;
    drop(w);
    drop(reader);
    assert!(root.join(MANIFEST_NEXT).exists());
    std::fs::write(root.join(MANIFEST_FILE), manifest).expect("manifest as before");
    std::fs::write(root.join(COMMIT_MARK), mark).expect("mark as before");
    (created, generation, a, b)
}

/// A commit cut short between its first write and its mark (a kill, a full disk), also with the
/// previous manifest put back after a kill between the manifest and the mark (the same files).
/// Before, the next writer took the commit's files for a dead writer's leftovers and deleted
/// them, and `repair` moved them aside (the random operations' seed 4: "repair lost blocks
/// 398 → 0"). A commit's point is now its first write, the whole manifest under its own name:
/// readers see the previous commit, the next writer completes the begun one, and `repair` keeps
/// its files and its fusion cursor.
#[test]
fn a_commit_cut_short_after_its_commit_point_is_completed_not_lost() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let (_, generation, a, b) = a_commit_cut_short(&root);
    let r = MapStore::open_read_only(&root).expect("a reader");
    assert_eq!(r.manifest().header.generation, generation - 1);
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_layers_identical(&a, &store_layer(&r));
    drop(r);
    let w = MapStore::open(&root).expect("the next writer");
    assert_eq!(w.manifest().header.generation, generation);
    assert_eq!(w.manifest().header.frames_committed, 9);
    assert!(w.verify().is_empty(), "{:?}", w.verify());
    assert_layers_identical(&b, &store_layer(&w));
    drop(w);
    let mark = std::fs::read_to_string(root.join(COMMIT_MARK)).expect("mark");
    assert!(
        mark.contains(&format!("generation {generation}\n")),
        "{mark}"
    );

    // The same, then an older manifest put back: refused by every opener; `repair` rebuilds the
    // begun commit, not the one the mark names.
    let root = dir.path().join("older");
    let (created, generation, _, b) = a_commit_cut_short(&root);
    std::fs::write(root.join(MANIFEST_FILE), created).expect("restore the first manifest");
    let before = files(&root);
    let (m, newer) = rolled_back(MapStore::open(&root).expect_err("writer"));
    assert_eq!((m, newer), (generation - 2, generation - 1));
    rolled_back(MapStore::open_read_only(&root).expect_err("reader"));
    assert_eq!(files(&root), before, "nothing deleted");
    let report = repair(&root).expect("repair");
    assert_eq!(report.frames_committed, Some(9), "{report:?}");
    let r = MapStore::open_read_only(&root).expect("repaired");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_layers_identical(&b, &store_layer(&r));
}

fn store_chunks(layer: &Layer) -> usize {
    denser::map::group_by_chunk(layer.indices_sorted(), CHUNK_BLOCKS).len()
}

/// Item 6: with `MAP/lock` removed while a writer ran, a second writer was admitted and the
/// first went on committing. The first now stops before its next commit.
#[test]
fn a_writer_whose_lock_file_was_removed_stops_before_committing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = dir.path().join("map");
    let a = surface_layer(2, 1, 8);
    let mut w = MapStore::create(&root, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &a);
    let generation = w.manifest().header.generation;
    std::fs::remove_file(root.join(LOCK_FILE)).expect("remove the lock file");
    let mut second = MapStore::open(&root).expect("a second writer takes a new lock file");
    let err = w.commit().expect_err("the first writer's commit");
    assert!(
        matches!(&err, Error::LockLost { .. })
            && err.to_string().contains("replaced by another file"),
        "{err}"
    );
    assert_eq!(
        MapStore::open_read_only(&root)
            .expect("r")
            .manifest()
            .header
            .generation,
        generation,
        "nothing committed by the first writer"
    );
    second.commit().expect("the second writer commits");
}

/// Item 5: a killed `merge` left a valid-looking map of 256 of 1123 chunks that every command
/// accepted, and a rerun was refused ("already holds a map"). The output now carries an
/// incomplete mark until its last commit: every opener refuses it, the same merge resumes it,
/// and the result equals an uninterrupted merge.
#[test]
fn a_stopped_merge_is_refused_by_every_opener_and_resumed_by_the_same_merge() {
    use denser::map::MapLocation;
    use denser::outofcore::merge::merge;
    let dir = tempfile::tempdir().expect("tempdir");
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for (root, seed) in [(&a, 1), (&b, 2)] {
        let mut w = MapStore::create(root, grid(), CHUNK_BLOCKS).expect("create");
        write_layer(&mut w, &surface_layer(12, 12, seed));
    }
    let inputs = [MapLocation::Dir(a.clone()), MapLocation::Dir(b.clone())];
    let whole = MapLocation::Dir(dir.path().join("whole"));
    let reference = merge(&inputs, &whole, 1 << 30).expect("uninterrupted merge");
    assert!(reference.chunks > 256, "{reference:?}");

    // Input a's last chunk file damaged: the merge stops there, after its commit of 256 chunks.
    let r = MapStore::open_read_only(&a).expect("a");
    let last = *r.chunk_indices().last().expect("chunks");
    let victim = r.chunk_path(last).expect("path");
    drop(r);
    let good = std::fs::read(&victim).expect("read");
    let mut bad = good.clone();
    let n = bad.len();
    bad[n - 1] ^= 0xff;
    std::fs::write(&victim, &bad).expect("damage");
    let out = MapLocation::Dir(dir.path().join("out"));
    merge(&inputs, &out, 1 << 30).expect_err("the merge stops at the damaged chunk");
    let root = dir.path().join("out");
    assert!(root.join(MANIFEST_FILE).exists(), "it had committed");
    for e in [
        MapStore::open_read_only(&root).expect_err("reader"),
        MapStore::open(&root).expect_err("writer"),
    ] {
        assert!(e.to_string().contains("unfinished map"), "{e}");
    }
    // Another merge into it is refused; the same merge resumes.
    let c = dir.path().join("c");
    let mut w = MapStore::create(&c, grid(), CHUNK_BLOCKS).expect("create");
    write_layer(&mut w, &surface_layer(12, 12, 3));
    drop(w);
    let other = [MapLocation::Dir(a.clone()), MapLocation::Dir(c)];
    let e = merge(&other, &out, 1 << 30).expect_err("another merge");
    assert!(
        e.to_string().contains("unfinished merge of other inputs"),
        "{e}"
    );
    std::fs::write(&victim, &good).expect("repair the input");
    let resumed = merge(&inputs, &out, 1 << 30).expect("resume");
    assert_eq!(resumed.chunks_resumed, 256, "{resumed:?}");
    assert_eq!(resumed.chunks + resumed.chunks_resumed, reference.chunks);
    let r = MapStore::open_read_only(&root).expect("complete: opens");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    let w = MapStore::open_read_only(&dir.path().join("whole")).expect("whole");
    assert_layers_identical(&store_layer(&w), &store_layer(&r));
    // A finished map is not merged into again.
    let e = merge(&inputs, &out, 1 << 30).expect_err("rerun after completion");
    assert!(e.to_string().contains("already holds a map"), "{e}");
}

/// Item 6: on S3, `repair` could not rebuild a lost manifest ("has no chunks/ folder"), yet every
/// opener told the user to run it. It rebuilds a lost and a rolled-back manifest there too.
#[cfg(feature = "s3")]
#[test]
fn repair_rebuilds_lost_and_rolled_back_manifests_on_s3() {
    use super::common::Moto;
    use denser::map::repair::repair_files;
    let Some(moto) = Moto::start() else { return };
    moto.create_bucket("maps");
    let files = super::scaleout::s3_files(&moto, "maps", "city/r", &[]);
    let a = surface_layer(2, 2, 9);
    let mut w = MapStore::create_files(files.clone(), grid(), CHUNK_BLOCKS).expect("s3 map");
    write_layer(&mut w, &a);
    let old = files
        .read(MANIFEST_FILE)
        .expect("read")
        .expect("manifest")
        .to_vec();
    let b = changed(&a, 6);
    write_layer(&mut w, &b);
    drop(w);

    files.delete(MANIFEST_FILE).expect("lose the manifest");
    let e = MapStore::open_read_only_files(files.clone()).expect_err("lost");
    assert!(e.to_string().contains("denser repair"), "{e}");
    repair_files(files.clone()).expect("repair on S3");
    let r = MapStore::open_read_only_files(files.clone()).expect("repaired");
    assert!(r.verify().is_empty(), "{:?}", r.verify());
    assert_layers_identical(&b, &store_layer(&r));
    drop(r);

    // An older manifest put back over the rebuilt one.
    files.write(MANIFEST_FILE, &old).expect("roll back");
    rolled_back(MapStore::open_files(files.clone()).expect_err("writer"));
    let report = repair_files(files.clone()).expect("repair the rollback");
    assert!(report.unreadable_manifest_moved_to.is_some());
    let r = MapStore::open_read_only_files(files.clone()).expect("repaired");
    assert_layers_identical(&b, &store_layer(&r));
}
