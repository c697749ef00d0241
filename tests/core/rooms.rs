//! The rooms of the out-of-core code and the rule between them (issue 39; ARCHITECTURE.md, "Three
//! rooms"): the storage engine (`src/map`), the out-of-core solvers (`src/outofcore`) and the
//! exports (`src/export`), in that order above the pipeline's own modules (the reconstruction
//! driver included: it sees a map only as a `BlockStore`), with the command line on top.
//!
//! 1. No module imports from a room above its own (every `crate::…` and `super::…` path in the
//!    library's code, comments and strings left out).
//! 2. No two modules of one room import each other, directly or round a circle (a module and its
//!    own submodules excepted: a parent re-exports its children, a child uses its parent).
//!
//! The checker reads the source files; it is tested on small planted trees so that it is known to
//! fail where it should.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A layer of the crate, lowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Room {
    /// The pipeline's own modules (grid, fusion, regularize, mesh, io, store, reconstruct, …):
    /// below every room.
    Base,
    /// `src/map`: chunk files, manifest, commits, locks, repair.
    Engine,
    /// `src/outofcore`: pager, paged store, regional and swept regularization, shards, merge.
    Solvers,
    /// `src/export`: stitched meshes and point clouds, export parts, 3D Tiles.
    Exports,
    /// The command line: may import anything.
    Top,
}

/// The room of each module that is in one, by path prefix (others are [`Room::Base`]).
const ROOMS: [(&str, Room); 5] = [
    ("map", Room::Engine),
    ("outofcore", Room::Solvers),
    ("export", Room::Exports),
    ("cli", Room::Top),
    ("main", Room::Top),
];

/// The room of a module: the table's longest entry (`a` or `a::b`) that is a prefix of its path.
fn room_of(module: &[String], rooms: &[(&str, Room)]) -> Room {
    rooms
        .iter()
        .filter(|(prefix, _)| {
            let p: Vec<&str> = prefix.split("::").collect();
            p.len() <= module.len() && p.iter().zip(module).all(|(a, b)| a == b)
        })
        .max_by_key(|(prefix, _)| prefix.len())
        .map_or(Room::Base, |(_, r)| *r)
}

/// The module path of a source file (`src/map/store/mod.rs` → `map::store`).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).expect("file under src");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().expect("a file name");
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" {
        parts.push(stem.to_string());
    }
    parts
}

