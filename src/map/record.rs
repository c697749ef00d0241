//! The framing shared by the map's small bincode records (`job.djr`, the sweep progress record):
//! magic (4 bytes), version (`u16` LE), 2 reserved zero bytes, payload length (`u32` LE), the
//! bincode 2 payload (standard config), CRC-32 of everything before it (`u32` LE). Byte tables:
//! `formats/job.md`, `formats/sweep-state.md`.

use crate::{Error, Result};
use std::path::Path;

/// The framed bytes of `value`.
pub(crate) fn encode<T: bincode::Encode>(magic: [u8; 4], version: u16, value: &T) -> Vec<u8> {
    let payload = bincode::encode_to_vec(value, bincode::config::standard())
        .expect("encoding to a Vec cannot fail");
    let mut out = Vec::with_capacity(16 + payload.len());
    out.extend_from_slice(&magic);
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&payload);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Decodes framed bytes of file `path`. `what` names the record in errors ("job record"),
/// `short` its version and checksum messages ("job record", "sweep progress").
pub(crate) fn decode<T: bincode::Decode<()>>(
    path: &Path,
    b: &[u8],
    magic: [u8; 4],
    version_read: u16,
    what: &str,
    short: &str,
) -> Result<T> {
    let bad = |m: String| Error::bad_input(path, m);
    if b.len() < 16 || b[..4] != magic {
        return Err(bad(format!("not a denser {what} (bad magic)")));
    }
    let version = u16::from_le_bytes([b[4], b[5]]);
    if version != version_read {
        return Err(bad(format!(
            "{short} version {version}, this denser reads version {version_read}"
        )));
    }
    let len = u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize;
    if b.len() != 16 + len {
        return Err(bad(format!(
            "{what} is {} bytes, its header says {}",
            b.len(),
            16 + len
        )));
    }
    let crc = u32::from_le_bytes([b[12 + len], b[13 + len], b[14 + len], b[15 + len]]);
    if crc32fast::hash(&b[..12 + len]) != crc {
        return Err(bad(format!("{short} checksum mismatch (corrupted)")));
    }
    let (record, used) =
        bincode::decode_from_slice::<T, _>(&b[12..12 + len], bincode::config::standard())
            .map_err(|e| bad(format!("{short} payload: {e}")))?;
    if used != len {
        return Err(bad(format!(
            "{short} payload has {} trailing bytes",
            len - used
        )));
    }
    Ok(record)
}
