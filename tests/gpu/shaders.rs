//! Every WGSL kernel parses and validates with naga (no GPU needed), every `.wgsl` file under
//! `shaders/` is part of some kernel, and what naga reflects from each kernel (its bindings,
//! the sizes of the structs it binds) equals what the host declares (`ShaderSource::bindings`,
//! the `#[repr(C)]` twins in `src/gpu/layout.rs`), so a broken, orphaned or out-of-sync shader
//! fails CI on any machine.

use denser::gpu::layout::WGSL_STRUCTS;
use denser::gpu::shaders::{self, Binding, ShaderSource};
use std::collections::BTreeSet;
use std::path::Path;

/// Every kernel: those of `shaders::ALL` and those that need f64.
fn every_kernel() -> impl Iterator<Item = &'static ShaderSource> {
    shaders::ALL.iter().chain(shaders::WITH_F64)
}

fn validate(src: &ShaderSource) -> naga::valid::ModuleInfo {
    let module = naga::front::wgsl::parse_str(src.source)
        .unwrap_or_else(|e| panic!("{}: {}", src.file, e.emit_to_string(src.source)));
    // f64 only where the kernel is listed as needing it.
    let f64_kernel = shaders::WITH_F64.iter().any(|k| k.file == src.file);
    let capabilities = if f64_kernel {
        naga::valid::Capabilities::FLOAT64
    } else {
        naga::valid::Capabilities::empty()
    };
    let mut validator =
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities);
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
    for src in every_kernel() {
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
    for src in every_kernel() {
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

/// The size naga computes for the struct type `ty` (or for the element of an array of structs),
/// with its WGSL name; `None` for other types.
fn bound_struct(module: &naga::Module, ty: naga::Handle<naga::Type>) -> Option<(String, u32)> {
    let t = &module.types[ty];
    match &t.inner {
        naga::TypeInner::Struct { span, .. } => Some((t.name.clone().unwrap_or_default(), *span)),
        naga::TypeInner::Array { base, stride, .. } => {
            let (name, span) = bound_struct(module, *base)?;
            assert_eq!(
                span, *stride,
                "array<{name}> has stride {stride} but {name} is {span} bytes"
            );
            Some((name, span))
        }
        _ => None,
    }
}

#[test]
fn bindings_and_struct_sizes_match_the_host() {
    let mut structs_seen = BTreeSet::new();
    for src in every_kernel() {
        let module = naga::front::wgsl::parse_str(src.source)
            .unwrap_or_else(|e| panic!("{}: {}", src.file, e.emit_to_string(src.source)));
        let mut reflected: Vec<(u32, Binding)> = Vec::new();
        for (_, var) in module.global_variables.iter() {
            let Some(rb) = &var.binding else { continue };
            assert_eq!(
                rb.group, 0,
                "{}: {:?} is not in group 0",
                src.file, var.name
            );
            let kind = match var.space {
                naga::AddressSpace::Uniform => Binding::Uniform,
                naga::AddressSpace::Storage { access }
                    if access.contains(naga::StorageAccess::STORE) =>
                {
                    Binding::ReadWrite
                }
                naga::AddressSpace::Storage { .. } => Binding::Read,
                other => panic!("{}: {:?} is bound in {other:?}", src.file, var.name),
            };
            reflected.push((rb.binding, kind));
            if let Some((name, span)) = bound_struct(&module, var.ty) {
                let rust = WGSL_STRUCTS
                    .iter()
                    .find(|(n, _)| *n == name)
                    .unwrap_or_else(|| {
                        panic!(
                            "{}: struct {name} is bound but has no Rust twin in WGSL_STRUCTS",
                            src.file
                        )
                    });
                assert_eq!(
                    span as usize, rust.1,
                    "{}: WGSL {name} is {span} bytes, its Rust twin {} bytes",
                    src.file, rust.1
                );
                structs_seen.insert(name);
            }
        }
        reflected.sort_by_key(|(k, _)| *k);
        let declared: Vec<(u32, Binding)> = src
            .bindings
            .iter()
            .enumerate()
            .map(|(k, b)| (k as u32, *b))
            .collect();
        assert_eq!(
            reflected, declared,
            "{}: shader bindings vs ShaderSource::bindings",
            src.file
        );
    }
    // Every listed Rust twin is bound by some kernel (no stale entries).
    let listed: BTreeSet<String> = WGSL_STRUCTS.iter().map(|(n, _)| n.to_string()).collect();
    assert_eq!(listed, structs_seen);
}

#[test]
fn a_binding_out_of_sync_is_caught() {
    // The comparison above can fail: a kernel whose shader reads a buffer the host declares as
    // read-write differs from its declaration.
    let module = naga::front::wgsl::parse_str(shaders::CENSUS.source).expect("parses");
    let spaces: Vec<naga::AddressSpace> = module
        .global_variables
        .iter()
        .filter(|(_, v)| v.binding.is_some())
        .map(|(_, v)| v.space)
        .collect();
    let edited = shaders::CENSUS.source.replace(
        "var<storage, read_write> signatures",
        "var<storage, read> signatures",
    );
    let module2 = naga::front::wgsl::parse_str(&edited).expect("parses");
    let spaces2: Vec<naga::AddressSpace> = module2
        .global_variables
        .iter()
        .filter(|(_, v)| v.binding.is_some())
        .map(|(_, v)| v.space)
        .collect();
    assert_ne!(spaces, spaces2);
    assert_eq!(shaders::CENSUS.bindings.last(), Some(&Binding::ReadWrite));
}