/// The code of a file without comments, string and character literals (so that a path in a doc
/// comment or a message is not an import).
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'"' {
            // A raw string (`r"…"`, `r#"…"#`) has no escapes; the prefix was copied already.
            let raw = out.ends_with('r') || out.ends_with('#');
            let hashes = out.chars().rev().take_while(|c| *c == '#').count();
            i += 1;
            while i < b.len() {
                if !raw && b[i] == b'\\' {
                    i += 2;
                    continue;
                }
                if b[i] == b'"' && b[i + 1..].iter().take(hashes).all(|c| *c == b'#') {
                    i += 1 + hashes;
                    break;
                }
                i += 1;
            }
            out.push_str("\"\"");
        } else if b[i] == b'\'' && i + 2 < b.len() && (b[i + 2] == b'\'' || b[i + 1] == b'\\') {
            // A character literal ('x' or an escape); lifetimes ('a) pass through.
            i += if b[i + 1] == b'\\' { 1 } else { 0 } + 3;
            while i < b.len() && b[i - 1] != b'\'' {
                i += 1;
            }
            out.push_str("' '");
        } else {
            let c = text[i..].chars().next().expect("a char");
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

fn ident_at(s: &str) -> Option<&str> {
    let end = s
        .find(|c: char| !(c.is_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    (end > 0).then(|| &s[..end])
}

/// The paths `rest` names after a `crate::` or resolved `super::` prefix: one path, or one per
/// item of a `{…}` group (first level only: enough to find the module).
fn named_paths(rest: &str) -> Vec<Vec<String>> {
    let rest = rest.trim_start();
    if let Some(group) = rest.strip_prefix('{') {
        let mut items = Vec::new();
        let (mut depth, mut start) = (0, 0);
        for (k, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => {
                    items.push(&group[start..k]);
                    break;
                }
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    items.push(&group[start..k]);
                    start = k + 1;
                }
                _ => {}
            }
        }
        return items
            .into_iter()
            .flat_map(|item| {
                let item = item.trim();
                if item.starts_with("self") && ident_at(item) == Some("self") {
                    vec![Vec::new()]
                } else {
                    named_paths(item)
                }
            })
            .collect();
    }
    let mut path = Vec::new();
    let mut s = rest;
    while let Some(id) = ident_at(s) {
        path.push(id.to_string());
        s = &s[id.len()..];
        match s.strip_prefix("::") {
            Some(t) if !t.starts_with('{') => s = t,
            Some(t) => {
                return named_paths(t)
                    .into_iter()
                    .map(|tail| path.iter().cloned().chain(tail).collect())
                    .collect()
            }
            None => break,
        }
    }
    vec![path]
}

/// Every crate path `code` of module `module` names (`crate::a::b`, `super::c` resolved).
fn imports(module: &[String], code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let starts_ident = |k: usize| {
        k == 0 || {
            let c = code[..k].chars().next_back().expect("a char");
            !(c.is_alphanumeric() || c == '_' || c == ':')
        }
    };
    for (k, _) in code.match_indices("crate::") {
        if starts_ident(k) {
            out.extend(named_paths(&code[k + "crate::".len()..]));
        }
    }
    for (k, _) in code.match_indices("super::") {
        if !starts_ident(k) {
            continue; // the second `super::` of a chain: counted from the first
        }
        // `super` is the parent of the file's module (for `mod.rs`, of the folder's module).
        let mut base: Vec<String> = module.to_vec();
        let mut s = &code[k..];
        while let Some(t) = s.strip_prefix("super::") {
            base.pop();
            s = t;
        }
        out.extend(named_paths(s).into_iter().map(|tail| {
            let mut p = base.clone();
            p.extend(tail);
            p
        }));
    }
    out
}

/// The library's source files under `src` (the binary's `main.rs` and `cli/` are on top and
/// may import anything: they are not read).
fn source_files(src: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .expect("read_dir")
            .map(|e| e.expect("entry").path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    let mut out = Vec::new();
    walk(src, &mut out);
    out
}

/// What the checker found: upward imports ("file: imports path (room → room)") and circles of
/// modules within one room ("a → b → a").
#[derive(Debug, Default)]
struct Findings {
    upward: Vec<String>,
    circles: Vec<String>,
}

fn check_tree(src: &Path, rooms: &[(&str, Room)]) -> Findings {
    let files = source_files(src);
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(src, f)).collect();
    let mut found = Findings::default();
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for f in &files {
        let module = module_of(src, f);
        let room = room_of(&module, rooms);
        if room == Room::Top {
            continue;
        }
        let text = std::fs::read_to_string(f).expect("read source");
        for path in imports(&module, &code_only(&text)) {
            let target_room = room_of(&path, rooms);
            if target_room > room {
                found.upward.push(format!(
                    "{}: imports {} ({room:?} → {target_room:?})",
                    f.strip_prefix(src).expect("under src").display(),
                    path.join("::")
                ));
            }
            // The module the path lands in: its longest prefix that is a module of the tree.
            let Some(target) = (0..=path.len())
                .rev()
                .map(|n| path[..n].to_vec())
                .find(|p| modules.contains(p))
            else {
                continue;
            };
            let related = target.starts_with(&module) || module.starts_with(&target);
            if !related && room != Room::Base && target_room == room {
                edges.entry(module.clone()).or_default().insert(target);
            }
        }
    }
    found.upward.sort();
    found.upward.dedup();
    found.circles = circles(&edges);
    found
}

/// The strongly connected components of more than one module (Tarjan), each as `a → b → …`.
fn circles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<String> {
    struct State<'a> {
        edges: &'a BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        index: BTreeMap<&'a Vec<String>, (usize, usize)>,
        stack: Vec<&'a Vec<String>>,
        on_stack: BTreeSet<&'a Vec<String>>,
        next: usize,
        out: Vec<String>,
    }
    fn visit<'a>(st: &mut State<'a>, v: &'a Vec<String>) {
        st.index.insert(v, (st.next, st.next));
        st.next += 1;
        st.stack.push(v);
        st.on_stack.insert(v);
        if let Some(ws) = st.edges.get(v) {
            for w in ws {
                if !st.index.contains_key(w) {
                    visit(st, w);
                    let low_w = st.index[w].1;
                    let e = st.index.get_mut(v).expect("visited");
                    e.1 = e.1.min(low_w);
                } else if st.on_stack.contains(w) {
                    let idx_w = st.index[w].0;
                    let e = st.index.get_mut(v).expect("visited");
                    e.1 = e.1.min(idx_w);
                }
            }
        }
        if st.index[v].0 == st.index[v].1 {
            let mut comp = Vec::new();
            while let Some(w) = st.stack.pop() {
                st.on_stack.remove(w);
                comp.push(w.join("::"));
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                st.out.push(comp.join(" ↔ "));
            }
        }
    }
    let mut st = State {
        edges,
        index: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !st.index.contains_key(v) {
            visit(&mut st, v);
        }
    }
    st.out.sort();
    st.out
}

