//! Maps on S3 (and S3-compatible servers) through the `object_store` crate: the object-store
//! side of the storage seam ([`super::files::MapFiles`]).
//!
//! The bucket is configured by the standard environment (`AWS_ENDPOINT_URL`,
//! `AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_REGION`, `AWS_ALLOW_HTTP`, …, read by
//! `AmazonS3Builder::from_env`). The store owns a small tokio runtime and blocks on it, so nothing
//! above the seam is asynchronous.
//!
//! What replaces the local guarantees (`formats/shards.md`, "Maps on object storage"):
//! - **Commit**: `manifest.dmf` is written with `If-Match` on the e-tag the writer read
//!   (`If-None-Match: *` for the first), so of two writers that read the same manifest only one
//!   commits; the other gets [`Error::CommitConflict`] and nothing of it is named by a manifest.
//! - **Chunk files** are created only if absent: a committed file is never replaced.
//! - **Writer lease** instead of `flock`: the object `lock` names its holder and an expiry; it is
//!   taken create-only (or by compare-and-swap over an expired or released one), renewed by a
//!   background thread every third of its duration, and released by emptying it. A writer whose
//!   lease was taken over (it was paused past the expiry) finds out at its next renewal or commit;
//!   a new writer commits once before deleting anything (fencing), so a late commit of the old
//!   one fails.
//! - **Readers** take no lock: superseded files are listed in a record under `gc/` and deleted
//!   by a later writer once the retention period has passed (`DENSER_S3_RETENTION_S`, default
//!   3600 s), so a reader sees its manifest's files for at least that long.

use super::files::{
    Conditional, Listed, MapFiles, ObjectBytes, ObjectVersion, ReaderHold, WriterHold,
};
use super::layout::{GC_FOLDER, LEASE_OBJECT};
use super::location::MapLocation;
use super::lock::{host_name, LockHolder};
use crate::error::{Error, Result};
use object_store::aws::{AmazonS3, AmazonS3Builder};
use object_store::path::Path as ObjPath;
use object_store::{ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload, UpdateVersion};
use std::ops::Range;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

fn now_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(default)
}

struct Inner {
    store: AmazonS3,
    rt: tokio::runtime::Runtime,
    bucket: String,
    prefix: String,
}

impl Inner {
    fn key(&self, name: &str) -> ObjPath {
        if self.prefix.is_empty() {
            ObjPath::from(name)
        } else {
            ObjPath::from(format!("{}/{name}", self.prefix))
        }
    }

    fn url(&self, name: &str) -> PathBuf {
        let base = if self.prefix.is_empty() {
            format!("s3://{}", self.bucket)
        } else {
            format!("s3://{}/{}", self.bucket, self.prefix)
        };
        if name.is_empty() {
            PathBuf::from(base)
        } else {
            PathBuf::from(format!("{base}/{name}"))
        }
    }

    fn err(&self, name: &str, e: object_store::Error) -> Error {
        Error::Storage {
            path: self.url(name),
            message: e.to_string(),
        }
    }

    fn put(&self, name: &str, bytes: &[u8], mode: PutMode) -> Result<Conditional> {
        let key = self.key(name);
        let opts = PutOptions {
            mode,
            ..Default::default()
        };
        let payload = PutPayload::from(bytes.to_vec());
        match self.rt.block_on(self.store.put_opts(&key, payload, opts)) {
            Ok(r) => Ok(Conditional::Written(ObjectVersion {
                e_tag: r.e_tag,
                version: r.version,
            })),
            Err(object_store::Error::AlreadyExists { .. })
            | Err(object_store::Error::Precondition { .. }) => Ok(Conditional::Conflict),
            Err(e) => Err(self.err(name, e)),
        }
    }

