//! Chunk files as bytes: decoding what was read (checked against nothing but itself), and
//! [`ChunkWriter`], which encodes and writes them.

use super::*;

/// Memory-maps and decodes one chunk file (either format); errors name the file. Checks only
/// the file itself: [`MapStore::read_chunk`] also checks it against the manifest.
pub fn read_chunk_file(path: &Path) -> Result<DecodedChunk> {
    read_chunk_file_len(path).map(|(d, _)| d)
}

pub(super) fn read_chunk_file_len(path: &Path) -> Result<(DecodedChunk, u64)> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map_or(String::new(), |n| n.to_string_lossy().into_owned());
    let files = crate::map::files::LocalFiles::new(dir);
    decode_object(&files, &name, files.read(&name)?)
}

/// Reads and decodes chunk object `name` of `files` (either format), with its size; errors name
/// it. Checks only the object itself.
pub fn read_chunk_object(files: &dyn MapFiles, name: &str) -> Result<(DecodedChunk, u64)> {
    decode_object(files, name, files.read(name)?)
}

/// Decodes a chunk object read from `files`; errors name it.
pub(super) fn decode_object(
    files: &dyn MapFiles,
    name: &str,
    bytes: Option<ObjectBytes>,
) -> Result<(DecodedChunk, u64)> {
    decode_object_bytes(files, name, bytes).map(|(d, b)| (d, b.len() as u64))
}

/// [`decode_object`] keeping the object's bytes.
pub(super) fn decode_object_bytes(
    files: &dyn MapFiles,
    name: &str,
    bytes: Option<ObjectBytes>,
) -> Result<(DecodedChunk, ObjectBytes)> {
    let path = files.path(name);
    let Some(bytes) = bytes else {
        return Err(Error::bad_input(
            path,
            "chunk file named by the manifest is missing (deleted by hand?); `inspect --verify` lists every problem",
        ));
    };
    if bytes.is_empty() {
        return Err(Error::bad_input(path, "empty chunk file"));
    }
    let d = decode_chunk(&bytes)
        .map_err(|e| Error::bad_input(&path, format!("corrupted chunk: {e}")))?;
    Ok((d, bytes))
}

impl MapStore {
    /// Reads and decodes chunk object `name` (through the object-store cache where there is
    /// one); errors name it.
    pub(super) fn read_object(&self, name: &str) -> Result<(DecodedChunk, ObjectBytes)> {
        if let Some(cache) = &self.cache {
            let bytes = match cache.get(name) {
                Some(b) => Some(ObjectBytes::Owned(b)),
                None => match self.files.read(name)? {
                    Some(ObjectBytes::Owned(b)) => {
                        cache.put(name, b.clone());
                        Some(ObjectBytes::Owned(b))
                    }
                    other => other,
                },
            };
            return decode_object_bytes(&*self.files, name, bytes);
        }
        decode_object_bytes(&*self.files, name, self.files.read(name)?)
    }

    /// Reads the file `e` names for chunk `c` and checks it: both CRCs, then against the entry and
    /// the manifest — file size, chunk coordinate, chunk edge, voxel size, μ, block count, payload
    /// CRC, whether it carries `u`, voxels in Ω, and (format-2 files) the map id, the file sequence
    /// number and the regularization pass. Any mismatch is an error naming the file, the chunk and
    /// every field that differs: a file replaced by another one (an older version, the same chunk
    /// of another map) is never read as if it were the committed one.
    pub fn read_entry(&self, c: ChunkIndex, e: &ChunkEntry) -> Result<DecodedChunk> {
        self.read_entry_bytes(c, e).map(|(d, _)| d)
    }

