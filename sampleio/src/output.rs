//! Where an output may go. Every file lfr writes is first written to a temporary file beside
//! its target and renamed onto it, which would replace whatever the target is: a device node
//! such as `/dev/null` (as root, for every user), a symbolic link, or one of the command's own
//! inputs. `check_output_target` refuses those before any work starts; the sample writer and
//! the tracer's image writer call it, and the commands call it with their inputs.

use std::path::Path;

use crate::error::{Result, SampleError};

/// Checks that `path` may be replaced by an output: it does not exist yet, or it is a regular
/// file (not a directory, device, FIFO, socket or symbolic link) and none of `inputs` (the same
/// file by device and inode, whatever path names it).
pub fn check_output_target(path: &Path, inputs: &[&Path]) -> Result<()> {
    let refuse = |reason: String| Err(SampleError::RefusedOutput { path: path.to_path_buf(), reason });
    let metadata = match std::fs::symlink_metadata(path) {
        Ok(metadata) => metadata,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(SampleError::io(path, "inspect", e)),
    };
    let kind = metadata.file_type();
    if kind.is_symlink() {
        return refuse("it is a symbolic link, which the output would replace; name its target instead".into());
    }
    if !kind.is_file() {
        return refuse(format!("it is {}, not a regular file", describe(&kind)));
    }
    for input in inputs {
        if same_file(&metadata, input) {
            return refuse(format!("it is the input {}", input.display()));
        }
    }
    Ok(())
}

/// Bytes free to an unprivileged writer on the file system that holds `dir`
/// (`statvfs`: available blocks × fragment size); `LFR_FREE_SPACE` (bytes) replaces the
/// measurement, for tests. `None` where it cannot be measured.
pub fn free_space(dir: &Path) -> Option<u64> {
    if let Some(given) = std::env::var("LFR_FREE_SPACE").ok().and_then(|v| v.trim().parse::<u64>().ok()) {
        return Some(given);
    }
    #[cfg(unix)]
    {
        let stat = nix::sys::statvfs::statvfs(dir).ok()?;
        Some((stat.blocks_available() as u64).saturating_mul(stat.fragment_size() as u64))
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        None
    }
}

/// Refuses, before any work, an output of about `bytes` bytes that the free space of its file
/// system ([`free_space`] of the folder `path` goes to) cannot hold; `what` says what the file
/// is in the message. Passes where the space cannot be measured.
pub fn check_free_space(path: &Path, bytes: u64, what: &str) -> Result<()> {
    // The nearest folder that exists: those missing are created on the same file system.
    let folder = path
        .ancestors()
        .skip(1)
        .find(|folder| !folder.as_os_str().is_empty() && folder.exists())
        .unwrap_or(Path::new("."));
    match free_space(folder) {
        Some(free) if bytes > free => Err(SampleError::RefusedOutput {
            path: path.to_path_buf(),
            reason: format!(
                "{what} would take about {} and its file system has {} free",
                human_bytes(bytes),
                human_bytes(free)
            ),
        }),
        _ => Ok(()),
    }
}

/// `bytes` in the largest binary unit that keeps it at least 1, one decimal.
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

fn describe(kind: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_char_device() {
            return "a character device";
        }
        if kind.is_block_device() {
            return "a block device";
        }
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// Whether `other` names the file `metadata` describes (following links, as reading it would).
fn same_file(metadata: &std::fs::Metadata, other: &Path) -> bool {
    let Ok(other) = std::fs::metadata(other) else { return false };
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        metadata.dev() == other.dev() && metadata.ino() == other.ino()
    }
    #[cfg(not(unix))]
    {
        metadata.len() == other.len() && metadata.modified().ok() == other.modified().ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_larger_than_the_free_space_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.lfrs");
        let free = free_space(dir.path()).expect("statvfs answers for a temporary folder");
        assert!(check_free_space(&path, 1, "the file").is_ok());
        let message = check_free_space(&path, free.saturating_add(1 << 30), "the sample file").unwrap_err().to_string();
        assert!(message.contains("big.lfrs") && message.contains("the sample file would take about"), "{message}");
        assert_eq!(human_bytes(1023), "1023 B");
        assert_eq!(human_bytes(3 << 40), "3.0 TiB");
    }

    #[test]
    fn new_and_regular_files_pass_special_files_and_inputs_do_not() {
        let dir = tempfile::tempdir().unwrap();
        let new = dir.path().join("new.lfrs");
        assert!(check_output_target(&new, &[]).is_ok());
        let regular = dir.path().join("old.lfrs");
        std::fs::write(&regular, b"x").unwrap();
        assert!(check_output_target(&regular, &[]).is_ok());
        let message = check_output_target(dir.path(), &[]).unwrap_err().to_string();
        assert!(message.contains("a directory") && message.contains("refusing"), "{message}");
        let input = dir.path().join("scene.toml");
        std::fs::write(&input, b"[render]").unwrap();
        let message = check_output_target(&input, &[&input]).unwrap_err().to_string();
        assert!(message.contains("the input"), "{message}");
        #[cfg(unix)]
        {
            // The same input by another name: a hard link.
            let alias = dir.path().join("alias.toml");
            std::fs::hard_link(&input, &alias).unwrap();
            assert!(check_output_target(&alias, &[&input]).unwrap_err().to_string().contains("the input"));
            let link = dir.path().join("link.exr");
            std::os::unix::fs::symlink(&regular, &link).unwrap();
            let message = check_output_target(&link, &[]).unwrap_err().to_string();
            assert!(message.contains("symbolic link"), "{message}");
            let fifo = dir.path().join("fifo.exr");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                let message = check_output_target(&fifo, &[]).unwrap_err().to_string();
                assert!(message.contains("a FIFO"), "{message}");
            }
        }
    }
}