    fn get(&self, name: &str) -> Result<Option<(Vec<u8>, ObjectVersion)>> {
        let key = self.key(name);
        let r = self.rt.block_on(async {
            let g = self.store.get(&key).await?;
            let meta = g.meta.clone();
            let bytes = g.bytes().await?;
            Ok::<_, object_store::Error>((bytes, meta))
        });
        match r {
            Ok((b, meta)) => Ok(Some((
                b.to_vec(),
                ObjectVersion {
                    e_tag: meta.e_tag,
                    version: meta.version,
                },
            ))),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.err(name, e)),
        }
    }

    fn list(&self, folder: &str, recursive: bool) -> Result<Vec<Listed>> {
        use futures_util::TryStreamExt;
        let key = self.key(folder);
        let base = format!("{}/", key.as_ref());
        let metas = if recursive {
            self.rt
                .block_on(self.store.list(Some(&key)).try_collect::<Vec<_>>())
        } else {
            self.rt
                .block_on(self.store.list_with_delimiter(Some(&key)))
                .map(|r| r.objects)
        }
        .map_err(|e| self.err(folder, e))?;
        let mut out: Vec<Listed> = metas
            .into_iter()
            .filter_map(|m| {
                let full = m.location.as_ref().to_string();
                let name = full.strip_prefix(&base)?.to_string();
                Some(Listed {
                    name,
                    size: m.size,
                    modified_unix_s: m.last_modified.timestamp().max(0) as u64,
                })
            })
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }
}

/// A map under `s3://bucket/prefix` (see the module documentation).
pub struct S3Files {
    inner: Arc<Inner>,
    location: MapLocation,
    lease_s: u64,
    retention_s: u64,
    renew: bool,
}

impl std::fmt::Debug for S3Files {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "S3Files({})", self.location)
    }
}

impl S3Files {
    /// The map at `s3://bucket/prefix`, configured from the `AWS_*` environment; the lease lasts
    /// `DENSER_S3_LEASE_S` (default 300 s) and superseded files are kept `DENSER_S3_RETENTION_S`
    /// (default 3600 s) for readers.
    pub fn from_env(bucket: &str, prefix: &str) -> Result<Self> {
        Self::with_options(bucket, prefix, std::iter::empty::<(&str, &str)>())
    }

    /// [`S3Files::from_env`] with `object_store` configuration keys set over the environment's
    /// (`("aws_endpoint", "http://127.0.0.1:9000")`, `("aws_allow_http", "true")`, …) and
    /// denser's own: `denser_lease_s`, `denser_retention_s`, and `denser_lease_renew` (`false`
    /// leaves the lease to expire: a writer paused past its lease, for tests).
    pub fn with_options<'a>(
        bucket: &str,
        prefix: &str,
        options: impl IntoIterator<Item = (&'a str, &'a str)>,
    ) -> Result<Self> {
        let location = MapLocation::S3 {
            bucket: bucket.to_string(),
            prefix: prefix.trim_matches('/').to_string(),
        };
        let mut builder = AmazonS3Builder::from_env();
        let mut lease_s = env_u64("DENSER_S3_LEASE_S", 300);
        let mut retention_s = env_u64("DENSER_S3_RETENTION_S", 3600);
        let mut renew = true;
        for (k, v) in options {
            let num = || {
                v.parse::<u64>()
                    .map_err(|_| Error::InvalidArgument(format!("{k}={v:?}")))
            };
            match k {
                "denser_lease_s" => {
                    lease_s = num()?;
                    continue;
                }
                "denser_retention_s" => {
                    retention_s = num()?;
                    continue;
                }
                "denser_lease_renew" => {
                    renew = v != "false";
                    continue;
                }
                _ => {}
            }
            let key = k.parse().map_err(|e| Error::Storage {
                path: location.display_path(),
                message: format!("configuration key {k:?}: {e}"),
            })?;
            builder = builder.with_config(key, v);
        }
        let store = builder
            .with_bucket_name(bucket)
            .build()
            .map_err(|e| Error::Storage {
                path: location.display_path(),
                message: format!("cannot configure the S3 client from the AWS_* environment: {e}"),
            })?;
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("denser-s3")
            .enable_all()
            .build()
            .map_err(|e| Error::io(location.display_path(), e))?;
        Ok(S3Files {
            inner: Arc::new(Inner {
                store,
                rt,
                bucket: bucket.to_string(),
                prefix: prefix.trim_matches('/').to_string(),
            }),
            location,
            lease_s: lease_s.max(1),
            retention_s,
            renew,
        })
    }

    /// Deletes the files of every deletion record whose retention has passed, then the record.
    fn collect_garbage(&self) -> Result<()> {
        let now = now_s();
        for rec in self.inner.list(GC_FOLDER, false)? {
            let due: u64 = rec
                .name
                .split('-')
                .next()
                .and_then(|s| s.parse().ok())
                .unwrap_or(u64::MAX);
            if due > now {
                continue;
            }
            let name = format!("{GC_FOLDER}/{}", rec.name);
            if let Some((b, _)) = self.inner.get(&name)? {
                for line in String::from_utf8_lossy(&b).lines().skip(1) {
                    if !line.is_empty() {
                        self.delete(line)?;
                    }
                }
            }
            self.delete(&name)?;
        }
        Ok(())
    }
}

