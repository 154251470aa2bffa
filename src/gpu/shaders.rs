//! WGSL shader library: files under `shaders/` composed with naga_oil.
//!
//! Why naga_oil: it is maintained (Bevy's shader system), works on naga 30 directly so the
//! composed `naga::Module` goes to wgpu without re-parsing, supports `#import` of items and
//! `#define_import_path` modules, and its errors carry file:line spans (codespan).
//!
//! Shaders are read from disk at run time (so hot reload can rebuild pipelines) with the
//! copy embedded at build time as fallback, so the binary also runs outside the repository.
//! Modules start with `#define_import_path gilab::NAME` (shared ones in `shaders/common/`, a
//! technique's own in its folder); every other file is an entry file.

use include_dir::{include_dir, Dir};
use naga_oil::compose::{
    get_preprocessor_data, ComposableModuleDescriptor, Composer, ComposerError, ImportDefinition,
    NagaModuleDescriptor, ShaderDefValue, ShaderLanguage, ShaderType,
};
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

static EMBEDDED: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/shaders");

/// A shader that failed to load or compose: `location` is `file:line:column` when known.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{location}: {message}")]
pub struct ShaderError {
    pub location: String,
    pub message: String,
    /// The full codespan report (source excerpt with markers).
    pub report: String,
}

#[derive(Clone, Debug)]
pub enum ShaderSource {
    Disk(PathBuf),
    Embedded,
}

/// Shader variants chosen by the scene (naga_oil shader defs): a feature the scene lacks is
/// compiled out rather than branched over at run time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ShaderVariant {
    /// `ALPHA_TEST`: BVH traversal runs the any-hit alpha test of alpha-tested triangles.
    /// Off for opaque scenes: on lavapipe the test alone made traversal ~3x slower even where
    /// no triangle was tagged (docs/known-issues.md).
    pub alpha_test: bool,
    /// `INSTANCES`: BVH traversal enters instances' bottom-level trees (a two-level BVH,
    /// src/scene/instancing.rs); off for a flat tree.
    pub instances: bool,
}

impl Default for ShaderVariant {
    /// Everything on: correct for any scene.
    fn default() -> Self {
        ShaderVariant {
            alpha_test: true,
            instances: true,
        }
    }
}

/// The bind group of the surface cache's lookup bindings (shaders/parts/surface_cache/shared.wgsl) when
/// a pipeline sets nothing else: Lumen's own group.
pub const DEFAULT_SURFACE_CACHE_GROUP: u32 = 2;
/// The bind group of the surfels' bindings (shaders/parts/surfels/shared.wgsl) when a pipeline sets
/// nothing else: the surfels' own group (the reflections part reads them at another).
pub const DEFAULT_SURFELS_GROUP: u32 = 2;
/// The bind group of the world ReGIR clipmap's bindings (shaders/parts/world_regir/shared.wgsl)
/// when a pipeline sets nothing else: the part's own build pass binds it there.
pub const DEFAULT_WORLD_REGIR_GROUP: u32 = 2;
/// Group of the world radiance cache's bindings when no pipeline def says (Lumen's probe group).
pub const DEFAULT_WORLD_CACHE_GROUP: u32 = 3;
/// Group of the hash radiance cache's bindings when no pipeline def says (its own passes').
pub const DEFAULT_HASH_CACHE_GROUP: u32 = 2;

impl ShaderVariant {
    fn defs(self) -> std::collections::HashMap<String, ShaderDefValue> {
        let mut defs = std::collections::HashMap::new();
        if self.alpha_test {
            defs.insert("ALPHA_TEST".to_string(), ShaderDefValue::Bool(true));
        }
        if self.instances {
            defs.insert("INSTANCES".to_string(), ShaderDefValue::Bool(true));
        }
        defs
    }
}

/// A composed entry file and the hash of everything it was composed from (its source, every
/// module it imports, directly or not, and the shader defs): equal hashes, equal modules.
pub struct Composed {
    pub module: naga::Module,
    pub version: u64,
}

/// Composed modules by (entry file, defs): composing parses every imported module with naga
/// (~50 ms an entry), and engines compose the same entries again and again.
type ComposeCache = std::collections::HashMap<(String, Vec<String>), (u64, naga::Module)>;
static COMPOSED: std::sync::Mutex<Option<ComposeCache>> = std::sync::Mutex::new(None);

#[derive(Clone, Debug)]
pub struct ShaderLibrary {
    pub source: ShaderSource,
    /// Variant every `compose` builds (defaults to all features on).
    pub variant: ShaderVariant,
    /// Defs a technique adds for some of its pipelines (`with_defs`): a part plugged in at
    /// build time, such as a cache lookup, and the bind group its bindings sit at.
    pub pipeline_defs: Vec<(String, u32)>,
    /// Modules a technique adds to some of its pipelines (`with_imports`) as naga_oil
    /// additional imports: a part's `override fn` of a virtual one (a cache's end of a path,
    /// `GiCache::path_end`), which a plain `#import` would not apply.
    pub pipeline_imports: Vec<String>,
}

