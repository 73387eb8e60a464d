//! Every path a command writes, planned in one place and checked before any work: each output
//! against every input the command reads (the scene file and every file it references, sample
//! files, references, caches) and against every other output.
//!
//! A command lists its outputs (files, with the previews and sidecars derived from them, and
//! folders it fills) and its inputs in an [`OutputPlan`] and calls [`OutputPlan::check`] before
//! anything long starts; after loading its scene it adds the files the scene read
//! (`Scene::inputs`) and checks again, still before any tracing. A file output is refused when
//! - its name is `-` (there is no writing to standard output), ends in `/`, or names no file
//!   (`..`, `.`): it names a folder;
//! - it is not a new or regular file (`sampleio::check_output_target`: a folder, a device, a
//!   FIFO or socket, a symbolic link);
//! - the nearest of its folders that exists is not a folder (a file on the way), or cannot be
//!   written into (tried by creating and removing a file there); the folders that do not exist
//!   yet are created when the output is written;
//! - it is the same file as an input or another output: by device and inode where the file
//!   exists (so also through `..`, another relative path or a hard link), else by its
//!   canonical folder and name;
//! - it lies at or inside a folder output (which the command removes and rewrites).
//!
//! An input inside a folder output is refused too.

use std::path::{Component, Path, PathBuf};

use anyhow::{bail, Result};

/// One path the command writes.
struct Output {
    path: PathBuf,
    /// What it is, for messages (`--out`, `the PNG preview beside --out`, ...).
    what: String,
    /// A folder the command fills (and may clear) rather than a file.
    folder: bool,
}

/// One path the command reads.
struct Input {
    path: PathBuf,
    what: String,
}

/// The outputs and inputs of one command (see the module doc).
#[derive(Default)]
pub struct OutputPlan {
    outputs: Vec<Output>,
    inputs: Vec<Input>,
}

/// Where a path leads: the file it names (device and inode) where it exists, else its canonical
/// folder and name.
#[derive(Debug, PartialEq, Eq, Hash)]
enum Identity {
    Node(u64, u64),
    Path(PathBuf),
}

fn identity(path: &Path) -> Identity {
    #[cfg(unix)]
    if let Ok(metadata) = std::fs::metadata(path) {
        use std::os::unix::fs::MetadataExt;
        return Identity::Node(metadata.dev(), metadata.ino());
    }
    Identity::Path(resolved(path))
}

/// `path` made absolute with every symbolic link and `..` resolved, as far as it exists; the
/// components that do not exist yet are appended lexically (`..` over one of them removes it:
/// a missing component cannot be a link).
pub fn resolved(path: &Path) -> PathBuf {
    let absolute =
        if path.is_absolute() { path.to_path_buf() } else { std::env::current_dir().unwrap_or_default().join(path) };
    let components: Vec<Component> = absolute.components().collect();
    // The longest prefix that exists, canonicalised; the rest lexically.
    for split in (0..=components.len()).rev() {
        let prefix: PathBuf = components[..split].iter().collect();
        if let Ok(mut base) = std::fs::canonicalize(&prefix) {
            for component in &components[split..] {
                match component {
                    Component::CurDir => {}
                    Component::ParentDir => {
                        base.pop();
                    }
                    other => base.push(other.as_os_str()),
                }
            }
            return base;
        }
    }
    absolute
}

/// The PNG preview written beside an EXR output: `X.png` for `X.exr`.
pub fn preview_of(out: &Path) -> PathBuf {
    out.with_extension("png")
}

/// Whether `path` names a folder by its spelling: a trailing `/`, or a last component of `.`,
/// `..` or none at all.
fn names_a_folder(path: &Path) -> bool {
    // Read off the spelling, not `components()`, which drops a trailing `.` (`x.exr/.` would
    // read as the file `x.exr` and fail only when renamed into place, after the work).
    let text = path.as_os_str().as_encoded_bytes();
    let last = text.rsplit(|&b| b == b'/').next().unwrap_or(text);
    matches!(last, b"" | b"." | b"..") || !matches!(path.components().next_back(), Some(Component::Normal(_)))
}

impl OutputPlan {
    pub fn new() -> OutputPlan {
        OutputPlan::default()
    }

    /// A file the command writes; `what` names it in messages.
    pub fn file(&mut self, path: &Path, what: impl Into<String>) -> &mut OutputPlan {
        self.outputs.push(Output { path: path.to_path_buf(), what: what.into(), folder: false });
        self
    }

    /// A folder the command fills and may clear: no input and no other output may lie inside.
    pub fn folder(&mut self, path: &Path, what: impl Into<String>) -> &mut OutputPlan {
        self.outputs.push(Output { path: path.to_path_buf(), what: what.into(), folder: true });
        self
    }

    /// A file (or folder) the command reads.
    pub fn input(&mut self, path: &Path, what: impl Into<String>) -> &mut OutputPlan {
        if !self.inputs.iter().any(|i| i.path == path) {
            self.inputs.push(Input { path: path.to_path_buf(), what: what.into() });
        }
        self
    }

