//! A point set bucketed by cubic tiles into one scratch file: points arrive in any order (scan by
//! scan, vertex by vertex), wait in per-tile buffers while they fit, and are appended to the file
//! as segments of their tile; a tile is read back whole, from its segments.
//!
//! Byte layout of the scratch file: segments one after another, each `count × 12` bytes of
//! `[f32; 3]` little endian, the point's offset from its tile's lower corner (metres, within
//! `[0, side)`: sub-micrometre precision whatever the coordinates' magnitude). Which segments
//! belong to which tile is kept in memory ([`TileInfo`]); the file has no header.

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// A tile: integer coordinates of its lower corner in units of the tile side.
pub(crate) type TileKey = [i32; 3];

/// Where a tile's points are, and their tight bounds.
#[derive(Clone, Debug)]
pub(crate) struct TileInfo {
    /// `(byte offset, points)` of each segment.
    segments: Vec<(u64, u32)>,
    /// Points in the tile.
    pub count: u64,
    /// Tight bounds of the points as stored (world frame, metres).
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

/// Points bucketed by tile: being written ([`TileSpill::push`]) or read ([`TileSpill::load`]).
pub(crate) struct TileSpill {
    path: PathBuf,
    side_m: f64,
    writer: Option<BufWriter<std::fs::File>>,
    file: std::fs::File,
    written: u64,
    buffers: HashMap<TileKey, Vec<[f32; 3]>>,
    buffered: usize,
    max_buffered: usize,
    tiles: HashMap<TileKey, TileInfo>,
}

impl TileSpill {
    /// A new spill file at `path` (created, replaced, removed on drop) of tiles `side_m` metres
    /// wide, holding at most `max_buffered` points in memory before it writes them out.
    pub(crate) fn create(path: &Path, side_m: f64, max_buffered: usize) -> Result<TileSpill> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(true)
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        let writer =
            BufWriter::with_capacity(1 << 20, file.try_clone().map_err(|e| Error::io(path, e))?);
        Ok(TileSpill {
            path: path.to_path_buf(),
            side_m,
            writer: Some(writer),
            file,
            written: 0,
            buffers: HashMap::new(),
            buffered: 0,
            max_buffered: max_buffered.max(1),
            tiles: HashMap::new(),
        })
    }

    /// The tile holding `p` (world frame, metres), and `p`'s offset from its corner.
    pub(crate) fn key_of(&self, p: [f64; 3]) -> (TileKey, [f32; 3]) {
        let key = p.map(|v| (v / self.side_m).floor() as i32);
        let corner = self.corner_m(key);
        let off = [0, 1, 2].map(|a| ((p[a] - corner[a]) as f32).clamp(0.0, self.side_m as f32));
        (key, off)
    }

    /// The lower corner of tile `key`, metres.
    pub(crate) fn corner_m(&self, key: TileKey) -> [f64; 3] {
        key.map(|k| k as f64 * self.side_m)
    }

    /// Adds a point (world frame, metres; must be finite).
    pub(crate) fn push(&mut self, p: [f64; 3]) -> Result<()> {
        let (key, off) = self.key_of(p);
        self.buffers.entry(key).or_default().push(off);
        self.buffered += 1;
        if self.buffered >= self.max_buffered {
            self.flush_buffers()?;
        }
        Ok(())
    }

    /// Writes every buffered point out as one segment per tile.
    fn flush_buffers(&mut self) -> Result<()> {
        let mut keys: Vec<TileKey> = self.buffers.keys().copied().collect();
        keys.sort_unstable();
        let writer = self.writer.as_mut().expect("flushed before finish");
        for key in keys {
            let points = self.buffers.remove(&key).expect("a listed key");
            let corner = key.map(|k| k as f64 * self.side_m);
            let info = self.tiles.entry(key).or_insert_with(|| TileInfo {
                segments: Vec::new(),
                count: 0,
                lo: [f64::INFINITY; 3],
                hi: [f64::NEG_INFINITY; 3],
            });
            let mut bytes = Vec::with_capacity(points.len() * 12);
            for p in &points {
                for a in 0..3 {
                    bytes.extend_from_slice(&p[a].to_le_bytes());
                    let w = corner[a] + p[a] as f64;
                    info.lo[a] = info.lo[a].min(w);
                    info.hi[a] = info.hi[a].max(w);
                }
            }
            writer
                .write_all(&bytes)
                .map_err(|e| Error::io(&self.path, e))?;
            info.segments.push((self.written, points.len() as u32));
            info.count += points.len() as u64;
            self.written += bytes.len() as u64;
        }
        self.buffered = 0;
        Ok(())
    }

