//! Fault injection under the storage seam, the way SQLite tests itself with a failing VFS:
//! [`FaultyFiles`] wraps any [`MapFiles`] and, at the Nth operation that changes the map (a
//! whole-object write, a conditional write, a chunk write, a create-only write, a delete, a
//! retirement of superseded files), either
//!
//! - **fails** it with an I/O error and writes nothing ([`Fault::Error`]: a full disk, a refused
//!   PUT), the process going on as it would after such an error; or
//! - **crashes** ([`Fault::Crash`]): the operation is cut short as a killed process leaves it — a
//!   chunk written only under its temporary name, a retirement that deleted half its files, any
//!   other write or delete not done — and every later operation of the process fails, as if it
//!   had died there.
//!
//! Reads, listings and locks pass through. Operations are counted per process (every map the
//! process opens shares one counter), so a scripted run can be interrupted at each of its
//! operations in turn.
//!
//! The binary turns it on with the environment variable `DENSER_FAULT_INJECTION` (a testing hook:
//! `count`, `error@N` or `crash@N`), read once when a map location is opened
//! ([`super::location::MapLocation::open_files`]); with `count` it only counts, and `denser`
//! prints the count on exit. `tests/cli/faults.rs` drives it.

use super::files::{
    Conditional, Listed, MapFiles, ObjectBytes, ObjectVersion, ReaderHold, WriterHold,
};
use super::location::MapLocation;
use crate::error::{Error, Result};
use std::ops::Range;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// The environment variable that turns fault injection on in the binary.
pub const FAULT_INJECTION_VARIABLE: &str = "DENSER_FAULT_INJECTION";

/// What happens at the chosen operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The operation fails with an I/O error and changes nothing; later ones work.
    Error,
    /// The operation is cut short as by a kill, and every later one fails.
    Crash,
}

/// Where and how to inject: `None` only counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaultPlan {
    /// The 1-based number of the operation to break (`None`: count only).
    pub at: Option<u64>,
    /// What happens there.
    pub fault: Fault,
}

impl FaultPlan {
    /// Parses `count`, `error@N` or `crash@N` (N ≥ 1).
    pub fn parse(s: &str) -> Result<Self> {
        let bad = || {
            Error::InvalidArgument(format!(
                "{FAULT_INJECTION_VARIABLE}={s:?}: expected count, error@N or crash@N (N ≥ 1)"
            ))
        };
        if s == "count" {
            return Ok(FaultPlan {
                at: None,
                fault: Fault::Error,
            });
        }
        let (kind, n) = s.split_once('@').ok_or_else(bad)?;
        let fault = match kind {
            "error" => Fault::Error,
            "crash" => Fault::Crash,
            _ => return Err(bad()),
        };
        let n: u64 = n.parse().map_err(|_| bad())?;
        if n == 0 {
            return Err(bad());
        }
        Ok(FaultPlan { at: Some(n), fault })
    }

    /// The plan the environment asks for, if any.
    pub fn from_env() -> Result<Option<Self>> {
        match std::env::var(FAULT_INJECTION_VARIABLE) {
            Ok(v) => Self::parse(&v).map(Some),
            Err(_) => Ok(None),
        }
    }
}

/// Operations that changed (or tried to change) a map in this process, across every
/// [`FaultyFiles`].
static OPERATIONS: AtomicU64 = AtomicU64::new(0);
/// Set once a [`Fault::Crash`] happened: the process is "dead" to every map.
static CRASHED: AtomicBool = AtomicBool::new(false);

/// Operations counted so far in this process.
pub fn operations() -> u64 {
    OPERATIONS.load(Ordering::SeqCst)
}

/// A [`MapFiles`] that breaks the operation its [`FaultPlan`] names (module documentation).
#[derive(Debug)]
pub struct FaultyFiles {
    inner: Arc<dyn MapFiles>,
    plan: FaultPlan,
}

enum Step {
    Go,
    Crash,
}

impl FaultyFiles {
    /// `inner` with `plan`.
    pub fn new(inner: Arc<dyn MapFiles>, plan: FaultPlan) -> Self {
        FaultyFiles { inner, plan }
    }

    fn step(&self, what: &str, name: &str) -> Result<Step> {
        if CRASHED.load(Ordering::SeqCst) {
            return Err(self.crashed(what, name));
        }
        let n = OPERATIONS.fetch_add(1, Ordering::SeqCst) + 1;
        if self.plan.at != Some(n) {
            return Ok(Step::Go);
        }
        match self.plan.fault {
            Fault::Error => Err(Error::io(
                self.inner.path(name),
                std::io::Error::new(
                    std::io::ErrorKind::StorageFull,
                    format!(
                        "{what}: no space left on device (fault injected at map operation {n})"
                    ),
                ),
            )),
            Fault::Crash => {
                CRASHED.store(true, Ordering::SeqCst);
                Ok(Step::Crash)
            }
        }
    }