impl ShaderLibrary {
    /// Picks `GILAB_SHADERS`, then `./shaders`, then the build tree's `shaders/`, then the embedded copy.
    pub fn discover() -> ShaderLibrary {
        let candidates = [
            std::env::var_os("GILAB_SHADERS").map(PathBuf::from),
            Some(PathBuf::from("shaders")),
            Some(PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/shaders"
            ))),
        ];
        for c in candidates.into_iter().flatten() {
            if c.join("common").is_dir() {
                return ShaderLibrary::at(c);
            }
        }
        ShaderLibrary::embedded()
    }

    pub fn embedded() -> ShaderLibrary {
        ShaderLibrary {
            source: ShaderSource::Embedded,
            variant: ShaderVariant::default(),
            pipeline_defs: Vec::new(),
            pipeline_imports: Vec::new(),
        }
    }

    /// The shaders in folder `root` (a copy a test edits, a user's folder).
    pub fn at(root: impl Into<PathBuf>) -> ShaderLibrary {
        ShaderLibrary {
            source: ShaderSource::Disk(root.into()),
            ..ShaderLibrary::embedded()
        }
    }

    /// The same sources, composed as `variant`.
    pub fn with_variant(&self, variant: ShaderVariant) -> ShaderLibrary {
        ShaderLibrary {
            variant,
            ..self.clone()
        }
    }

    /// The same sources and variant with these defs added (a later value of a name wins).
    pub fn with_defs(&self, defs: &[(&str, u32)]) -> ShaderLibrary {
        let mut out = self.clone();
        for (name, value) in defs {
            out.pipeline_defs.retain(|(n, _)| n != name);
            out.pipeline_defs.push((name.to_string(), *value));
        }
        out.pipeline_defs.sort();
        out
    }

    /// The same sources, variant and defs with these modules added as additional imports.
    pub fn with_imports(&self, modules: &[&str]) -> ShaderLibrary {
        let mut out = self.clone();
        for m in modules {
            if !out.pipeline_imports.iter().any(|n| n == m) {
                out.pipeline_imports.push(m.to_string());
            }
        }
        out.pipeline_imports.sort();
        out
    }

    /// Every def a `compose` sets: the scene variant's, the defaults, then `pipeline_defs`.
    fn defs(&self) -> std::collections::HashMap<String, ShaderDefValue> {
        let mut defs = self.variant.defs();
        defs.insert(
            "SURFACE_CACHE_GROUP".into(),
            ShaderDefValue::UInt(DEFAULT_SURFACE_CACHE_GROUP),
        );
        defs.insert(
            "SURFELS_GROUP".into(),
            ShaderDefValue::UInt(DEFAULT_SURFELS_GROUP),
        );
        defs.insert(
            "WORLD_REGIR_GROUP".into(),
            ShaderDefValue::UInt(DEFAULT_WORLD_REGIR_GROUP),
        );
        defs.insert(
            "WORLD_CACHE_GROUP".into(),
            ShaderDefValue::UInt(DEFAULT_WORLD_CACHE_GROUP),
        );
        defs.insert(
            "HASH_CACHE_GROUP".into(),
            ShaderDefValue::UInt(DEFAULT_HASH_CACHE_GROUP),
        );
        for (name, value) in &self.pipeline_defs {
            defs.insert(name.clone(), ShaderDefValue::UInt(*value));
        }
        defs
    }

    /// The defs as sorted `NAME=value` strings: part of a composed module's cache key.
    pub fn def_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .defs()
            .into_iter()
            .map(|(k, v)| format!("{k}={v:?}"))
            .collect();
        names.sort();
        // The additional imports change the module too: they belong to its cache key.
        names.extend(self.pipeline_imports.iter().map(|m| format!("+{m}")));
        names
    }

    pub fn root(&self) -> Option<&Path> {
        match &self.source {
            ShaderSource::Disk(p) => Some(p),
            ShaderSource::Embedded => None,
        }
    }

    /// Every `.wgsl` file, as (path relative to `shaders/`, source).
    pub fn files(&self) -> Result<BTreeMap<String, String>, ShaderError> {
        let mut out = BTreeMap::new();
        match &self.source {
            ShaderSource::Disk(root) => collect_disk(root, root, &mut out)?,
            ShaderSource::Embedded => collect_embedded(&EMBEDDED, &mut out),
        }
        Ok(out)
    }

    /// Entry files: `.wgsl` files that declare no `#define_import_path` (that directive marks a
    /// module, wherever it lives: shared ones in `common/`, a technique's own in its folder).
    pub fn entry_files(&self) -> Result<Vec<String>, ShaderError> {
        Ok(self
            .files()?
            .into_iter()
            .filter(|(_, src)| get_preprocessor_data(src).0.is_none())
            .map(|(k, _)| k)
            .collect())
    }

    /// Composes `entry` (e.g. "reference/path_trace.wgsl") and its imports into one validated module.
    pub fn compose(&self, entry: &str) -> Result<naga::Module, ShaderError> {
        Ok(self.compose_versioned(entry)?.module)
    }

    /// [`ShaderLibrary::compose`] with the version of its sources; taken from a process-wide
    /// cache when no file it reads has changed since.
    pub fn compose_versioned(&self, entry: &str) -> Result<Composed, ShaderError> {
        let files = self.files()?;
        let defs = self.def_names();
        let version = source_version(&files, entry, &defs, &self.pipeline_imports);
        let key = (entry.to_string(), defs);
        if let Some((v, module)) = COMPOSED
            .lock()
            .expect("compose cache")
            .as_ref()
            .and_then(|c| c.get(&key))
        {
            if *v == version {
                return Ok(Composed {
                    module: module.clone(),
                    version,
                });
            }
        }
        let module = self.compose_files(&files, entry)?;
        COMPOSED
            .lock()
            .expect("compose cache")
            .get_or_insert_with(Default::default)
            .insert(key, (version, module.clone()));
        Ok(Composed { module, version })
    }

    fn compose_files(
        &self,
        files: &BTreeMap<String, String>,
        entry: &str,
    ) -> Result<naga::Module, ShaderError> {
        let source = files.get(entry).ok_or_else(|| ShaderError {
            location: format!("shaders/{entry}"),
            message: "shader file not found".into(),
            report: String::new(),
        })?;
        let modules = modules_of(files);
        let mut composer = Composer::default();
        let mut added = HashSet::new();
        let (_, imports, _) = get_preprocessor_data(source);
        let imports = imports.into_iter().map(|i| i.import);
        for import in imports.chain(self.pipeline_imports.iter().cloned()) {
            add_module_recursive(
                &mut composer,
                &modules,
                &import,
                &mut added,
                &mut Vec::new(),
            )?;
        }
        let additional_imports: Vec<ImportDefinition> = self
            .pipeline_imports
            .iter()
            .map(|m| ImportDefinition {
                import: m.clone(),
                items: Vec::new(),
            })
            .collect();
        let file_path = format!("shaders/{entry}");
        composer
            .make_naga_module(NagaModuleDescriptor {
                source,
                file_path: &file_path,
                shader_type: ShaderType::Wgsl,
                shader_defs: self.defs(),
                additional_imports: &additional_imports,
            })
            .map_err(|e| composer_error(&composer, &e))
    }

    /// Files that are, or import (directly or not), the given file: what hot reload must
    /// rebuild. Entry files, and the modules a pipeline adds by `with_imports` (which no entry
    /// imports: an engine records them beside its entries, `import_files`).
    pub fn dependents(&self, changed: &str) -> Result<Vec<String>, ShaderError> {
        let files = self.files()?;
        let modules = modules_of(&files);
        let mut out = Vec::new();
        for (file, source) in &files {
            let imports_changed = || {
                import_closure(&modules, source, &self.pipeline_imports)
                    .iter()
                    .any(|name| modules[name].0 == changed)
            };
            if file == changed || imports_changed() {
                out.push(file.clone());
            }
        }
        Ok(out)
    }

    /// The files of the modules added by `with_imports`, which hot reload watches like the
    /// entry files (`pipelines::recording_entries`).
    pub fn import_files(&self) -> Vec<String> {
        if self.pipeline_imports.is_empty() {
            return Vec::new();
        }
        let Ok(files) = self.files() else {
            return Vec::new();
        };
        let modules = modules_of(&files);
        self.pipeline_imports
            .iter()
            .filter_map(|m| resolve_module(&modules, m))
            .map(|name| modules[&name].0.clone())
            .collect()
    }
}