#[test]
fn rooms_import_only_downwards_and_without_circles() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let found = check_tree(&src, &ROOMS);
    assert!(
        found.upward.is_empty(),
        "imports from a room above (engine → solvers → exports → cli):\n{}",
        found.upward.join("\n")
    );
    assert!(
        found.circles.is_empty(),
        "modules of one room that import each other:\n{}",
        found.circles.join("\n")
    );
    // The rooms exist where the table says (a renamed folder would make the check vacuous).
    for (name, room) in ROOMS.iter().filter(|(_, r)| *r != Room::Top) {
        assert!(
            src.join(name).join("mod.rs").is_file(),
            "room {room:?} expects src/{name}/mod.rs"
        );
    }
}

/// Writes `files` (path under src, text) into a fresh tree and checks it.
fn check_planted(files: &[(&str, &str)]) -> Findings {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    for (path, text) in files {
        let p = src.join(path);
        std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
        std::fs::write(&p, text).expect("write");
    }
    check_tree(&src, &ROOMS)
}

#[test]
fn the_checker_finds_the_tangles_of_the_old_tiles_folder() {
    // The shapes issue 39 found in src/tiles, planted in the new rooms' names: the engine's
    // clean-up reading a solver's records, the paged store importing the exporter, and circles
    // (files ↔ s3, regional ↔ sweeps, export ↔ parts).
    let found = check_planted(&[
        ("lib.rs", "pub mod map; pub mod outofcore; pub mod export; pub mod grid;"),
        ("grid/mod.rs", "pub struct Block;"),
        (
            "map/mod.rs",
            "pub mod files; pub mod s3; pub mod store;\nuse crate::grid::Block;",
        ),
        ("map/files.rs", "use super::s3::S3Files; // crate::export::x in a comment\nconst S: &str = \"crate::export::y\";"),
        ("map/s3.rs", "use super::files::{MapFiles, ObjectBytes};"),
        (
            "map/store/mod.rs",
            "mod cleanup;\nfn f() { let r = crate::outofcore::shards::reserved_ranges(); }",
        ),
        ("map/store/cleanup.rs", "use super::*;\nuse super::super::files::MapFiles;"),
        (
            "outofcore/mod.rs",
            "pub mod paged; pub mod regional; pub mod sweeps; pub mod shards;",
        ),
        (
            "outofcore/paged.rs",
            "use crate::{map::store::MapStore, export::{export, ExportTarget}};",
        ),
        ("outofcore/regional.rs", "use super::sweeps::SweptPass;"),
        ("outofcore/sweeps.rs", "use super::regional::{region_of, MapRegularizeStats};"),
        ("outofcore/shards.rs", "use crate::map::store::MapStore;"),
        ("export/mod.rs", "pub mod parts;\nuse self::parts::chunk_mesh;"),
        ("export/parts.rs", "use super::mesh_chunk; use crate::outofcore::shards::Shard;"),
    ]);
    assert_eq!(
        found.upward,
        vec![
            "map/store/mod.rs: imports outofcore::shards::reserved_ranges (Engine → Solvers)",
            "outofcore/paged.rs: imports export::ExportTarget (Solvers → Exports)",
            "outofcore/paged.rs: imports export::export (Solvers → Exports)",
        ]
    );
    assert_eq!(
        found.circles,
        vec![
            "map::files ↔ map::s3",
            "outofcore::regional ↔ outofcore::sweeps"
        ],
        "export ↔ export::parts is a parent and its child, not a circle"
    );
}

#[test]
fn the_checker_passes_a_tree_that_keeps_the_rule() {
    let found = check_planted(&[
        (
            "lib.rs",
            "pub mod map; pub mod outofcore; pub mod export; pub mod grid;",
        ),
        ("grid/mod.rs", "pub struct Block;"),
        (
            "map/mod.rs",
            "pub mod files; pub mod s3;\nuse crate::grid::Block;",
        ),
        ("map/files.rs", "use crate::grid::Block;"),
        ("map/s3.rs", "use super::files::MapFiles;"),
        (
            "outofcore/mod.rs",
            "pub mod plan; pub mod regional; pub mod sweeps;",
        ),
        ("outofcore/plan.rs", "use crate::map::files::MapFiles;"),
        (
            "outofcore/regional.rs",
            "use super::{plan::region_of, sweeps::run};",
        ),
        ("outofcore/sweeps.rs", "use super::plan::region_of;"),
        (
            "export/mod.rs",
            "use crate::{map::s3::S3Files, outofcore::sweeps};\nfn f<'a>(c: char) -> char { 'x' }",
        ),
        ("cli/mod.rs", "use denser::export; use crate::cli::x;"),
    ]);
    assert!(found.upward.is_empty(), "{:?}", found.upward);
    assert!(found.circles.is_empty(), "{:?}", found.circles);
}
