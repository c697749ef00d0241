//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/data/<sub>` relative to the project root, or `None` (with a message saying the test
/// is skipped) when that folder is absent, as on a fresh clone.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data").join(sub);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipped: {} is absent (real data lives in ../shared/data)", p.display());
        None
    }
}