    /// The scene file of `--scene`, when one is given.
    pub fn scene_file(&mut self, scene: Option<&Path>) -> &mut OutputPlan {
        if let Some(scene) = scene {
            self.input(scene, "the scene file");
        }
        self
    }

    /// Every file the loaded `scene` read: its own file and those it references.
    pub fn scene(&mut self, scene: &tracer::Scene) -> &mut OutputPlan {
        for (i, path) in scene.inputs.iter().enumerate() {
            let what = if i == 0 {
                "the scene file".to_string()
            } else {
                format!("a file the scene {} reads", scene.source.display())
            };
            self.input(path, what);
        }
        self
    }

    /// Checks every output (see the module doc); the first problem is the error, naming the
    /// output, what it is and what it collides with. Linear in the number of paths (an
    /// animation plans two files a frame), plus one pass per folder output.
    pub fn check(&self) -> Result<()> {
        let place = |o: &Output| format!("{} ({})", o.path.display(), o.what);
        let mut writable = std::collections::HashSet::new();
        for output in self.outputs.iter().filter(|o| !o.folder) {
            check_file_output(output, &mut writable)?;
        }
        let mut read: std::collections::HashMap<Identity, &Input> = std::collections::HashMap::new();
        for input in &self.inputs {
            read.entry(identity(&input.path)).or_insert(input);
        }
        let mut written: std::collections::HashMap<Identity, &Output> = std::collections::HashMap::new();
        for output in self.outputs.iter().filter(|o| !o.folder) {
            let id = identity(&output.path);
            if let Some(input) = read.get(&id) {
                bail!(
                    "{}: refusing to write here: it is {} {}, which the command reads; choose another name",
                    place(output),
                    input.what,
                    input.path.display()
                );
            }
            if let Some(other) = written.insert(id, output) {
                bail!(
                    "{}: it is the same file as {}: one would replace the other; choose another name",
                    place(output),
                    place(other)
                );
            }
        }
        let inputs: Vec<(PathBuf, &Input)> = self.inputs.iter().map(|i| (resolved(&i.path), i)).collect();
        for (i, output) in self.outputs.iter().enumerate().filter(|(_, o)| o.folder) {
            let folder = resolved(&output.path);
            if let Some((_, input)) = inputs.iter().find(|(path, _)| path.starts_with(&folder)) {
                bail!(
                    "{}: {} {} lies at or inside this path, which the command removes and rewrites; move it or \
                     choose another place",
                    place(output),
                    input.what,
                    input.path.display()
                );
            }
            for (j, other) in self.outputs.iter().enumerate() {
                if j != i && resolved(&other.path).starts_with(&folder) {
                    bail!(
                        "{}: {} lies at or inside this path, which the command removes and rewrites; choose another \
                         place",
                        place(output),
                        place(other)
                    );
                }
            }
        }
        Ok(())
    }
}

/// The plan of a benchmark: its `--json` (when given) against its scene files, checked; add
/// each loaded scene's files with [`OutputPlan::scene`] and check again.
pub fn json_plan(json: Option<&Path>, scenes: &[Option<PathBuf>]) -> Result<OutputPlan> {
    let mut plan = OutputPlan::new();
    if let Some(json) = json {
        plan.file(json, "--json");
    }
    for scene in scenes {
        plan.scene_file(scene.as_deref());
    }
    plan.check()?;
    Ok(plan)
}

/// The plan of `lfr compare`: what it writes into `dir` (`compare::out_dir::WRITTEN`, each
/// treated as a folder: nothing read may lie at or under it, since a run removes them first)
/// against the scene file (`--scene`), an external reference's files and the reference cache
/// folder `cache`. Check it before the scene is loaded, and again with [`OutputPlan::scene`]
/// once it is, for the files the scene reads.
pub fn comparison_plan(dir: &Path, scene: Option<&Path>, references: &[PathBuf], cache: &Path) -> OutputPlan {
    let mut plan = OutputPlan::new();
    for name in crate::compare::out_dir::WRITTEN {
        plan.folder(&dir.join(name), format!("the comparison's {name}"));
    }
    plan.scene_file(scene).input(cache, "the reference cache (--cache-dir)");
    for reference in references {
        plan.input(reference, "--reference");
    }
    plan
}

