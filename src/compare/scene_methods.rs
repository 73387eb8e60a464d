//! The harness's scene-level methods: those that need the scene and the tracer, not only the
//! traced samples, so that `recon::registry` (which must not use the tracer) cannot hold them.
//! Declared as data beside the registry's methods (name, effects, options as
//! `recon::options::OptionSpec`, one line of description), parsed by the same
//! `recon::options` into the same errors, and listed by `--list-methods` in the same form.
//! Today one: `probes` (`probes_method`).

use recon::method::Effect;
use recon::options::OptionSpec;

use super::probes_method;

/// One scene-level method as data.
pub struct SceneMethodSpec {
    /// The `--methods` name.
    pub name: &'static str,
    pub effects: &'static [Effect],
    pub options: &'static [OptionSpec],
    pub description: &'static str,
}

/// Every scene-level method, in the order reports list them.
pub const SCENE_METHODS: &[SceneMethodSpec] = &[SceneMethodSpec {
    name: probes_method::NAME,
    effects: &[Effect::Indirect],
    options: probes_method::OPTIONS,
    description: probes_method::DESCRIPTION,
}];

/// The scene-level methods' blocks of `--list-methods`, in the registry's form.
pub fn listing() -> String {
    SCENE_METHODS
        .iter()
        .map(|spec| recon::registry::method_block(spec.name, spec.description, spec.effects, spec.options))
        .collect()
}