    /// Ends writing: every point is in the file from here on.
    pub(crate) fn finish(&mut self) -> Result<()> {
        self.flush_buffers()?;
        if let Some(w) = self.writer.take() {
            w.into_inner()
                .map_err(|e| Error::io(&self.path, e.into_error()))?;
        }
        self.buffers.shrink_to_fit();
        Ok(())
    }

    /// The tiles, in Morton order of their keys (neighbours close together in the order).
    pub(crate) fn keys(&self) -> Vec<TileKey> {
        let mut keys: Vec<TileKey> = self.tiles.keys().copied().collect();
        let lo = keys
            .iter()
            .fold([i32::MAX; 3], |m, k| [0, 1, 2].map(|a| m[a].min(k[a])));
        keys.sort_by_key(|k| morton([0, 1, 2].map(|a| (k[a] as i64 - lo[a] as i64) as u64)));
        keys
    }

    /// A tile's segments and bounds.
    pub(crate) fn info(&self, key: &TileKey) -> Option<&TileInfo> {
        self.tiles.get(key)
    }

    /// Every tile's bounds.
    pub(crate) fn tiles(&self) -> impl Iterator<Item = (&TileKey, &TileInfo)> {
        self.tiles.iter()
    }

    /// Points in all tiles.
    pub(crate) fn len(&self) -> u64 {
        self.tiles.values().map(|t| t.count).sum()
    }

    /// Bytes written to the scratch file.
    pub(crate) fn bytes(&self) -> u64 {
        self.written
    }

    /// The points of tile `key`, as offsets from its corner (empty when it has none).
    pub(crate) fn load(&self, key: &TileKey) -> Result<Vec<[f32; 3]>> {
        let Some(info) = self.tiles.get(key) else {
            return Ok(Vec::new());
        };
        let mut out = Vec::with_capacity(info.count as usize);
        let mut bytes = Vec::new();
        for &(offset, n) in &info.segments {
            bytes.resize(n as usize * 12, 0);
            self.file
                .read_exact_at(&mut bytes, offset)
                .map_err(|e| Error::io(&self.path, e))?;
            out.extend(bytes.chunks_exact(12).map(|r| {
                [0, 1, 2].map(|a| f32::from_le_bytes(r[4 * a..4 * a + 4].try_into().expect("4")))
            }));
        }
        Ok(out)
    }
}

impl Drop for TileSpill {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Interleaves the low 21 bits of three coordinates (a Morton code).
fn morton(k: [u64; 3]) -> u64 {
    let spread = |v: u64| {
        let mut x = v & 0x1f_ffff;
        x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
        x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
        x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
        x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
        (x | (x << 2)) & 0x1249_2492_4924_9249
    };
    spread(k[0]) | (spread(k[1]) << 1) | (spread(k[2]) << 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_come_back_in_their_tiles_whatever_the_flushes() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = TileSpill::create(&dir.path().join("s.bin"), 8.0, 7).unwrap();
        let mut expected: HashMap<TileKey, Vec<[f64; 3]>> = HashMap::new();
        let mut x = 12345u64;
        for _ in 0..1000 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let p = [0, 1, 2].map(|a| ((x >> (10 + 15 * a)) % 4000) as f64 * 0.01 - 20.0);
            s.push(p).unwrap();
            expected.entry(s.key_of(p).0).or_default().push(p);
        }
        s.finish().unwrap();
        assert_eq!(s.len(), 1000);
        assert_eq!(s.keys().len(), expected.len());
        for (key, want) in &expected {
            let corner = s.corner_m(*key);
            let got = s.load(key).unwrap();
            assert_eq!(got.len(), want.len());
            let info = s.info(key).unwrap();
            for (g, w) in got.iter().zip(want) {
                for a in 0..3 {
                    let back = corner[a] + g[a] as f64;
                    assert!((back - w[a]).abs() < 1e-6, "{back} {}", w[a]);
                    assert!(back >= info.lo[a] && back <= info.hi[a]);
                    assert!(w[a] >= corner[a] && w[a] < corner[a] + 8.0);
                }
            }
        }
        let path = dir.path().join("s.bin");
        assert!(path.exists());
        drop(s);
        assert!(!path.exists(), "the scratch file is removed");
    }
}
