//! Stage shaders composed from named WGSL modules.
//!
//! A stage's shader is an ordered list of modules: `shaders/<name>.wgsl` files and the small
//! pieces the host generates (constants such as `VOLUME_FILTERABLE`, a module with its
//! binding group put in, [`crate::LoopGuard::wgsl`]). WGSL has no imports, so the modules are
//! joined in order, and a module that needs something only another one defines says so in
//! its header:
//!
//! ```text
//! // requires: majorant_fetch, env_word
//! ```
//!
//! (functions, constants, variables or structs, by name). [`ShaderComposer::build`] checks
//! that every requirement is defined by some module of the list, and that no name is defined
//! by two modules, and says which module and which name when not; naga would only report an
//! unknown identifier somewhere in the joined text.

use std::fmt;

/// An ordered list of named WGSL modules; see the module documentation.
#[derive(Clone, Debug, Default)]
pub struct ShaderComposer {
    modules: Vec<(String, String)>,
}

/// A composition whose modules do not fit together.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ComposeError {
    /// `module` requires `symbol`, and no module defines it.
    Missing { module: String, symbol: String, modules: Vec<String> },
    /// Two modules define `symbol`.
    Duplicate { symbol: String, first: String, second: String },
}

impl fmt::Display for ComposeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ComposeError::Missing { module, symbol, modules } => {
                write!(f, "WGSL module `{module}` requires `{symbol}`, which none of the composed modules defines ({})", modules.join(", "))
            }
            ComposeError::Duplicate { symbol, first, second } => write!(f, "`{symbol}` is defined by both WGSL modules `{first}` and `{second}`"),
        }
    }
}

impl std::error::Error for ComposeError {}

impl From<ComposeError> for crate::GpuError {
    fn from(e: ComposeError) -> Self {
        crate::GpuError::Validation { context: "shader composition".to_string(), message: e.to_string() }
    }
}

impl ShaderComposer {
    /// No module yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The start of every stage shader: `VOLUME_FILTERABLE` (`filterable` must be
    /// [`crate::GpuContext::float32_filterable`] of the device the pipeline is built on),
    /// `dispatch` ([`crate::DISPATCH_WGSL`]) and `volume` ([`crate::VOLUME_WGSL`]).
    pub fn stage(filterable: bool) -> Self {
        Self::new()
            .module("VOLUME_FILTERABLE", format!("const VOLUME_FILTERABLE: bool = {filterable};"))
            .module("dispatch", crate::DISPATCH_WGSL)
            .module("volume", crate::VOLUME_WGSL)
    }

    /// `source` as the next module, called `name` in errors.
    pub fn module(mut self, name: impl Into<String>, source: impl Into<String>) -> Self {
        self.modules.push((name.into(), source.into()));
        self
    }

    /// The modules joined in order, unchecked.
    pub fn source(&self) -> String {
        self.modules.iter().map(|(_, s)| s.as_str()).collect::<Vec<_>>().join("\n")
    }

    /// The modules joined in order, once every requirement is defined and no name twice.
    pub fn build(&self) -> Result<String, ComposeError> {
        let mut defined: Vec<(&str, &str)> = Vec::new();
        for (module, source) in &self.modules {
            for symbol in defined_symbols(source) {
                if let Some((_, first)) = defined.iter().find(|(s, _)| *s == symbol) {
                    return Err(ComposeError::Duplicate { symbol: symbol.to_string(), first: first.to_string(), second: module.clone() });
                }
                defined.push((symbol, module));
            }
        }
        for (module, source) in &self.modules {
            for symbol in required_symbols(source) {
                if !defined.iter().any(|(s, _)| *s == symbol) {
                    let modules = self.modules.iter().map(|(n, _)| n.clone()).collect();
                    return Err(ComposeError::Missing { module: module.clone(), symbol: symbol.to_string(), modules });
                }
            }
        }
        Ok(self.source())
    }
}

/// The names a module's `// requires:` lines list.
fn required_symbols(source: &str) -> impl Iterator<Item = &str> {
    source
        .lines()
        .filter_map(|l| l.trim_start().strip_prefix("// requires:"))
        .flat_map(|l| l.split(','))
        .map(|s| s.trim().trim_start_matches("fn ").trim())
        .filter(|s| !s.is_empty())
}

/// The names a module declares at module scope (declarations start a line, unindented):
/// functions, structs, constants, overrides, aliases and variables.
fn defined_symbols(source: &str) -> Vec<&str> {
    let mut out = Vec::new();
    for line in source.lines() {
        if line.starts_with(char::is_whitespace) {
            continue;
        }
        // Attributes first (`@group(1) @binding(2) var<...> name`, `@compute ... fn name`).
        let mut rest = line;
        while let Some(after) = rest.strip_prefix('@') {
            let end = after.find(char::is_whitespace).unwrap_or(after.len());
            rest = after[end..].trim_start();
        }
        let name = ["fn ", "struct ", "const ", "override ", "alias ", "var "].iter().find_map(|k| rest.strip_prefix(k)).or_else(|| {
            // var<space, access> name
            rest.strip_prefix("var<").and_then(|r| r.split_once('>')).map(|(_, r)| r)
        });
        if let Some(name) = name {
            let name = name.trim_start();
            let end = name.find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(name.len());
            if end > 0 {
                out.push(&name[..end]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn declarations_are_found_at_module_scope_only() {
        let source = "// requires: fn a, B\nconst C: u32 = 1u;\n@group(1) @binding(2) var<storage, read> d: array<f32>;\nvar<private> e: f32;\nstruct F {\n    x: f32,\n}\n@compute @workgroup_size(64)\nfn g(x: u32) {\n    let h = 1;\n    const i = 2;\n}\n";
        assert_eq!(defined_symbols(source), ["C", "d", "e", "F", "g"]);
        assert_eq!(required_symbols(source).collect::<Vec<_>>(), ["a", "B"]);
    }

    #[test]
    fn a_missing_requirement_names_the_module_and_the_symbol() {
        let composer = ShaderComposer::new().module("tracking", "// requires: majorant_fetch\nfn track() {}\n").module("stage", "fn main() {}\n");
        let e = composer.build().unwrap_err();
        assert_eq!(e, ComposeError::Missing { module: "tracking".into(), symbol: "majorant_fetch".into(), modules: vec!["tracking".into(), "stage".into()] });
        assert!(e.to_string().starts_with("WGSL module `tracking` requires `majorant_fetch`, which none"), "{e}");
        let fixed = composer.module("accessors", "fn majorant_fetch(index: u32) -> f32 {\n    return 0.0;\n}\n");
        assert!(fixed.build().is_ok());
    }

    #[test]
    fn a_name_defined_twice_names_both_modules() {
        let e = ShaderComposer::new().module("a", "const X: u32 = 1u;").module("b", "const X: u32 = 2u;").build().unwrap_err();
        assert_eq!(e.to_string(), "`X` is defined by both WGSL modules `a` and `b`");
    }

    #[test]
    fn a_stage_starts_as_compose_shader_does() {
        assert_eq!(ShaderComposer::stage(true).module("stage", "fn main() {}").build().unwrap(), crate::compose_shader(true, "fn main() {}"));
    }
}
