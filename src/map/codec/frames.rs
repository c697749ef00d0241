//! A previous file's compressed parts, for rewriting a chunk of which only some parts change.
//!
//! Format 3 compresses each payload part as its own zstd frame. A regularization pass rewrites a
//! chunk with `u` added: the block flags and the `u` parts change, while the coordinates,
//! weights, TSDF and colour parts stay byte for byte what they were. Copying those parts' frames
//! from the file being replaced skips compressing them again (the structured parts at level 15:
//! most of a rewrite's time). A frame is reused only when it decompresses to exactly the part
//! being written, so the new file decodes to the same blocks whatever the old file was; when the
//! old file was compressed at the same levels, the new file is byte-identical to a fresh encode.

use super::{decode_header_with_origin, header_len, le_u16, CHUNK_VERSION_3};

/// The zstd frames of a format-3 chunk file's payload, each with what it decompresses to.
#[derive(Debug, Default)]
pub struct PreviousFrames<'a> {
    frames: Vec<(Vec<u8>, &'a [u8])>,
}

impl<'a> PreviousFrames<'a> {
    /// The frames of `file` (a complete chunk file). Empty, so that every part is compressed
    /// afresh, when `file` is not format 3 or 4 or its payload does not split into frames.
    pub fn of(file: &'a [u8]) -> Self {
        Self::split(file).unwrap_or_default()
    }

    fn split(file: &'a [u8]) -> Option<Self> {
        let (h, origin) = decode_header_with_origin(file).ok()?;
        if le_u16(file, 8) < CHUNK_VERSION_3 {
            return None;
        }
        let start = header_len(origin.as_ref());
        let mut rest = file.get(start..start + h.payload_zstd_bytes as usize)?;
        let cap = h.payload_raw_bytes as usize;
        let mut frames = Vec::new();
        while !rest.is_empty() {
            let len = zstd::zstd_safe::find_frame_compressed_size(rest).ok()?;
            let (frame, tail) = rest.split_at_checked(len)?;
            frames.push((zstd::bulk::decompress(frame, cap).ok()?, frame));
            rest = tail;
        }
        Some(PreviousFrames { frames })
    }

    /// A frame that decompresses to exactly `part`.
    pub fn frame_of(&self, part: &[u8]) -> Option<&'a [u8]> {
        self.frames
            .iter()
            .find(|(plain, _)| plain.as_slice() == part)
            .map(|(_, frame)| *frame)
    }

    /// Number of frames found.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame was found.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}
