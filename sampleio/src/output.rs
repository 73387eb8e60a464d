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