    /// [`MapStore::read_entry`] keeping the file's bytes.
    pub fn read_entry_bytes(
        &self,
        c: ChunkIndex,
        e: &ChunkEntry,
    ) -> Result<(DecodedChunk, ObjectBytes)> {
        let path = self.file_path(c, e.file_seq);
        let (d, bytes) = self.read_object(&chunk_object(c, e.file_seq))?;
        let len = bytes.len();
        let h = &d.header;
        let m = &self.manifest.header;
        let mut diff: Vec<String> = Vec::new();
        let mut field = |name: &str, file: String, want: String| {
            if file != want {
                diff.push(format!("{name} {file} (manifest: {want})"));
            }
        };
        field("chunk", format!("{:?}", h.chunk.0), format!("{:?}", c.0));
        field(
            "size",
            format!("{len} bytes"),
            format!("{} bytes", e.file_bytes),
        );
        field(
            "chunk edge",
            h.chunk_blocks.to_string(),
            m.chunk_blocks.to_string(),
        );
        field(
            "voxel size",
            format!("{} m", h.voxel_size_m),
            format!("{} m", m.voxel_size_m),
        );
        field(
            "μ",
            format!("{} m", h.truncation_m),
            format!("{} m", m.truncation_m),
        );
        field(
            "blocks",
            h.block_count.to_string(),
            e.block_count.to_string(),
        );
        field(
            "payload CRC",
            format!("{:#010x}", h.payload_crc32),
            format!("{:#010x}", e.payload_crc32),
        );
        field(
            "carries u",
            (h.flags & FLAG_HAS_REGULARIZED != 0).to_string(),
            (e.flags & ENTRY_HAS_REGULARIZED != 0).to_string(),
        );
        if let Some(o) = &d.origin {
            field(
                "file number",
                o.file_seq.to_string(),
                e.file_seq.to_string(),
            );
            if o.map_id != 0 && m.map_id != 0 {
                field(
                    "map id",
                    format!("{:016x}", o.map_id),
                    format!("{:016x}", m.map_id),
                );
            }
            field("pass", o.reg_pass.to_string(), e.reg_pass.to_string());
        }
        if h.block_count == e.block_count {
            let obs = count_observed(d.blocks.iter().map(|(_, b)| &**b));
            field("Ω voxels", obs.to_string(), e.observed_voxels.to_string());
        }
        if !diff.is_empty() {
            return Err(Error::bad_input(
                &path,
                format!(
                    "chunk {:?} does not match its manifest entry: {}; the file was replaced (an older version, or another map's) and is not read",
                    c.0,
                    diff.join(", ")
                ),
            ));
        }
        Ok((d, bytes))
    }

    /// [`MapStore::read_chunk`] keeping the file's bytes, for [`MapStore::rewrite_chunk`].
    pub fn read_chunk_bytes(&self, c: ChunkIndex) -> Result<Option<(DecodedChunk, ObjectBytes)>> {
        match self.manifest.chunks.get(&c) {
            None => Ok(None),
            Some(e) => self.read_entry_bytes(c, e).map(Some),
        }
    }

    /// Writes a chunk file encoded by [`ChunkWriter::encode_reusing`] (crash-safely, under its own
    /// number) and records it in the manifest (committed by the next [`MapStore::commit`]).
    pub fn write_encoded_chunk(&mut self, w: WrittenChunk, bytes: &[u8]) -> Result<()> {
        self.require_writer("writing a chunk")?;
        self.files
            .write_chunk(&chunk_object(w.chunk, w.entry.file_seq), bytes)?;
        self.record(w);
        Ok(())
    }

    /// [`MapStore::write_chunk`] for a chunk whose file `previous` (as read by
    /// [`MapStore::read_chunk_bytes`]) this one replaces: the parts that did not change keep
    /// their compressed frames ([`PreviousFrames`]).
    pub fn rewrite_chunk(
        &mut self,
        c: ChunkIndex,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
        previous: &[u8],
    ) -> Result<()> {
        self.require_writer("writing a chunk")?;
        let seq = self.allocate_seq();
        let w =
            self.writer()
                .write_reusing(c, seq, blocks, reg_pass, &PreviousFrames::of(previous))?;
        self.record(w);
        Ok(())
    }
}

/// Encodes and writes chunk files; cheap to clone and `Send`, so background workers can own one.
#[derive(Clone, Debug)]
pub struct ChunkWriter {
    pub(super) files: Arc<dyn MapFiles>,
    pub(super) grid: GridParams,
    pub(super) chunk_blocks: u32,
    pub(super) zstd_level: i32,
    pub(super) map_id: u64,
    /// The latest regularization pass and its parameters when the writer was made.
    pub(super) pass: (u32, TvParams),
    /// The commit generation to stamp, as the store advances it ([`MapStore::writer`]).
    pub(super) commit_gen: Arc<std::sync::atomic::AtomicU64>,
}

