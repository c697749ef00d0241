//! The map on disk: chunk and manifest formats, crash safety, paging, regional regularisation.

#[path = "../common/mod.rs"]
mod common;

mod format;
mod paging;
