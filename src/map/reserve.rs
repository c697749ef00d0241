//! File-number reservations (the rule is stated in [`super::layout`]): a record
//! `shards/KEY/plan.json` whose `seq_base` and `chunks` fields hold chunk file numbers for writers
//! other than the map's writer (an array job's shards, `formats/shards.md`). The writer's clean-up
//! at open leaves the files in an open reservation's range alone; its owner closes it with
//! [`super::store::MapStore::remove_unnamed_in`] and deletes the record.

use super::files::MapFiles;
use super::layout::{RESERVATION_FILE, SHARDS_AREA};
use crate::error::{Error, Result};
use std::ops::Range;

/// What the engine reads of a reservation: the file numbers it holds. Other fields of the record
/// belong to its owner and are ignored here.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
pub struct Reservation {
    /// First reserved chunk file number.
    pub seq_base: u64,
    /// Numbers reserved (`seq_base .. seq_base + chunks`).
    pub chunks: u64,
}

impl Reservation {
    /// The file numbers it holds.
    pub fn range(&self) -> Range<u64> {
        self.seq_base..self.seq_base + self.chunks
    }
}

/// The name of reservation `folder` (`shards/FOLDER/plan.json`).
pub fn reservation_name(folder: &str) -> String {
    format!("{SHARDS_AREA}/{folder}/{RESERVATION_FILE}")
}

/// Every reservation's record under [`SHARDS_AREA`], by object name, sorted by name.
pub fn reservation_objects(files: &dyn MapFiles) -> Result<Vec<String>> {
    Ok(files
        .list_recursive(SHARDS_AREA)?
        .into_iter()
        .filter(|o| {
            o.name.matches('/').count() == 1 && o.name.ends_with(&format!("/{RESERVATION_FILE}"))
        })
        .map(|o| format!("{SHARDS_AREA}/{}", o.name))
        .collect())
}

/// The file numbers held by every open reservation: writers opening the map leave those files
/// alone. An unreadable reservation is reported and skipped.
pub fn reservations(files: &dyn MapFiles) -> Result<Vec<Range<u64>>> {
    let mut out = Vec::new();
    for name in reservation_objects(files)? {
        let Some((bytes, _)) = files.read_versioned(&name)? else {
            continue;
        };
        match serde_json::from_slice::<Reservation>(&bytes) {
            Ok(r) => out.push(r.range()),
            Err(e) => tracing::warn!(
                "{}",
                Error::bad_input(files.path(&name), format!("not a valid record: {e}"))
            ),
        }
    }
    Ok(out)
}
