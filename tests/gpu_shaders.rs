//! Every WGSL kernel parses and validates with naga (no GPU needed), and every `.wgsl` file under
//! `shaders/` is part of some kernel, so a broken or orphaned shader fails CI on any machine.

use denser::gpu::shaders::{self, ShaderSource};
use std::collections::BTreeSet;
use std::path::Path;

fn validate(src: &ShaderSource) -> naga::valid::ModuleInfo {
    let module = naga::front::wgsl::parse_str(src.source)
        .unwrap_or_else(|e| panic!("{}: {}", src.file, e.emit_to_string(src.source)));
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    );
    let info = validator
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}: {}", src.file, e.emit_to_string(src.source)));
    let entries: Vec<&str> = module
        .entry_points
        .iter()
        .map(|e| e.name.as_str())
        .collect();
    assert_eq!(
        entries,
        ["main"],
        "{}: one compute entry point `main`",
        src.file
    );
    assert_eq!(
        module.entry_points[0].workgroup_size,
        [denser::gpu::WORKGROUP_SIZE, 1, 1],
        "{}: workgroup size must equal WORKGROUP_SIZE",
        src.file
    );
    info
}

#[test]
fn every_kernel_validates_with_naga() {
    for src in shaders::ALL {
        validate(src);
    }
}

#[test]
fn every_wgsl_file_is_assembled_into_a_kernel() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut on_disk = BTreeSet::new();
    for dir in [root.clone(), root.join("shared")] {
        for entry in std::fs::read_dir(&dir).expect("read shaders/") {
            let path = entry.expect("dir entry").path();
            if path.extension().is_some_and(|e| e == "wgsl") {
                let rel = path.strip_prefix(&root).expect("under shaders/");
                on_disk.insert(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }
    let mut used = BTreeSet::new();
    for src in shaders::ALL {
        used.insert(src.file.to_string());
        for s in src.shared {
            used.insert(s.to_string());
        }
        // The assembled source really is the files on disk, in order.
        let mut expected = String::new();
        for f in src.shared.iter().chain(std::iter::once(&src.file)) {
            expected += &std::fs::read_to_string(root.join(f)).expect("read shader");
        }
        assert_eq!(expected, src.source, "{} is stale", src.file);
    }
    assert_eq!(
        on_disk, used,
        "every .wgsl under shaders/ must be part of a kernel"
    );
}

#[test]
fn a_broken_shader_is_rejected() {
    // The check above can fail: a type error in an otherwise valid kernel is caught.
    let broken = shaders::TV_DUAL
        .source
        .replace("let scale = 1.0 /", "let scale = 1u /");
    assert_ne!(broken, shaders::TV_DUAL.source);
    let parsed = naga::front::wgsl::parse_str(&broken);
    let rejected = match parsed {
        Err(_) => true,
        Ok(module) => naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::empty(),
        )
        .validate(&module)
        .is_err(),
    };
    assert!(rejected);
}