/// The checks of one file output on its own: its spelling, what is at its path, its folder.
fn check_file_output(output: &Output, writable: &mut std::collections::HashSet<PathBuf>) -> Result<()> {
    let path = &output.path;
    let name = format!("{} ({})", path.display(), output.what);
    if path.as_os_str() == "-" {
        bail!("{name}: lfr writes no output to standard output; name a file");
    }
    if path.as_os_str().is_empty() || names_a_folder(path) {
        bail!("{name}: names a folder (a trailing `/`, `.` or `..`), not a file; name the file to write");
    }
    // The folders that do not exist yet are created by the writer; the nearest one that exists
    // must be a folder that can be written into.
    let mut folder = Path::new(".");
    for ancestor in path.ancestors().skip(1).filter(|a| !a.as_os_str().is_empty()) {
        match std::fs::metadata(ancestor) {
            // Missing, or under a file (which the next ancestor names).
            Err(e) if matches!(e.kind(), std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory) => continue,
            Err(e) => bail!("{name}: cannot reach the folder {}: {e}", ancestor.display()),
            Ok(m) if !m.is_dir() => bail!("{name}: {} is not a folder", ancestor.display()),
            Ok(_) => {
                folder = ancestor;
                break;
            }
        }
    }
    sampleio::check_output_target(path, &[])?;
    // Whether a file can be made there, tried now (once per folder) rather than after the work.
    if !writable.contains(folder) {
        if let Err(e) = tempfile::Builder::new().prefix(".lfr-write-test").tempfile_in(folder) {
            bail!("{name}: cannot write into the folder {}: {e}", folder.display());
        }
        writable.insert(folder.to_path_buf());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_is_read_off_the_spelling_whatever_components_make_of_it() {
        for folder in ["o.exr/", "o.exr/.", "o.exr/..", "d/o.exr//", ".", "..", "/", "./", "a/b/."] {
            assert!(names_a_folder(Path::new(folder)), "{folder}");
        }
        for file in ["o.exr", "a/./o.exr", "./o.exr", "../o.exr", "a/../o.exr", ".o.exr", "o.exr."] {
            assert!(!names_a_folder(Path::new(file)), "{file}");
        }
    }

    fn refusal(plan: &OutputPlan) -> String {
        plan.check().expect_err("refused").to_string()
    }

    #[test]
    fn an_output_equal_to_an_input_by_any_name_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("a")).unwrap();
        std::fs::write(d.join("X.png"), b"texture").unwrap();
        std::fs::write(d.join("scene.toml"), b"").unwrap();
        let texture = d.join("X.png");
        // The same file through `..`, and through a hard link.
        let spelled = d.join("a/../X.png");
        std::fs::hard_link(&texture, d.join("linked.png")).unwrap();
        for output in [texture.clone(), spelled, d.join("linked.png")] {
            let mut plan = OutputPlan::new();
            plan.file(&output, "the PNG preview beside --out").input(&texture, "a texture");
            let message = refusal(&plan);
            assert!(message.contains("a texture") && message.contains("PNG preview"), "{message}");
        }
        let mut plan = OutputPlan::new();
        plan.file(&d.join("new.png"), "--out").input(&texture, "a texture");
        plan.check().unwrap();
        assert_eq!(std::fs::read(&texture).unwrap(), b"texture", "never written");
    }

    #[test]
    fn two_outputs_of_one_name_are_refused_new_or_not() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("a")).unwrap();
        let mut plan = OutputPlan::new();
        plan.file(&d.join("r.json"), "--json").file(&d.join("a/../r.json"), "--out");
        assert!(refusal(&plan).contains("same file"), "{}", refusal(&plan));
        std::fs::write(d.join("r.json"), b"{}").unwrap();
        assert!(refusal(&plan).contains("same file"));
    }

    #[test]
    fn folder_spellings_files_as_folders_and_standard_output_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = d.to_str().unwrap();
        std::fs::write(d.join("file"), b"").unwrap();
        for (path, needle) in [
            (format!("{text}/o.exr/"), "names a folder"),
            (format!("{text}/.."), "names a folder"),
            ("-".to_string(), "standard output"),
            (format!("{text}/file/o.exr"), "is not a folder"),
            (format!("{text}/file/deeper/o.exr"), "is not a folder"),
            (text.to_string(), "directory"),
        ] {
            let mut plan = OutputPlan::new();
            plan.file(Path::new(&path), "--out");
            let message = refusal(&plan);
            assert!(message.contains(needle), "{path}: {message}");
        }
        // Folders that do not exist yet pass (the writer creates them), and are not created here.
        let mut plan = OutputPlan::new();
        plan.file(&d.join("new/deeper/o.exr"), "--out");
        plan.check().unwrap();
        assert!(!d.join("new").exists());
        // A directory by its plain name: `check_output_target` refuses it.
        std::fs::create_dir(d.join("o.exr")).unwrap();
        let mut plan = OutputPlan::new();
        plan.file(&d.join("o.exr"), "--out");
        assert!(refusal(&plan).contains("directory"), "{}", refusal(&plan));
    }

    #[test]
    fn an_input_inside_a_folder_output_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir_all(d.join("out/images")).unwrap();
        std::fs::write(d.join("out/images/reference.exr"), b"").unwrap();
        let mut plan = OutputPlan::new();
        plan.folder(&d.join("out/images"), "--out's images").input(&d.join("out/images/reference.exr"), "--reference");
        assert!(refusal(&plan).contains("--reference"), "{}", refusal(&plan));
        // Missing folders resolve lexically.
        let mut plan = OutputPlan::new();
        plan.folder(&d.join("new/images"), "images").input(&d.join("new/x/../images/a.png"), "a texture");
        assert!(resolved(&d.join("new/x/../images")).ends_with("new/images"));
        assert!(refusal(&plan).contains("lies at or inside"), "{}", refusal(&plan));
    }
}