/// A hash of `entry`'s source, every module it imports (directly or not) and `defs`.
fn source_version(
    files: &BTreeMap<String, String>,
    entry: &str,
    defs: &[String],
    extra_imports: &[String],
) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    (entry, defs).hash(&mut hasher);
    if let Some(source) = files.get(entry) {
        source.hash(&mut hasher);
        let modules = modules_of(files);
        for name in import_closure(&modules, source, extra_imports) {
            modules[&name].hash(&mut hasher);
        }
    }
    hasher.finish()
}

/// Module name -> (file, source) for every file that declares an import path.
fn modules_of(files: &BTreeMap<String, String>) -> BTreeMap<String, (String, String)> {
    let mut modules = BTreeMap::new();
    for (path, src) in files {
        if let (Some(name), _, _) = get_preprocessor_data(src) {
            modules.insert(name, (path.clone(), src.clone()));
        }
    }
    modules
}

/// The modules `source` and `extra_imports` import, directly or not, in name order.
fn import_closure(
    modules: &BTreeMap<String, (String, String)>,
    source: &str,
    extra_imports: &[String],
) -> std::collections::BTreeSet<String> {
    let mut seen = std::collections::BTreeSet::new();
    let mut stack: Vec<String> = get_preprocessor_data(source)
        .1
        .into_iter()
        .map(|i| i.import)
        .chain(extra_imports.iter().cloned())
        .collect();
    while let Some(import) = stack.pop() {
        let Some(name) = resolve_module(modules, &import) else {
            continue;
        };
        if seen.insert(name.clone()) {
            stack.extend(
                get_preprocessor_data(&modules[&name].1)
                    .1
                    .into_iter()
                    .map(|i| i.import),
            );
        }
    }
    seen
}

