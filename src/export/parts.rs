//! Exports as an array job: `denser export MAP … --shard I/N` meshes its share of the chunks and
//! stores the meshes as one **part** object in the map's own store
//! (`exports/<key>/part-I-of-N.dmp`, `formats/shards.md`), the one place every shard, on any
//! machine, can write; the plain `denser export MAP …` afterwards takes each chunk's mesh from
//! the parts (ranged reads of one record at a time), meshes what no part holds, and writes the
//! output exactly as a single process would — the same stitching over the same per-chunk
//! meshes in the same order, so the files are byte-identical — then removes the parts.
//!
//! The key is a hash of the map id, the field and every chunk's committed file: parts of another
//! state of the map are never used (and are removed by the next final export).

use super::chunks::{mesh_chunk, Mesher};
use crate::error::{Error, Result};
use crate::grid::VoxelIndex;
use crate::map::layout::EXPORTS_AREA;
use crate::map::manifest::Manifest;
use crate::map::store::MapStore;
use crate::map::ChunkIndex;
use crate::mesh::{EdgeKey, Field, Mesh};
use crate::outofcore::shards::Shard;
use std::collections::BTreeMap;
use std::sync::Arc;

/// First 8 bytes of a part object.
pub const PART_MAGIC: [u8; 8] = *b"DNSRPART";
/// Part format version.
pub const PART_VERSION: u16 = 1;
const HEADER_BYTES: usize = 32;
const INDEX_ENTRY_BYTES: usize = 28;
const FOOTER_BYTES: usize = 12;

/// A chunk's mesh as the exporters use it: the mesh (map frame), each vertex's edge key, and the
/// number of the chunk's own blocks.
pub type ChunkMesh = (Mesh, Vec<EdgeKey>, usize);

/// The key of exports of `field` from the manifest `m` (FNV-1a 64 over the map id, the field and
/// every entry's chunk and file number).
pub fn export_key(m: &Manifest, field: Field) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |b: &[u8]| {
        for x in b {
            h ^= *x as u64;
            h = h.wrapping_mul(0x100_0000_01b3);
        }
    };
    eat(&m.header.map_id.to_le_bytes());
    eat(&[field as u8]);
    for (c, e) in &m.chunks {
        for a in c.0 {
            eat(&a.to_le_bytes());
        }
        eat(&e.file_seq.to_le_bytes());
    }
    h
}

fn part_name(key: u64, shard: Shard) -> String {
    format!(
        "{EXPORTS_AREA}/{key:016x}/part-{}-of-{}.dmp",
        shard.index, shard.count
    )
}