    fn crashed(&self, what: &str, name: &str) -> Error {
        Error::io(
            self.inner.path(name),
            std::io::Error::other(format!(
                "{what}: the process crashed at map operation {} (fault injection)",
                self.plan.at.unwrap_or(0)
            )),
        )
    }
}

impl MapFiles for FaultyFiles {
    fn location(&self) -> &MapLocation {
        self.inner.location()
    }
    fn path(&self, name: &str) -> PathBuf {
        self.inner.path(name)
    }
    fn exists(&self, name: &str) -> Result<bool> {
        self.inner.exists(name)
    }
    fn read(&self, name: &str) -> Result<Option<ObjectBytes>> {
        self.inner.read(name)
    }
    fn read_versioned(&self, name: &str) -> Result<Option<(Vec<u8>, ObjectVersion)>> {
        self.inner.read_versioned(name)
    }
    fn read_range(&self, name: &str, range: Range<u64>) -> Result<Vec<u8>> {
        self.inner.read_range(name, range)
    }
    fn write(&self, name: &str, bytes: &[u8]) -> Result<()> {
        match self.step("write", name)? {
            Step::Go => self.inner.write(name, bytes),
            // Killed before the rename: the object keeps its old content.
            Step::Crash => Err(self.crashed("write", name)),
        }
    }
    fn write_if(
        &self,
        name: &str,
        bytes: &[u8],
        prev: Option<&ObjectVersion>,
    ) -> Result<Conditional> {
        match self.step("conditional write", name)? {
            Step::Go => self.inner.write_if(name, bytes, prev),
            Step::Crash => Err(self.crashed("conditional write", name)),
        }
    }
    fn write_chunk(&self, name: &str, bytes: &[u8]) -> Result<()> {
        match self.step("chunk write", name)? {
            Step::Go => self.inner.write_chunk(name, bytes),
            Step::Crash => {
                // Killed between writing the temporary file and its rename: half of it is there
                // under the temporary name (what a local writer leaves; an object store leaves
                // nothing, which the clean-up handles the same way).
                if let Some(stem) = name.strip_suffix(".dchk") {
                    let _ = self
                        .inner
                        .write(&format!("{stem}.tmp"), &bytes[..bytes.len() / 2]);
                }
                Err(self.crashed("chunk write", name))
            }
        }
    }
    fn list(&self, folder: &str) -> Result<Vec<Listed>> {
        self.inner.list(folder)
    }
    fn list_recursive(&self, folder: &str) -> Result<Vec<Listed>> {
        self.inner.list_recursive(folder)
    }
    fn delete(&self, name: &str) -> Result<()> {
        match self.step("delete", name)? {
            Step::Go => self.inner.delete(name),
            Step::Crash => Err(self.crashed("delete", name)),
        }
    }
    fn lock_writer(&self) -> Result<Box<dyn WriterHold>> {
        self.inner.lock_writer()
    }
    fn writer_holding(&self) -> Option<String> {
        self.inner.writer_holding()
    }
    fn hold_readers(&self) -> Box<dyn ReaderHold> {
        self.inner.hold_readers()
    }
    fn retire(&self, names: &[String], generation: u64, map_id: u64) -> Result<bool> {
        let first = names.first().map_or("", String::as_str);
        match self.step("retire", first)? {
            Step::Go => self.inner.retire(names, generation, map_id),
            Step::Crash => {
                // Killed halfway through the deletions.
                for n in &names[..names.len() / 2] {
                    let _ = self.inner.delete(n);
                }
                Err(self.crashed("retire", first))
            }
        }
    }
    fn deletes_after_s(&self) -> Option<u64> {
        self.inner.deletes_after_s()
    }
    fn needs_fencing(&self) -> bool {
        self.inner.needs_fencing()
    }
    fn write_new(&self, name: &str, bytes: &[u8]) -> Result<bool> {
        match self.step("create-only write", name)? {
            Step::Go => self.inner.write_new(name, bytes),
            Step::Crash => Err(self.crashed("create-only write", name)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_parse() {
        assert_eq!(
            FaultPlan::parse("crash@7").unwrap(),
            FaultPlan {
                at: Some(7),
                fault: Fault::Crash
            }
        );
        assert_eq!(FaultPlan::parse("error@1").unwrap().fault, Fault::Error);
        assert_eq!(FaultPlan::parse("count").unwrap().at, None);
        for bad in ["crash@0", "crash", "boom@3", "error@x", ""] {
            assert!(FaultPlan::parse(bad).is_err(), "{bad}");
        }
    }
}