/// The lease's record: who, until when, and the token that tells this holder from others.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
struct LeaseRecord {
    holder: LockHolder,
    token: u64,
    expires_unix_s: u64,
}

impl LeaseRecord {
    fn encode(&self) -> String {
        format!(
            "{}token={:016x}\nexpires_unix_s={}\n",
            self.holder.encode(),
            self.token,
            self.expires_unix_s
        )
    }

    fn parse(s: &str) -> Option<Self> {
        let holder = LockHolder::parse(s)?;
        let mut r = LeaseRecord {
            holder,
            ..Default::default()
        };
        for line in s.lines() {
            match line.split_once('=') {
                Some(("token", v)) => r.token = u64::from_str_radix(v, 16).unwrap_or(0),
                Some(("expires_unix_s", v)) => r.expires_unix_s = v.parse().unwrap_or(0),
                _ => {}
            }
        }
        Some(r)
    }

    fn describe(&self) -> String {
        let left = self.expires_unix_s as i64 - now_s() as i64;
        format!("{}; lease expires in {left} s", self.holder.describe())
    }
}

/// The writer lease (see the module documentation), renewed until dropped.
struct Lease {
    inner: Arc<Inner>,
    version: Arc<Mutex<Option<ObjectVersion>>>,
    lost: Arc<Mutex<Option<String>>>,
    stop: Option<std::sync::mpsc::Sender<()>>,
    renewer: Option<std::thread::JoinHandle<()>>,
    stale: Option<String>,
    record: LeaseRecord,
}

impl std::fmt::Debug for Lease {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Lease({:016x})", self.record.token)
    }
}

impl WriterHold for Lease {
    fn stale_holder(&self) -> Option<String> {
        self.stale.clone()
    }

    fn check(&self) -> Result<()> {
        match self.lost.lock().map(|l| l.clone()) {
            Ok(Some(why)) => Err(Error::MapLocked {
                dir: self.inner.url(""),
                holder: format!("this writer lost its lease: {why}"),
            }),
            _ => Ok(()),
        }
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(h) = self.renewer.take() {
            let _ = h.join();
        }
        // Release by emptying the record, only if it is still ours.
        let v = self.version.lock().ok().and_then(|v| v.clone());
        if let Some(v) = v {
            let _ = self
                .inner
                .put(LEASE_OBJECT, b"", PutMode::Update(update(&v)));
        }
    }
}

fn update(v: &ObjectVersion) -> UpdateVersion {
    UpdateVersion {
        e_tag: v.e_tag.clone(),
        version: v.version.clone(),
    }
}

#[derive(Debug)]
struct NoReaderHold;

impl ReaderHold for NoReaderHold {}