/// Encodes one chunk's record (before compression).
fn encode_record(c: ChunkIndex, (m, keys, own): &ChunkMesh) -> Vec<u8> {
    let mut b = Vec::with_capacity(24 + m.positions_m.len() * 40 + m.triangles.len() * 12);
    for a in c.0 {
        b.extend_from_slice(&a.to_le_bytes());
    }
    b.extend_from_slice(&(*own as u32).to_le_bytes());
    b.extend_from_slice(&(m.positions_m.len() as u32).to_le_bytes());
    b.extend_from_slice(&(m.triangles.len() as u32).to_le_bytes());
    for p in &m.positions_m {
        for v in p {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    for col in &m.colors {
        b.extend_from_slice(col);
    }
    for k in keys {
        for v in k.0 .0 {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.push(k.1);
    }
    for t in &m.triangles {
        for v in t {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    b
}

fn decode_record(b: &[u8]) -> std::result::Result<(ChunkIndex, ChunkMesh), String> {
    let mut at = 0usize;
    let mut take = |n: usize| -> std::result::Result<&[u8], String> {
        let s = b.get(at..at + n).ok_or("record truncated")?;
        at += n;
        Ok(s)
    };
    let u32_ = |s: &[u8]| u32::from_le_bytes(s.try_into().expect("4 bytes"));
    let mut c = [0i32; 3];
    for v in &mut c {
        *v = u32_(take(4)?) as i32;
    }
    let own = u32_(take(4)?) as usize;
    let nv = u32_(take(4)?) as usize;
    let nt = u32_(take(4)?) as usize;
    if b.len() != 24 + nv * 40 + nt * 12 {
        return Err(format!(
            "record of {} bytes for {nv} vertices and {nt} triangles",
            b.len()
        ));
    }
    let mut m = Mesh::default();
    for _ in 0..nv {
        let s = take(12)?;
        m.positions_m.push(
            [0, 1, 2].map(|k| f32::from_le_bytes(s[4 * k..4 * k + 4].try_into().expect("4 bytes"))),
        );
    }
    for _ in 0..nv {
        let s = take(3)?;
        m.colors.push([s[0], s[1], s[2]]);
    }
    let mut keys = Vec::with_capacity(nv);
    for _ in 0..nv {
        let s = take(25)?;
        let v = [0, 1, 2].map(|k| i64::from_le_bytes(s[8 * k..8 * k + 8].try_into().expect("8")));
        keys.push((VoxelIndex(v), s[24]));
    }
    for _ in 0..nt {
        let s = take(12)?;
        let t = [0, 1, 2].map(|k| u32_(&s[4 * k..4 * k + 4]));
        if t.iter().any(|i| *i as usize >= nv) {
            return Err("triangle names a vertex past the end".into());
        }
        m.triangles.push(t);
    }
    Ok((ChunkIndex(c), (m, keys, own)))
}

/// What one export shard wrote.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PartStats {
    /// The part object (its full name).
    pub object: String,
    /// Chunks meshed.
    pub chunks: usize,
    /// Vertices and triangles in them.
    pub vertices: u64,
    /// Triangles.
    pub triangles: u64,
    /// Bytes of the part.
    pub bytes: u64,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Meshes shard `shard`'s share of `chunks` (sorted; the k-th goes to shard `k mod N`) and stores
/// the part in the map's store (replacing an earlier run's part of the same shard).
pub fn write_part(
    store: &MapStore,
    field: Field,
    chunks: &[ChunkIndex],
    shard: Shard,
    mesher: &Mesher,
) -> Result<PartStats> {
    let t0 = std::time::Instant::now();
    let key = export_key(store.manifest(), field);
    let mut out = vec![0u8; HEADER_BYTES];
    out[0..8].copy_from_slice(&PART_MAGIC);
    out[8..10].copy_from_slice(&PART_VERSION.to_le_bytes());
    out[12..16].copy_from_slice(&shard.index.to_le_bytes());
    out[16..20].copy_from_slice(&shard.count.to_le_bytes());
    out[20..28].copy_from_slice(&key.to_le_bytes());
    let mut index: Vec<(ChunkIndex, u64, u64)> = Vec::new();
    let mut stats = PartStats::default();
    let mine: Vec<ChunkIndex> = chunks
        .iter()
        .enumerate()
        .filter(|(k, _)| shard.owns(*k))
        .map(|(_, c)| *c)
        .collect();
    let bar = crate::progress::bar(mine.len() as u64, "meshing");
    for c in mine {
        let cm = mesh_chunk(store, c, field, mesher)?;
        stats.vertices += cm.0.positions_m.len() as u64;
        stats.triangles += cm.0.triangles.len() as u64;
        let raw = encode_record(c, &cm);
        let mut rec = zstd::bulk::compress(&raw, 3)
            .map_err(|e| Error::InvalidArgument(format!("compressing a mesh part: {e}")))?;
        let crc = crc32fast::hash(&rec);
        rec.extend_from_slice(&(raw.len() as u32).to_le_bytes());
        rec.extend_from_slice(&crc.to_le_bytes());
        index.push((c, out.len() as u64, rec.len() as u64));
        out.extend_from_slice(&rec);
        stats.chunks += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    out[28..32].copy_from_slice(&(index.len() as u32).to_le_bytes());
    let index_at = out.len() as u64;
    for (c, off, len) in &index {
        for a in c.0 {
            out.extend_from_slice(&a.to_le_bytes());
        }
        out.extend_from_slice(&off.to_le_bytes());
        out.extend_from_slice(&len.to_le_bytes());
    }
    let crc = crc32fast::hash(&out[index_at as usize..]);
    out.extend_from_slice(&index_at.to_le_bytes());
    out.extend_from_slice(&crc.to_le_bytes());
    let name = part_name(key, shard);
    store.files().write(&name, &out)?;
    stats.object = store.files().path(&name).display().to_string();
    stats.bytes = out.len() as u64;
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}

/// The parts stored for the map's current state and `field`: where each chunk's record is.
#[derive(Debug)]
pub struct ExportParts {
    store_files: Arc<dyn crate::map::files::MapFiles>,
    key: u64,
    /// Chunk → (part object, offset, length).
    records: BTreeMap<ChunkIndex, (String, u64, u64)>,
    /// Part objects found.
    pub parts: usize,
}

impl ExportParts {
    /// Reads the index of every part of `field` for `store`'s committed state (ranged reads of
    /// their ends); `None` when there is none.
    pub fn load(store: &MapStore, field: Field) -> Result<Option<Self>> {
        let key = export_key(store.manifest(), field);
        let files = store.files().clone();
        let folder = format!("{EXPORTS_AREA}/{key:016x}");
        let listed = files.list(&folder)?;
        if listed.is_empty() {
            return Ok(None);
        }
        let mut records = BTreeMap::new();
        let mut parts = 0;
        for o in listed {
            if !o.name.ends_with(".dmp") || o.size < (HEADER_BYTES + FOOTER_BYTES) as u64 {
                continue;
            }
            let name = format!("{folder}/{}", o.name);
            let bad = |m: &str| Error::bad_input(files.path(&name), format!("export part: {m}"));
            let head = files.read_range(&name, 0..HEADER_BYTES as u64)?;
            if head.len() < HEADER_BYTES || head[0..8] != PART_MAGIC {
                return Err(bad("bad magic"));
            }
            if u16::from_le_bytes([head[8], head[9]]) != PART_VERSION
                || u64::from_le_bytes(head[20..28].try_into().expect("8")) != key
            {
                return Err(bad("another version or key"));
            }
            let n = u32::from_le_bytes(head[28..32].try_into().expect("4")) as u64;
            let foot = files.read_range(&name, o.size - FOOTER_BYTES as u64..o.size)?;
            let index_at = u64::from_le_bytes(foot[0..8].try_into().expect("8"));
            let crc = u32::from_le_bytes(foot[8..12].try_into().expect("4"));
            if index_at + n * INDEX_ENTRY_BYTES as u64 + FOOTER_BYTES as u64 != o.size {
                return Err(bad("index does not fit the object"));
            }
            let idx = files.read_range(&name, index_at..index_at + n * INDEX_ENTRY_BYTES as u64)?;
            if crc32fast::hash(&idx) != crc {
                return Err(bad("index checksum mismatch"));
            }
            for e in idx.chunks_exact(INDEX_ENTRY_BYTES) {
                let c = [0, 1, 2]
                    .map(|k| i32::from_le_bytes(e[4 * k..4 * k + 4].try_into().expect("4")));
                let off = u64::from_le_bytes(e[12..20].try_into().expect("8"));
                let len = u64::from_le_bytes(e[20..28].try_into().expect("8"));
                records.insert(ChunkIndex(c), (name.clone(), off, len));
            }
            parts += 1;
        }
        Ok(Some(ExportParts {
            store_files: files,
            key,
            records,
            parts,
        }))
    }

    /// Chunks some part holds.
    pub fn chunks(&self) -> usize {
        self.records.len()
    }

    /// The mesh of chunk `c` from its part (one ranged read), `None` when no part holds it.
    pub fn mesh(&self, c: ChunkIndex) -> Result<Option<ChunkMesh>> {
        let Some((name, off, len)) = self.records.get(&c) else {
            return Ok(None);
        };
        let files = &self.store_files;
        let bad = |m: String| Error::bad_input(files.path(name), format!("export part: {m}"));
        let rec = files.read_range(name, *off..off + len)?;
        if rec.len() < 8 {
            return Err(bad("record truncated".into()));
        }
        let (z, tail) = rec.split_at(rec.len() - 8);
        let raw_len = u32::from_le_bytes(tail[0..4].try_into().expect("4")) as usize;
        if crc32fast::hash(z) != u32::from_le_bytes(tail[4..8].try_into().expect("4")) {
            return Err(bad(format!("record of chunk {:?}: checksum mismatch", c.0)));
        }
        let raw = zstd::bulk::decompress(z, raw_len).map_err(|e| bad(e.to_string()))?;
        let (cc, m) = decode_record(&raw).map_err(bad)?;
        if cc != c {
            return Err(bad(format!(
                "record says chunk {:?}, index {:?}",
                cc.0, c.0
            )));
        }
        Ok(Some(m))
    }

    /// Removes these parts, and parts of other states of the map (stale), from the store.
    pub fn remove_all(&self) -> Result<()> {
        for o in self.store_files.list_recursive(EXPORTS_AREA)? {
            let name = format!("{EXPORTS_AREA}/{}", o.name);
            let ours = o.name.starts_with(&format!("{:016x}/", self.key));
            if ours || o.name.ends_with(".dmp") {
                self.store_files.delete(&name)?;
            }
        }
        Ok(())
    }
}

/// Where an export's chunk meshes come from: the part of an `export --shard` run that holds
/// one, else the map, meshed by `mesher`.
#[derive(Clone, Copy, Debug)]
pub struct ChunkSource<'a> {
    /// The parts of `export --shard` runs, if any.
    pub parts: Option<&'a ExportParts>,
    /// What meshes the chunks no part holds.
    pub mesher: &'a Mesher,
}

impl ChunkSource<'_> {
    /// Chunk `c`'s mesh of `field`.
    pub fn mesh(&self, store: &MapStore, c: ChunkIndex, field: Field) -> Result<ChunkMesh> {
        if let Some(p) = self.parts {
            if let Some(m) = p.mesh(c)? {
                return Ok(m);
            }
        }
        mesh_chunk(store, c, field, self.mesher)
    }
}
