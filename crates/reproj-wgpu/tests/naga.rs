//! Every composed WGSL module parses and validates with naga (the wgpu release's shader
//! compiler), with exactly the capabilities the host requests, and declares the bindings of the
//! host's explicit bind-group layout.

use naga::valid::{Capabilities, ValidationFlags, Validator};
use reproj_wgpu::reprojector::bind_group_layout_entries;
use reproj_wgpu::shaders::Module;

fn parse(m: Module) -> (String, naga::Module) {
    let src = m.source();
    let module = naga::front::wgsl::parse_str(&src)
        .unwrap_or_else(|e| panic!("{}: {}", m.file().0, e.emit_to_string(&src)));
    (src, module)
}

fn caps(m: Module) -> Capabilities {
    if m.needs_int64() {
        Capabilities::SHADER_INT64 | Capabilities::SHADER_INT64_ATOMIC_MIN_MAX
    } else {
        Capabilities::empty()
    }
}

#[test]
fn every_module_validates() {
    for m in Module::ALL {
        let (src, module) = parse(m);
        Validator::new(ValidationFlags::all(), caps(m))
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}: {}", m.file().0, e.emit_to_string(&src)));
        for ep in m.entry_points() {
            let e = module
                .entry_points
                .iter()
                .find(|e| e.name == *ep)
                .unwrap_or_else(|| panic!("{}: no entry point {ep}", m.file().0));
            assert_eq!(e.stage, naga::ShaderStage::Compute);
            // The host dispatches 16×16 tiles (reproj-core's TILE).
            assert_eq!(e.workgroup_size, [16, 16, 1], "{ep}");
        }
    }
}

/// Only the 64-bit splat needs 64-bit atomics: the fallback runs on any adapter.
#[test]
fn only_splat64_needs_int64_atomics() {
    for m in Module::ALL {
        let (_, module) = parse(m);
        let r = Validator::new(ValidationFlags::all(), Capabilities::empty()).validate(&module);
        assert_eq!(r.is_err(), m.needs_int64(), "{}", m.file().0);
    }
}

/// Every resource a module declares is in the explicit layout with the same address space
/// (wgpu requires an exact match of uniform / storage read / storage read-write).
#[test]
fn bindings_match_the_explicit_layout() {
    let entries = bind_group_layout_entries();
    for m in Module::ALL {
        let (_, module) = parse(m);
        let mut seen = 0;
        for (_, var) in module.global_variables.iter() {
            let Some(b) = &var.binding else { continue };
            assert_eq!(b.group, 0);
            let entry = entries
                .iter()
                .find(|e| e.binding == b.binding)
                .unwrap_or_else(|| {
                    panic!("{}: binding {} not in the layout", m.file().0, b.binding)
                });
            let wgpu::BindingType::Buffer { ty, .. } = entry.ty else {
                panic!("binding {} is not a buffer", b.binding)
            };
            let ok = match (var.space, ty) {
                (naga::AddressSpace::Uniform, wgpu::BufferBindingType::Uniform) => true,
                (
                    naga::AddressSpace::Storage { access },
                    wgpu::BufferBindingType::Storage { read_only },
                ) => access.contains(naga::StorageAccess::STORE) != read_only,
                _ => false,
            };
            assert!(
                ok,
                "{}: binding {} is {:?}, layout {:?}",
                m.file().0,
                b.binding,
                var.space,
                ty
            );
            seen += 1;
        }
        assert!(seen >= 5, "{}: only {seen} bindings", m.file().0);
    }
}
