//! Temporary files to remove when the process is interrupted. Every output is written to a
//! temporary file beside its target and renamed onto it, so an interrupted command leaves no
//! half-written target; but without this registry it would leave the temporary file itself
//! (`NAME.<pid>.tmp`), a half-written sample dump, or a folder of intermediate files. Writers
//! register what they create ([`remove_on_interrupt`]; the registration ends when the returned
//! [`Registered`] is dropped), and the command's signal handler calls [`clean_up_and_exit`].
//!
//! This crate depends on nothing of ours, so the registry lives here, below every writer (the
//! sample writer here, the tracer's image writer, the reconstructions' helper processes and the
//! commands).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

static REGISTERED: Mutex<Vec<(u64, PathBuf)>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

/// A registration: the path is removed if the process is interrupted while this lives.
#[derive(Debug)]
#[must_use = "the registration ends when this is dropped"]
pub struct Registered {
    id: u64,
}

impl Drop for Registered {
    fn drop(&mut self) {
        let mut list = REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        list.retain(|(id, _)| *id != self.id);
    }
}

/// Registers `path` (a file or a folder, which need not exist yet) for removal on interrupt.
pub fn remove_on_interrupt(path: &Path) -> Registered {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    let mut list = REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    list.push((id, path.to_path_buf()));
    Registered { id }
}

/// The paths registered now, oldest first.
pub fn registered() -> Vec<PathBuf> {
    let list = REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    list.iter().map(|(_, path)| path.clone()).collect()
}

/// Removes every registered path that exists (newest first, so files go before the folders
/// that hold them); returns how many were removed.
fn remove_all(list: &[(u64, PathBuf)]) -> usize {
    let mut removed = 0;
    for (_, path) in list.iter().rev() {
        let gone = match std::fs::symlink_metadata(path) {
            Ok(meta) if meta.is_dir() => std::fs::remove_dir_all(path).is_ok(),
            Ok(_) => std::fs::remove_file(path).is_ok(),
            Err(_) => false,
        };
        removed += usize::from(gone);
    }
    removed
}

/// For a signal handler: removes every registered path, says so on standard error and exits
/// with `code`. The registry stays locked until the process is gone, so no writer can register
/// (and then create) another temporary file in between.
pub fn clean_up_and_exit(code: i32) -> ! {
    let list = REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let removed = remove_all(&list);
    eprintln!(
        "\ninterrupted: removed {removed} temporary file{} and folder{}; no output was half-written",
        if removed == 1 { "" } else { "s" },
        if removed == 1 { "" } else { "s" }
    );
    std::process::exit(code);
}

/// Removes the temporary files that killed processes left beside `target` (`NAME.<pid>.tmp`
/// whose process no longer runs: SIGKILL or a power cut give no chance to clean up); returns how
/// many. Only on systems with /proc, where a process's liveness can be read; elsewhere nothing
/// is removed.
pub fn remove_stale_temporaries(target: &Path) -> usize {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return 0;
    }
    let (Some(dir), Some(name)) = (target.parent(), target.file_name().and_then(|n| n.to_str())) else {
        return 0;
    };
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(pid) = file_name
            .to_str()
            .and_then(|n| n.strip_prefix(name))
            .and_then(|rest| rest.strip_prefix('.'))
            .and_then(|rest| rest.strip_suffix(".tmp"))
            .filter(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
        else {
            continue;
        };
        let alive = proc.join(pid).exists();
        if !alive && entry.file_type().is_ok_and(|t| t.is_file()) && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed_and_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("image.exr");
        // No process has a pid beyond the kernel's pid_max (at most 2^22).
        let dead = dir.path().join("image.exr.999999999.tmp");
        let live = dir.path().join(format!("image.exr.{}.tmp", std::process::id()));
        let other = dir.path().join("other.exr.999999999.tmp");
        let unrelated = dir.path().join("image.exr.notes.tmp");
        for path in [&dead, &live, &other, &unrelated] {
            std::fs::write(path, b"x").unwrap();
        }
        assert_eq!(remove_stale_temporaries(&target), 1);
        assert!(!dead.exists() && live.exists() && other.exists() && unrelated.exists());
    }

    #[test]
    fn registrations_end_when_dropped_and_removal_takes_files_and_folders() {
        let dir = tempfile::tempdir().unwrap();
        let (file, folder) = (dir.path().join("a.tmp"), dir.path().join("inputs"));
        std::fs::write(&file, b"x").unwrap();
        std::fs::create_dir_all(folder.join("deep")).unwrap();
        std::fs::write(folder.join("deep/s.lfrs"), b"x").unwrap();
        let kept = dir.path().join("kept");
        std::fs::write(&kept, b"x").unwrap();
        let a = remove_on_interrupt(&file);
        let b = remove_on_interrupt(&folder);
        {
            let _gone = remove_on_interrupt(&kept);
        }
        let now = registered();
        assert!(now.contains(&file) && now.contains(&folder) && !now.contains(&kept));
        let mine: Vec<(u64, PathBuf)> = vec![(a.id, file.clone()), (b.id, folder.clone())];
        assert_eq!(remove_all(&mine), 2);
        assert!(!file.exists() && !folder.exists() && kept.exists());
        // Removing what is already gone counts nothing and does not fail.
        assert_eq!(remove_all(&mine), 0);
        drop((a, b));
        assert!(!registered().contains(&file));
    }
}