impl MapFiles for S3Files {
    fn location(&self) -> &MapLocation {
        &self.location
    }

    fn path(&self, name: &str) -> PathBuf {
        self.inner.url(name)
    }

    fn exists(&self, name: &str) -> Result<bool> {
        let key = self.inner.key(name);
        match self.inner.rt.block_on(self.inner.store.head(&key)) {
            Ok(_) => Ok(true),
            Err(object_store::Error::NotFound { .. }) => Ok(false),
            Err(e) => Err(self.inner.err(name, e)),
        }
    }

    fn read(&self, name: &str) -> Result<Option<ObjectBytes>> {
        Ok(self
            .inner
            .get(name)?
            .map(|(b, _)| ObjectBytes::Owned(Arc::new(b))))
    }

    fn read_versioned(&self, name: &str) -> Result<Option<(Vec<u8>, ObjectVersion)>> {
        self.inner.get(name)
    }

    fn read_range(&self, name: &str, range: Range<u64>) -> Result<Vec<u8>> {
        let key = self.inner.key(name);
        let inner = &self.inner;
        // A range past the end is clamped to the object (S3 answers 416 for a start past it).
        let r = inner.rt.block_on(async {
            let meta = inner.store.head(&key).await?;
            let end = range.end.min(meta.size);
            if range.start >= end {
                return Ok(bytes::Bytes::new());
            }
            inner.store.get_range(&key, range.start..end).await
        });
        r.map(|b| b.to_vec()).map_err(|e| self.inner.err(name, e))
    }

    fn write(&self, name: &str, bytes: &[u8]) -> Result<()> {
        self.inner.put(name, bytes, PutMode::Overwrite).map(|_| ())
    }

    fn write_if(
        &self,
        name: &str,
        bytes: &[u8],
        prev: Option<&ObjectVersion>,
    ) -> Result<Conditional> {
        let mode = match prev {
            None => PutMode::Create,
            Some(v) => PutMode::Update(update(v)),
        };
        self.inner.put(name, bytes, mode)
    }

    fn write_chunk(&self, name: &str, bytes: &[u8]) -> Result<()> {
        match self.inner.put(name, bytes, PutMode::Create)? {
            Conditional::Written(_) => Ok(()),
            Conditional::Conflict => Err(Error::bad_input(
                self.path(name),
                "exists already: a chunk file name is used once, and another writer has used this one (a writer whose lease expired?); nothing was replaced",
            )),
        }
    }

    fn write_new(&self, name: &str, bytes: &[u8]) -> Result<bool> {
        Ok(matches!(
            self.inner.put(name, bytes, PutMode::Create)?,
            Conditional::Written(_)
        ))
    }

    fn list(&self, folder: &str) -> Result<Vec<Listed>> {
        self.inner.list(folder, false)
    }

    fn list_recursive(&self, folder: &str) -> Result<Vec<Listed>> {
        self.inner.list(folder, true)
    }

    fn delete(&self, name: &str) -> Result<()> {
        let key = self.inner.key(name);
        match self.inner.rt.block_on(self.inner.store.delete(&key)) {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(self.inner.err(name, e)),
        }
    }