/// `gilab::scene::Light` imports item `Light` from module `gilab::scene`: longest known prefix wins.
fn resolve_module(modules: &BTreeMap<String, (String, String)>, import: &str) -> Option<String> {
    let mut candidate = import.to_string();
    loop {
        if modules.contains_key(&candidate) {
            return Some(candidate);
        }
        let cut = candidate.rfind("::")?;
        candidate.truncate(cut);
    }
}

fn add_module_recursive(
    composer: &mut Composer,
    modules: &BTreeMap<String, (String, String)>,
    import: &str,
    added: &mut HashSet<String>,
    chain: &mut Vec<String>,
) -> Result<(), ShaderError> {
    let Some(name) = resolve_module(modules, import) else {
        // Unknown: let naga_oil report it with a span when composing the importer.
        return Ok(());
    };
    if added.contains(&name) {
        return Ok(());
    }
    if chain.contains(&name) {
        return Err(ShaderError {
            location: format!("shaders/{}", modules[&name].0),
            message: format!("import cycle: {} -> {name}", chain.join(" -> ")),
            report: String::new(),
        });
    }
    chain.push(name.clone());
    let (file, src) = &modules[&name];
    for dep in get_preprocessor_data(src).1 {
        add_module_recursive(composer, modules, &dep.import, added, chain)?;
    }
    chain.pop();
    let file_path = format!("shaders/{file}");
    let result = composer.add_composable_module(ComposableModuleDescriptor {
        source: src,
        file_path: &file_path,
        language: ShaderLanguage::Wgsl,
        ..Default::default()
    });
    if let Err(e) = result {
        return Err(composer_error(composer, &e));
    }
    added.insert(name);
    Ok(())
}

/// Turns naga_oil's codespan report into `file:line:column: message` plus the full report.
fn composer_error(composer: &Composer, e: &ComposerError) -> ShaderError {
    let report = e.emit_to_string(composer);
    let plain = strip_ansi(&report);
    let location = plain
        .lines()
        .find_map(|l| l.split_once("┌─ ").map(|(_, loc)| loc.trim().to_string()))
        .unwrap_or_else(|| e.source.path(composer).clone());
    let message = plain
        .lines()
        .find_map(|l| l.trim().strip_prefix("error: ").map(str::to_string))
        .unwrap_or_else(|| e.inner.to_string());
    ShaderError {
        location,
        message,
        report: plain,
    }
}

fn strip_ansi(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for c2 in chars.by_ref() {
                if c2.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

fn collect_disk(
    root: &Path,
    dir: &Path,
    out: &mut BTreeMap<String, String>,
) -> Result<(), ShaderError> {
    let io_err = |p: &Path, e: std::io::Error| ShaderError {
        location: p.display().to_string(),
        message: e.to_string(),
        report: String::new(),
    };
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| io_err(dir, e))?
        .flatten()
        .collect();
    entries.sort_by_key(|e| e.path());
    for entry in entries {
        let p = entry.path();
        if p.is_dir() {
            collect_disk(root, &p, out)?;
        } else if p.extension().is_some_and(|e| e == "wgsl") {
            let rel = p
                .strip_prefix(root)
                .unwrap_or(&p)
                .to_string_lossy()
                .replace('\\', "/");
            out.insert(rel, std::fs::read_to_string(&p).map_err(|e| io_err(&p, e))?);
        }
    }
    Ok(())
}

fn collect_embedded(dir: &Dir<'static>, out: &mut BTreeMap<String, String>) {
    for f in dir.files() {
        if f.path().extension().is_some_and(|e| e == "wgsl") {
            if let Some(text) = f.contents_utf8() {
                out.insert(
                    f.path().to_string_lossy().replace('\\', "/"),
                    text.to_string(),
                );
            }
        }
    }
    for d in dir.dirs() {
        collect_embedded(d, out);
    }
}