impl ChunkWriter {
    /// Encodes `blocks` of chunk `c` as file number `seq` without writing it, copying the frames
    /// of `previous` for the parts that did not change; written by
    /// [`MapStore::write_encoded_chunk`]. Lets callers encode on many threads and write in order.
    pub fn encode_reusing(
        &self,
        c: ChunkIndex,
        seq: u64,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
        previous: &PreviousFrames,
    ) -> (Vec<u8>, WrittenChunk) {
        let header = ChunkHeader {
            voxel_size_m: self.grid.voxel_size_m,
            truncation_m: self.grid.truncation_m,
            chunk: c,
            chunk_blocks: self.chunk_blocks,
            block_count: 0,
            flags: 0,
            payload_raw_bytes: 0,
            payload_zstd_bytes: 0,
            payload_crc32: 0,
        };
        let origin = ChunkOrigin {
            map_id: self.map_id,
            file_seq: seq,
            reg_pass,
            reg_params: if reg_pass != 0 && reg_pass == self.pass.0 {
                self.pass.1
            } else {
                NO_PARAMS
            },
            commit_gen: self.commit_gen.load(std::sync::atomic::Ordering::SeqCst),
        };
        let bytes = encode_chunk_v4_reusing(&header, &origin, blocks, self.zstd_level, previous);
        let has_reg = blocks.iter().any(|(_, b)| b.regularized.is_some());
        let w = WrittenChunk {
            chunk: c,
            entry: ChunkEntry {
                block_count: blocks.len() as u32,
                observed_voxels: count_observed(blocks.iter().map(|(_, b)| *b)),
                flags: if has_reg { ENTRY_HAS_REGULARIZED } else { 0 },
                file_seq: seq,
                file_bytes: bytes.len() as u64,
                payload_crc32: u32::from_le_bytes(bytes[52..56].try_into().expect("header")),
                reg_pass,
            },
        };
        (bytes, w)
    }

    /// Encodes `blocks` of chunk `c` and writes them crash-safely as file number `seq` (from
    /// [`MapStore::allocate_seq`]), in chunk format 2 with its origin (this map, `seq`,
    /// `reg_pass` and that pass's parameters). The result must be given to [`MapStore::record`].
    pub fn write(
        &self,
        c: ChunkIndex,
        seq: u64,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
    ) -> Result<WrittenChunk> {
        self.write_reusing(c, seq, blocks, reg_pass, &PreviousFrames::default())
    }

    /// [`ChunkWriter::write`] copying the frames of `previous` for the parts that did not change.
    pub fn write_reusing(
        &self,
        c: ChunkIndex,
        seq: u64,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
        previous: &PreviousFrames,
    ) -> Result<WrittenChunk> {
        let (bytes, w) = self.encode_reusing(c, seq, blocks, reg_pass, previous);
        self.files.write_chunk(&chunk_object(c, seq), &bytes)?;
        Ok(w)
    }

    /// [`ChunkWriter::write`] for a regularization shard, create-only: when file `seq` of chunk
    /// `c` exists already (a shard run again after it was killed, or two runs of one shard), the
    /// existing file is kept and its entry returned, once its origin says it is this map's file
    /// `seq` of `c` at `reg_pass`. `previous`: the file this one replaces, whose unchanged parts'
    /// frames are copied.
    pub fn write_once(
        &self,
        c: ChunkIndex,
        seq: u64,
        blocks: &[(BlockIndex, &Block)],
        reg_pass: u32,
        previous: Option<&ObjectBytes>,
    ) -> Result<WrittenChunk> {
        let name = chunk_object(c, seq);
        let frames = previous.map(|p| PreviousFrames::of(p)).unwrap_or_default();
        let (bytes, w) = self.encode_reusing(c, seq, blocks, reg_pass, &frames);
        if self.files.write_new(&name, &bytes)? {
            return Ok(w);
        }
        let (d, len) = decode_object(&*self.files, &name, self.files.read(&name)?)?;
        let ours = d.header.chunk == c
            && d.origin.is_some_and(|o| {
                o.file_seq == seq && o.map_id == self.map_id && o.reg_pass == reg_pass
            });
        if !ours {
            return Err(Error::bad_input(
                self.files.path(&name),
                format!(
                    "exists and is not this map's file {seq} of chunk {:?} at pass {reg_pass}; not replaced",
                    c.0
                ),
            ));
        }
        Ok(WrittenChunk {
            chunk: c,
            entry: ChunkEntry {
                block_count: d.header.block_count,
                observed_voxels: count_observed(d.blocks.iter().map(|(_, b)| &**b)),
                flags: if d.header.flags & FLAG_HAS_REGULARIZED != 0 {
                    ENTRY_HAS_REGULARIZED
                } else {
                    0
                },
                file_seq: seq,
                file_bytes: len,
                payload_crc32: d.header.payload_crc32,
                reg_pass,
            },
        })
    }
}
