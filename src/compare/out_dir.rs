//! The output folder of a comparison: a rerun into the same `--out` must not leave the previous
//! run's images beside the new `results.json`, and a killed run must not leave an old
//! `results.json` beside new images. Before anything is traced, the files a comparison writes
//! are removed from `--out` (`results.json` first); a folder that holds anything else is refused
//! unless `--force`, and then only the comparison's own files are removed.

use std::path::Path;

use anyhow::{bail, Context, Result};

/// What `lfr compare` writes into `--out`, `results.json` first.
pub const WRITTEN: [&str; 7] =
    ["results.json", "report.md", "report.html", "error-vs-time.png", "error-vs-time.svg", "images", "inputs"];

/// Whether `name` is one of [`WRITTEN`] or the temporary file of one (`NAME.<pid>.tmp`, left by a
/// killed run).
fn is_ours(name: &str) -> bool {
    let base = match name.strip_suffix(".tmp").and_then(|rest| rest.rsplit_once('.')) {
        Some((base, pid)) if !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()) => base,
        _ => name,
    };
    WRITTEN.contains(&base)
}

/// Makes `dir` an empty comparison folder (see the module doc). Returns how many previous
/// entries were removed.
pub fn prepare(dir: &Path, force: bool) -> Result<usize> {
    // A symbolic link to a folder is that folder.
    match std::fs::metadata(dir) {
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => {
            // By its components: `create_dir_all` cannot make `new/.` (its parent reads as "").
            let folder: std::path::PathBuf = dir.components().collect();
            std::fs::create_dir_all(&folder).with_context(|| format!("--out: creating {}", dir.display()))?;
            return Ok(0);
        }
        Err(error) => bail!("--out {}: {error}", dir.display()),
        Ok(meta) if !meta.is_dir() => bail!("--out {}: not a directory", dir.display()),
        Ok(_) => {}
    }
    let mut ours = Vec::new();
    let mut foreign = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("--out: reading {}", dir.display()))? {
        let entry = entry.with_context(|| format!("--out: reading {}", dir.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if is_ours(&name) {
            ours.push(name);
        } else {
            foreign.push(name);
        }
    }
    if !foreign.is_empty() && !force {
        foreign.sort();
        let shown: Vec<&str> = foreign.iter().take(5).map(String::as_str).collect();
        bail!(
            "--out {}: the folder holds files that are not a comparison's ({}{}); choose an empty or new folder, \
             or pass --force to keep them and replace only the comparison's own files",
            dir.display(),
            shown.join(", "),
            if foreign.len() > shown.len() { ", …" } else { "" }
        );
    }
    // results.json first: a run killed while clearing never leaves it beside other images.
    ours.sort_by_key(|name| (name != "results.json", name.clone()));
    for name in &ours {
        let path = dir.join(name);
        let removed = match std::fs::symlink_metadata(&path) {
            Ok(meta) if meta.is_dir() => std::fs::remove_dir_all(&path),
            Ok(_) => std::fs::remove_file(&path),
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(error) => Err(error),
        };
        removed.with_context(|| format!("--out: removing the previous run's {}", path.display()))?;
    }
    Ok(ours.len())
}

/// Prepares `dir` for a comparison ([`prepare`]), says what it removed, and creates its
/// `images` folder.
pub fn open(dir: &Path, force: bool) -> Result<()> {
    let cleared = prepare(dir, force)?;
    if cleared > 0 {
        eprintln!("compare: removed the previous comparison's {cleared} files and folders from {}", dir.display());
    }
    std::fs::create_dir_all(dir.join("images")).with_context(|| format!("creating {}", dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn our_names_and_their_temporaries_are_recognised() {
        assert!(is_ours("results.json") && is_ours("images") && is_ours("report.html"));
        assert!(is_ours("results.json.4711.tmp") && is_ours("report.md.1.tmp"));
        assert!(!is_ours("results.json.tmp") && !is_ours("results.json.x1.tmp") && !is_ours("notes.txt"));
        assert!(!is_ours("my-images"));
    }

    #[test]
    fn a_previous_run_is_cleared_and_a_foreign_folder_refused() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        assert_eq!(prepare(&out, false).unwrap(), 0);
        assert!(out.is_dir());
        std::fs::create_dir_all(out.join("images")).unwrap();
        std::fs::write(out.join("images/old-method-4spp.png"), b"x").unwrap();
        std::fs::write(out.join("results.json"), b"{}").unwrap();
        std::fs::write(out.join("report.md.123.tmp"), b"half").unwrap();
        assert_eq!(prepare(&out, false).unwrap(), 3);
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0);

        std::fs::write(out.join("results.json"), b"{}").unwrap();
        std::fs::write(out.join("thesis.tex"), b"mine").unwrap();
        let error = format!("{:#}", prepare(&out, false).unwrap_err());
        assert!(error.contains("thesis.tex") && error.contains("--force"), "{error}");
        assert!(out.join("results.json").exists(), "nothing removed on refusal");
        assert_eq!(prepare(&out, true).unwrap(), 1);
        assert!(out.join("thesis.tex").exists() && !out.join("results.json").exists());
    }

    #[test]
    fn a_new_folder_spelled_with_a_trailing_dot_or_slash_is_made() {
        let dir = tempfile::tempdir().unwrap();
        for (spelled, made) in [("a/.", "a"), ("b/", "b"), ("c/d/./", "c/d"), ("e/f/..", "e")] {
            assert_eq!(prepare(&dir.path().join(spelled), false).unwrap(), 0, "{spelled}");
            assert!(dir.path().join(made).is_dir(), "{spelled}");
        }
    }

    #[test]
    fn a_file_is_not_a_folder() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f");
        std::fs::write(&file, b"x").unwrap();
        let error = format!("{:#}", prepare(&file, true).unwrap_err());
        assert!(error.contains("not a directory"), "{error}");
    }
}