    fn lock_writer(&self) -> Result<Box<dyn WriterHold>> {
        let record = LeaseRecord {
            holder: LockHolder::current(),
            token: super::manifest::new_map_id(),
            expires_unix_s: now_s() + self.lease_s,
        };
        let bytes = record.encode();
        let mut stale = None;
        let version = match self
            .inner
            .put(LEASE_OBJECT, bytes.as_bytes(), PutMode::Create)?
        {
            Conditional::Written(v) => v,
            Conditional::Conflict => {
                let Some((b, v)) = self.inner.get(LEASE_OBJECT)? else {
                    // Released and deleted between our two requests: try once more.
                    return self.lock_writer();
                };
                let text = String::from_utf8_lossy(&b).into_owned();
                let held = LeaseRecord::parse(&text);
                if let Some(h) = held.as_ref().filter(|h| h.expires_unix_s > now_s()) {
                    return Err(Error::MapLocked {
                        dir: self.inner.url(""),
                        holder: h.describe(),
                    });
                }
                // Released (empty) or expired: take it over by compare-and-swap.
                stale = held.map(|h| {
                    format!(
                        "{} (lease expired {} s ago)",
                        h.holder.describe(),
                        now_s().saturating_sub(h.expires_unix_s)
                    )
                });
                match self
                    .inner
                    .put(LEASE_OBJECT, bytes.as_bytes(), PutMode::Update(update(&v)))?
                {
                    Conditional::Written(v) => v,
                    Conditional::Conflict => {
                        return Err(Error::MapLocked {
                            dir: self.inner.url(""),
                            holder: "another writer that took the lease at this very moment".into(),
                        })
                    }
                }
            }
        };
        let version = Arc::new(Mutex::new(Some(version)));
        let lost = Arc::new(Mutex::new(None));
        let (stop_tx, stop_rx) = std::sync::mpsc::channel::<()>();
        let renewer = {
            let inner = self.inner.clone();
            let version = version.clone();
            let lost = lost.clone();
            let lease_s = self.lease_s;
            let renew = self.renew;
            let mut record = record.clone();
            std::thread::Builder::new()
                .name("denser-lease".into())
                .spawn(move || loop {
                    let period = std::time::Duration::from_secs((lease_s / 3).max(1));
                    match stop_rx.recv_timeout(period) {
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) if renew => {}
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => continue,
                        _ => return,
                    }
                    record.expires_unix_s = now_s() + lease_s;
                    let Some(v) = version.lock().ok().and_then(|v| v.clone()) else {
                        return;
                    };
                    match inner.put(
                        LEASE_OBJECT,
                        record.encode().as_bytes(),
                        PutMode::Update(update(&v)),
                    ) {
                        Ok(Conditional::Written(nv)) => {
                            if let Ok(mut g) = version.lock() {
                                *g = Some(nv);
                            }
                        }
                        Ok(Conditional::Conflict) => {
                            if let Ok(mut g) = lost.lock() {
                                *g = Some("it expired and another writer took it over".into());
                            }
                            if let Ok(mut g) = version.lock() {
                                *g = None;
                            }
                            return;
                        }
                        Err(e) => tracing::warn!("renewing the map's lease: {e}"),
                    }
                })
                .map_err(|e| Error::io(self.inner.url(LEASE_OBJECT), e))?
        };
        Ok(Box::new(Lease {
            inner: self.inner.clone(),
            version,
            lost,
            stop: Some(stop_tx),
            renewer: Some(renewer),
            stale,
            record,
        }))
    }

    fn writer_holding(&self) -> Option<String> {
        let (b, _) = self.inner.get(LEASE_OBJECT).ok()??;
        let r = LeaseRecord::parse(&String::from_utf8_lossy(&b))?;
        (r.expires_unix_s > now_s()).then(|| r.describe())
    }

    fn hold_readers(&self) -> Box<dyn ReaderHold> {
        Box::new(NoReaderHold)
    }

    fn retire(&self, names: &[String], generation: u64, map_id: u64) -> Result<bool> {
        if !names.is_empty() {
            let due = now_s() + self.retention_s;
            let mut text = format!(
                "denser-gc 1 map {map_id:016x} generation {generation} host {}\n",
                host_name()
            );
            for n in names {
                text.push_str(n);
                text.push('\n');
            }
            let name = format!(
                "{GC_FOLDER}/{due:012}-{generation:020}-{:016x}.txt",
                super::manifest::new_map_id()
            );
            self.write(&name, text.as_bytes())?;
        }
        self.collect_garbage()?;
        Ok(true)
    }

    fn deletes_after_s(&self) -> Option<u64> {
        Some(self.retention_s)
    }

    fn needs_fencing(&self) -> bool {
        true
    }
}
