//! One `.db3` file of a bag (rosbag2's SQLite3 storage, ROS 2 Foxy to Humble's default) through
//! `rusqlite`: `topics(id, name, type, …)` and `messages(id, topic_id, timestamp, data)`.
//! Messages are streamed row by row in insertion order and addressed by their row id.

use super::{Damage, Message};
use crate::{Error, Result};
use rusqlite::{Connection, OpenFlags};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// One SQLite3 bag file, opened read-only.
pub struct SqliteFile {
    path: PathBuf,
    db: Mutex<Connection>,
}

fn sql(path: &Path, e: rusqlite::Error) -> Error {
    Error::bad_input(path, format!("SQLite: {e}"))
}

impl SqliteFile {
    /// Opens `path` read-only; fails unless it holds rosbag2's tables.
    pub fn open(path: &Path) -> Result<SqliteFile> {
        std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let db = Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_ONLY)
            .map_err(|e| sql(path, e))?;
        let tables: i64 = db
            .query_row(
                "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name IN ('topics', 'messages')",
                [],
                |r| r.get(0),
            )
            .map_err(|e| sql(path, e))?;
        if tables != 2 {
            return Err(Error::bad_input(
                path,
                "not a rosbag2 SQLite3 file (no 'topics' and 'messages' tables)",
            ));
        }
        Ok(SqliteFile {
            path: path.to_path_buf(),
            db: Mutex::new(db),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Hands every message to `visit` in insertion order, its row id as locator; a read error
    /// part-way is returned as the damage that stopped the pass.
    pub fn scan(&self, visit: &mut dyn FnMut(Message<'_>) -> Result<()>) -> Result<Option<Damage>> {
        let db = self.db.lock().unwrap_or_else(|e| e.into_inner());
        let mut topics: HashMap<i64, (String, String)> = HashMap::new();
        {
            let mut st = db
                .prepare("SELECT id, name, type FROM topics")
                .map_err(|e| sql(&self.path, e))?;
            let rows = st
                .query_map([], |r| Ok((r.get(0)?, (r.get(1)?, r.get(2)?))))
                .map_err(|e| sql(&self.path, e))?;
            for row in rows {
                let (id, topic) = row.map_err(|e| sql(&self.path, e))?;
                topics.insert(id, topic);
            }
        }
        let mut st = db
            .prepare("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id")
            .map_err(|e| sql(&self.path, e))?;
        let mut rows = st.query([]).map_err(|e| sql(&self.path, e))?;
        let mut offset = 0u64;
        let damage = |offset, e: rusqlite::Error| Damage {
            path: self.path.clone(),
            offset,
            message: format!("SQLite: {e}"),
        };
        loop {
            let row = match rows.next() {
                Ok(Some(row)) => row,
                Ok(None) => return Ok(None),
                Err(e) => return Ok(Some(damage(offset, e))),
            };
            let fields = (|| -> rusqlite::Result<(i64, i64, i64, &[u8])> {
                Ok((
                    row.get(0)?,
                    row.get(1)?,
                    row.get(2)?,
                    row.get_ref(3)?.as_blob()?,
                ))
            })();
            let (id, topic_id, stamp, data) = match fields {
                Ok(f) => f,
                Err(e) => return Ok(Some(damage(offset, e))),
            };
            let Some(topic) = topics.get(&topic_id) else {
                let message =
                    format!("message {id} names topic id {topic_id}, which the topics table lacks");
                return Ok(Some(Damage {
                    path: self.path.clone(),
                    offset,
                    message,
                }));
            };
            visit(Message {
                topic: &topic.0,
                type_name: &topic.1,
                log_time_ns: stamp.max(0) as u64,
                data,
                locator: id as u64,
                offset,
            })?;
            offset += data.len() as u64;
        }
    }

    /// The body of the message with row id `id`.
    pub fn fetch(&self, id: u64) -> Result<Vec<u8>> {
        let db = self.db.lock().unwrap_or_else(|e| e.into_inner());
        db.query_row(
            "SELECT data FROM messages WHERE id = ?1",
            [id as i64],
            |r| r.get(0),
        )
        .map_err(|e| sql(&self.path, e))
    }
}
