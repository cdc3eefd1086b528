//! WGSL sources. They live in the workspace's `shaders/` folder; ray-cast shaders
//! are prefixed with `common.wgsl` at load time. Every composed source is validated
//! by naga in this module's tests, so a WGSL error fails `cargo test` without a GPU.

/// Functions shared by the ray casters.
pub const COMMON: &str = include_str!("../../../shaders/common.wgsl");
/// The in-core ray-cast compute shader body.
pub const RAYCAST_INCORE: &str = include_str!("../../../shaders/raycast_incore.wgsl");
/// The out-of-core ray-cast compute shader body.
pub const RAYCAST_OOC: &str = include_str!("../../../shaders/raycast_ooc.wgsl");
/// The octree-with-ropes traversal library (`brickray-index`'s GPU twin).
pub const OCTREE_TRAVERSAL: &str = include_str!("../../../shaders/octree_traversal.wgsl");
/// The composite (fullscreen) shader.
pub const COMPOSITE: &str = include_str!("../../../shaders/composite.wgsl");

/// The in-core ray caster as compiled: `common.wgsl` followed by its body.
pub fn raycast_incore() -> String {
    format!("{COMMON}\n{RAYCAST_INCORE}")
}

/// The out-of-core ray caster as compiled: `common.wgsl`, the traversal library,
/// then its body.
pub fn raycast_ooc() -> String {
    format!("{COMMON}\n{OCTREE_TRAVERSAL}\n{RAYCAST_OOC}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn validate(name: &str, src: &str) {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{name}: parse error:\n{}", e.emit_to_string(src)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: validation error:\n{}", e.emit_to_string(src)));
    }

    #[test]
    fn raycast_incore_validates() {
        validate("raycast_incore", &raycast_incore());
    }

    #[test]
    fn raycast_ooc_validates() {
        validate("raycast_ooc", &raycast_ooc());
    }

    #[test]
    fn composite_validates() {
        validate("composite", COMPOSITE);
    }

    #[test]
    fn host_quad_validates() {
        validate("host_quad", include_str!("../../../shaders/host_quad.wgsl"));
    }

    /// Every `.wgsl` file in shaders/ is either validated above or a library that
    /// is validated as part of a composed shader; a new file must be added here.
    #[test]
    fn every_shader_file_is_covered() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let known = [
            "common.wgsl",
            "raycast_incore.wgsl",
            "composite.wgsl",
            "octree_traversal.wgsl",
            "host_quad.wgsl",
            "raycast_ooc.wgsl",
        ];
        for entry in std::fs::read_dir(dir).unwrap() {
            let name = entry.unwrap().file_name().into_string().unwrap();
            if name.ends_with(".wgsl") {
                assert!(
                    known.contains(&name.as_str()),
                    "{name} is not validated by any test"
                );
            }
        }
    }
}
