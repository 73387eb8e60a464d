//! Reading an input file the way every loader must: only a regular file (a directory, a FIFO
//! or a device is an error at once, where reading would block forever or never end), no larger
//! than a documented bound (`crate::limits`), with an error that says which of these it was;
//! and, for a file that a scene file references, only inside the folders a scene may reach
//! ([`FileAccess`], [`confine`]).

use std::cell::RefCell;
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::error::SceneError;

/// Which files the references inside scene files (TOML mesh and texture paths, OBJ `mtllib`
/// and texture maps, glTF buffer and image URIs) may name.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FileAccess {
    /// Only files inside the folder of the file that makes the reference, or inside the shared
    /// scenes folder that `@shared/` names (`$LFR_SCENES`, else `../../shared/scenes` from that
    /// folder), after canonicalisation: `..` and symbolic links that lead out are refused.
    #[default]
    Confined,
    /// Any file the user can read (`--allow-outside-scene-dir`).
    Anywhere,
}

/// Checks that `target`, which `referencing_file` names as `reference` in `field`, may be read
/// under `access` (see [`FileAccess::Confined`]). A target that does not exist passes: the read
/// that follows reports it. The error names the referencing file, the field and the reference,
/// never anything of the refused file's content (it is not opened).
pub fn confine(
    target: &Path,
    reference: &str,
    referencing_file: &Path,
    field: &str,
    access: FileAccess,
) -> Result<(), SceneError> {
    if access == FileAccess::Anywhere {
        return Ok(());
    }
    let Ok(canonical) = std::fs::canonicalize(target) else { return Ok(()) };
    let folder = referencing_file.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let roots = [folder.to_path_buf(), shared_scenes_dir(folder)];
    if roots.iter().filter_map(|root| std::fs::canonicalize(root).ok()).any(|root| canonical.starts_with(root)) {
        return Ok(());
    }
    Err(SceneError::new(
        referencing_file,
        field,
        format!(
            "`{reference}` resolves to {}, outside this file's folder and the shared scenes folder; \
             a scene may only reference files there (--allow-outside-scene-dir lifts this)",
            canonical.display()
        ),
    ))
}

thread_local! {
    /// The files [`check_input`] was asked about while [`recording_reads`] runs on this thread.
    static READS: RefCell<Option<Vec<PathBuf>>> = const { RefCell::new(None) };
}

/// Runs `load` and returns, beside its result, every file it read through [`check_input`] (and
/// so [`read_input`]) on this thread, in the order read: the scene file and every file it
/// references (models, material libraries, glTF buffers and images, textures). The commands
/// check their outputs against these before any work. Every loader reads its files on the
/// calling thread; nested recordings each see their own reads, which also count for the
/// enclosing one.
pub fn recording_reads<T>(load: impl FnOnce() -> T) -> (T, Vec<PathBuf>) {
    let outer = READS.with(|reads| reads.borrow_mut().replace(Vec::new()));
    let result = load();
    let read = READS.with(|reads| reads.borrow_mut().take()).unwrap_or_default();
    if let Some(mut outer) = outer {
        outer.extend(read.iter().cloned());
        READS.with(|reads| *reads.borrow_mut() = Some(outer));
    }
    (result, read)
}

/// Checks that `path` (followed through symbolic links) is a regular file of at most
/// `max_bytes`; `referenced_from` and `field` name where the path came from in errors.
/// The error names `referenced_from` first; `path` is repeated in the message only when it is
/// another file (a scene's own file would be named twice).
pub fn check_input(path: &Path, max_bytes: u64, referenced_from: &Path, field: &str) -> Result<u64, SceneError> {
    READS.with(|reads| {
        if let Some(reads) = reads.borrow_mut().as_mut() {
            if !reads.iter().any(|p| p == path) {
                reads.push(path.to_path_buf());
            }
        }
    });
    let error = |message: String| SceneError::new(referenced_from, field, message);
    let named = if path == referenced_from { String::new() } else { format!("{}: ", path.display()) };
    let metadata = std::fs::metadata(path).map_err(|e| {
        error(match e.kind() {
            std::io::ErrorKind::NotFound => format!("{named}file not found"),
            _ => format!("{named}cannot read: {e}"),
        })
    })?;
    if metadata.is_dir() {
        return Err(error(format!("{named}a directory, not a file")));
    }
    if !metadata.is_file() {
        return Err(error(format!("{named}not a regular file (a device, FIFO or socket)")));
    }
    if metadata.len() > max_bytes {
        return Err(error(format!("{named}{} bytes, more than the {max_bytes} lfr reads", metadata.len())));
    }
    Ok(metadata.len())
}

/// The bytes of `path` after [`check_input`]; reads at most `max_bytes` even if the file grows.
pub fn read_input(path: &Path, max_bytes: u64, referenced_from: &Path, field: &str) -> Result<Vec<u8>, SceneError> {
    let len = check_input(path, max_bytes, referenced_from, field)?;
    let error =
        |e: std::io::Error| SceneError::new(referenced_from, field, format!("{}: cannot read: {e}", path.display()));
    let file = std::fs::File::open(path).map_err(error)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max_bytes).read_to_end(&mut bytes).map_err(error)?;
    Ok(bytes)
}

/// The folder that `@shared/` paths resolve to.
pub fn shared_scenes_dir(description_dir: &Path) -> PathBuf {
    match std::env::var_os("LFR_SCENES") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => description_dir.join("../../shared/scenes"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_within_the_bound_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene.toml");
        let file = dir.path().join("mesh.obj");
        std::fs::write(&file, b"v 0 0 0\n").unwrap();
        assert_eq!(read_input(&file, 100, &scene, "mesh.file").unwrap(), b"v 0 0 0\n");
        let message = |path: &Path, max: u64| read_input(path, max, &scene, "mesh.file").unwrap_err().to_string();
        for (path, max, needle) in [
            (file.as_path(), 3, "more than the 3"),
            (dir.path(), 100, "a directory"),
            (Path::new("/dev/zero"), 100, "not a regular file"),
            (&dir.path().join("gone.obj"), 100, "file not found"),
        ] {
            let text = message(path, max);
            assert!(text.contains(needle) && text.contains("scene.toml") && text.contains("mesh.file"), "{text}");
        }
        #[cfg(unix)]
        {
            let looped = dir.path().join("loop.obj");
            std::os::unix::fs::symlink(&looped, &looped).unwrap();
            assert!(message(&looped, 100).contains("cannot read"), "{}", message(&looped, 100));
        }
        // Reads are recorded while a recording runs, nested ones for both.
        let other = dir.path().join("other.obj");
        std::fs::write(&other, b"v 1 1 1\n").unwrap();
        let ((), outer) = recording_reads(|| {
            read_input(&file, 100, &scene, "mesh.file").unwrap();
            let ((), inner) = recording_reads(|| {
                read_input(&other, 100, &scene, "mesh.file").unwrap();
            });
            assert_eq!(inner, vec![other.clone()]);
            read_input(&file, 100, &scene, "mesh.file").unwrap();
        });
        assert_eq!(outer, vec![file.clone(), other.clone()]);
        // A scene's own file is named once (as the file of the error), not again in the message.
        let own = read_input(&scene, 100, &scene, "file").unwrap_err().to_string();
        assert_eq!(own.matches("scene.toml").count(), 1, "{own}");
        assert!(own.contains("file not found"), "{own}");
    }
}
