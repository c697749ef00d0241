//! One `.mcap` file of a bag, read front to back through the `mcap` crate's sans-io
//! [`LinearReader`](mcap::sans_io::LinearReader): a few MiB at a time (one chunk decompressed
//! at once), never the whole file. Messages are addressed by their ordinal in the file; reading
//! them in increasing order continues one pass, a smaller ordinal starts a new one.
//!
//! A file cut short or damaged (a truncated chunk, a bad CRC) is read up to the damage, which
//! is reported with the byte offset reached.

use super::{Damage, Message};
use crate::{Error, Result};
use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// A front-to-back pass over one file.
struct Pass {
    file: std::fs::File,
    reader: LinearReader,
    /// Bytes handed to the reader so far.
    offset: u64,
    /// The file's size.
    len: u64,
    /// Ordinal of the next message.
    next: u64,
    /// channel id → (topic, type).
    channels: HashMap<u16, (String, String)>,
    /// schema id → type name.
    schemas: HashMap<u16, String>,
    /// The last message's body (copied out of the reader's buffer).
    body: Vec<u8>,
}

/// What a pass yields next.
enum Next<'a> {
    Message {
        topic: &'a (String, String),
        log_time_ns: u64,
        data: &'a [u8],
    },
    End,
}

impl Pass {
    fn open(path: &Path) -> Result<Pass> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        Ok(Pass {
            file,
            // The end of a file cut short is the damage reported, not an error of the pass.
            // Chunk CRCs (where the writer stored them) are checked before a chunk's messages
            // are handed out; a record or chunk claiming more than 1 GiB is damage, not an
            // allocation.
            reader: LinearReader::new_with_options(
                LinearReaderOptions::default()
                    .with_skip_end_magic(false)
                    .with_prevalidate_chunk_crcs(true)
                    .with_record_length_limit(1 << 30),
            ),
            len,
            offset: 0,
            next: 0,
            channels: HashMap::new(),
            schemas: HashMap::new(),
            body: Vec::new(),
        })
    }

    /// Advances to the next message (its ordinal is `self.next - 1` once returned).
    fn next(&mut self, path: &Path) -> std::result::Result<Next<'_>, Damage> {
        let (channel, log_time_ns) = loop {
            let event = match self.reader.next_event() {
                None => return Ok(Next::End),
                Some(Err(e)) => return Err(self.damage(path, e.to_string())),
                Some(Ok(event)) => event,
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let remaining = self.len.saturating_sub(self.offset);
                    if need as u64 > remaining && remaining > 0 {
                        let msg = format!("a record needs {need} more bytes where {remaining} remain: the file is cut short or a record's length is damaged");
                        return Err(self.damage(path, msg));
                    }
                    let want = need.max(1 << 16).min(remaining.max(1) as usize);
                    let buf = self.reader.insert(want);
                    let n = match self.file.read(buf) {
                        Ok(n) => n,
                        Err(e) => return Err(self.damage(path, e.to_string())),
                    };
                    self.reader.notify_read(n);
                    self.offset += n as u64;
                }
                LinearReadEvent::Record { opcode, data } => {
                    let record = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => {
                            let msg = format!("malformed record (opcode {opcode:#x}): {e}");
                            return Err(self.damage(path, msg));
                        }
                    };
                    match record {
                        Record::Schema { header, .. } => {
                            self.schemas.insert(header.id, header.name);
                        }
                        Record::Channel(c) => {
                            let ty = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                            self.channels.insert(c.id, (c.topic, ty));
                        }
                        Record::Message { header, data: body } => {
                            self.body.clear();
                            self.body.extend_from_slice(&body);
                            self.next += 1;
                            break (header.channel_id, header.log_time);
                        }
                        _ => {}
                    }
                }
            }
        };
        match self.channels.get(&channel) {
            Some(topic) => Ok(Next::Message {
                topic,
                log_time_ns,
                data: &self.body,
            }),
            None => Err(self.damage(path, format!("a message on unknown channel {channel}"))),
        }
    }

    fn damage(&self, path: &Path, message: String) -> Damage {
        Damage {
            path: path.to_path_buf(),
            offset: self.offset,
            message,
        }
    }
}

/// One `.mcap` file.
pub struct McapFile {
    path: PathBuf,
    /// The pass `fetch` continues.
    cursor: std::sync::Mutex<Option<Pass>>,
}

impl McapFile {
    /// Opens `path` (read lazily).
    pub fn open(path: &Path) -> Result<McapFile> {
        std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        Ok(McapFile {
            path: path.to_path_buf(),
            cursor: std::sync::Mutex::new(None),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Hands every message to `visit`, in file order, with its ordinal as locator; returns the
    /// damage that stopped the pass early, if any.
    pub fn scan(&self, visit: &mut dyn FnMut(Message<'_>) -> Result<()>) -> Result<Option<Damage>> {
        let mut pass = Pass::open(&self.path)?;
        loop {
            let offset = pass.offset;
            let locator = pass.next;
            match pass.next(&self.path) {
                Ok(Next::End) => return Ok(None),
                Ok(Next::Message {
                    topic,
                    log_time_ns,
                    data,
                }) => visit(Message {
                    topic: &topic.0,
                    type_name: &topic.1,
                    log_time_ns,
                    data,
                    locator,
                    offset,
                })?,
                Err(damage) => return Ok(Some(damage)),
            }
        }
    }

    /// The body of message `ordinal` (continuing the last pass when it lies ahead).
    pub fn fetch(&self, ordinal: u64) -> Result<Vec<u8>> {
        let mut cursor = self.cursor.lock().unwrap_or_else(|e| e.into_inner());
        if cursor.as_ref().is_none_or(|p| p.next > ordinal) {
            *cursor = Some(Pass::open(&self.path)?);
        }
        let pass = cursor.as_mut().expect("opened above");
        loop {
            let at = pass.next;
            match pass.next(&self.path) {
                Ok(Next::Message { data, .. }) if at == ordinal => return Ok(data.to_vec()),
                Ok(Next::Message { .. }) => {}
                Ok(Next::End) => {
                    return Err(Error::bad_input(
                        &self.path,
                        format!(
                        "message {ordinal} is past the end of the file (it changed while read?)"
                    ),
                    ))
                }
                Err(d) => return Err(Error::bad_input(&self.path, d.to_string())),
            }
        }
    }
}
