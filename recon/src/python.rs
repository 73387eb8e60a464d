//! A small bridge to Python for methods and metrics whose reference implementation is a Python
//! package (Intel Open Image Denoise through `pyoidn`, HDR-FLIP through `flip_evaluator`).
//!
//! The interpreter is `$LFR_PYTHON` when set, else `python3` on the `PATH`. A script is embedded
//! in the Rust code with `include_str!`, written into a caller-owned directory (a
//! `tempfile::TempDir` per call site) and run with its JSON arguments as `argv[1]`; it answers
//! with a JSON object on the last line of its stdout. Images travel as raw little-endian `f32`
//! RGB files, row-major from the top-left, which the Python side reads with
//! `numpy.fromfile(path, dtype="<f4").reshape(height, width, 3)`.

use std::collections::HashMap;
use std::fs;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{Mutex, OnceLock};

use crate::error::Error;
use crate::image::Image;

/// The environment variable naming the Python interpreter.
pub const PYTHON_ENV: &str = "LFR_PYTHON";

/// Name of the file a script is written to inside the caller's directory.
const SCRIPT_FILE: &str = "lfr_script.py";

/// At most this many characters of a failed script's stderr (its tail) go into the error.
const MAX_STDERR_CHARS: usize = 4000;

/// The interpreter to run: `$LFR_PYTHON` when set and non-empty, else `python3`.
pub fn interpreter() -> String {
    match std::env::var(PYTHON_ENV) {
        Ok(python) if !python.trim().is_empty() => python,
        _ => "python3".to_string(),
    }
}

/// The `pip install` line for a module (the distribution name where it differs).
pub fn install_hint(module: &str) -> String {
    let package = match module {
        "flip_evaluator" => "flip-evaluator".to_string(),
        other => other.split('.').next().unwrap_or(other).replace('_', "-"),
    };
    format!("pip install {package}")
}

/// Per (interpreter, module): why the import fails, `None` when it succeeds.
type AvailabilityCache = HashMap<(String, String), Option<String>>;

/// `Ok` when the interpreter (`interpreter()`) can import `module`; otherwise what is missing
/// and how to install it. Cached per interpreter and module for the life of the process.
pub fn module_available(module: &str) -> Result<(), Error> {
    static CACHE: OnceLock<Mutex<AvailabilityCache>> = OnceLock::new();
    check_module_name(module)?;
    let python = interpreter();
    let key = (python.clone(), module.to_string());
    // The lock is held across the check so that concurrent callers run it once.
    let mut cache = CACHE.get_or_init(|| Mutex::new(HashMap::new())).lock().unwrap_or_else(|e| e.into_inner());
    match cache.entry(key).or_insert_with(|| import_failure(&python, module)) {
        None => Ok(()),
        Some(message) => Err(Error::python(python, message.clone())),
    }
}

/// `Ok` when `python` can import `module`; uncached, and independent of `$LFR_PYTHON`.
pub fn module_available_with(python: &str, module: &str) -> Result<(), Error> {
    check_module_name(module)?;
    match import_failure(python, module) {
        None => Ok(()),
        Some(message) => Err(Error::python(python, message)),
    }
}

/// `Ok` when `module` is a dotted Python module name (so that it is safe to hand to `python`).
fn check_module_name(module: &str) -> Result<(), Error> {
    let valid = !module.is_empty()
        && module.split('.').all(|part| {
            !part.is_empty()
                && !part.starts_with(|c: char| c.is_ascii_digit())
                && part.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        });
    if valid {
        Ok(())
    } else {
        Err(Error::parameter("module", format!("`{module}` is not a Python module name")))
    }
}

/// Why `python` cannot import `module` (a valid module name): the interpreter does not run, or
/// the import fails, with how to install the module; `None` when the import succeeds.
fn import_failure(python: &str, module: &str) -> Option<String> {
    let output = match Command::new(python)
        .args(["-c", "import importlib, sys; importlib.import_module(sys.argv[1])", module])
        .stdin(Stdio::null())
        .output()
    {
        Ok(output) => output,
        Err(e) => {
            return Some(format!(
                "cannot run the Python interpreter `{python}` to import `{module}`: {e} \
                 (set {PYTHON_ENV} to a Python 3 interpreter)"
            ))
        }
    };
    if output.status.success() {
        return None;
    }
    let stderr = String::from_utf8_lossy(&output.stderr);
    let reason = stderr.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("").trim();
    let reason = if reason.is_empty() { format!("import exited with {}", output.status) } else { reason.to_string() };
    Some(format!(
        "Python module `{module}` cannot be imported by `{python}` ({reason}); install it with `{}` \
         or set {PYTHON_ENV} to an interpreter that has it",
        install_hint(module)
    ))
}

/// Writes `script` into `dir`, runs it with `interpreter()` and `args` (JSON) as `argv[1]`, and
/// returns the JSON object on the last non-empty line of its stdout. A non-zero exit, or a
/// last line that is not a JSON object, is an error carrying the script's (trimmed) stderr.
pub fn run_script(script: &str, args: &serde_json::Value, dir: &Path) -> Result<serde_json::Value, Error> {
    run_script_with(&interpreter(), script, args, dir)
}

/// `run_script` with an explicit interpreter.
pub fn run_script_with(
    python: &str,
    script: &str,
    args: &serde_json::Value,
    dir: &Path,
) -> Result<serde_json::Value, Error> {
    let path = dir.join(SCRIPT_FILE);
    fs::write(&path, script).map_err(|source| Error::Io { path: path.clone(), op: "write Python script", source })?;
    let output = Command::new(python)
        .arg(&path)
        .arg(args.to_string())
        .current_dir(dir)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .stdin(Stdio::null())
        .output()
        .map_err(|e| {
            Error::python(
                python,
                format!(
                    "cannot run the Python interpreter `{python}` on {}: {e} (set {PYTHON_ENV} to a Python 3 \
                     interpreter)",
                    path.display()
                ),
            )
        })?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        // Some native libraries report on stdout before exiting; show it when stderr is silent.
        let detail = if stderr.trim().is_empty() { tail(stdout.trim()) } else { tail(stderr.trim()) };
        let message = format!("Python script {} ({python}) failed with {}: {detail}", path.display(), output.status);
        return Err(Error::python(python, message));
    }
    let last = stdout.lines().rev().map(str::trim).find(|l| !l.is_empty()).unwrap_or("");
    match serde_json::from_str::<serde_json::Value>(last) {
        Ok(value) if value.is_object() => Ok(value),
        _ => Err(Error::python(
            python,
            format!(
                "Python script {} ({python}) did not print a JSON object on its last line of output; \
                 last line: {last:?}; stderr: {}",
                path.display(),
                tail(stderr.trim())
            ),
        )),
    }
}

/// The last `MAX_STDERR_CHARS` characters of `text`.
fn tail(text: &str) -> &str {
    match text.char_indices().rev().nth(MAX_STDERR_CHARS) {
        Some((index, _)) => &text[index..],
        None => text,
    }
}

/// Writes `image` as raw little-endian `f32` RGB, row-major from the top-left.
pub fn write_image_f32(path: &Path, image: &Image) -> Result<(), Error> {
    let mut bytes = Vec::with_capacity(image.pixels.len() * 12);
    for pixel in &image.pixels {
        for channel in pixel {
            bytes.extend_from_slice(&channel.to_le_bytes());
        }
    }
    fs::write(path, bytes).map_err(|source| Error::Io { path: path.to_path_buf(), op: "write image", source })
}

/// Reads a raw little-endian `f32` RGB image of `width` x `height`; the file must hold exactly
/// `width * height * 12` bytes.
pub fn read_image_f32(path: &Path, width: u32, height: u32) -> Result<Image, Error> {
    let bytes = fs::read(path).map_err(|source| Error::Io { path: path.to_path_buf(), op: "read image", source })?;
    let count = width as usize * height as usize;
    let expected = count * 12;
    if bytes.len() != expected {
        return Err(Error::size_mismatch(
            "image file",
            format!(
                "image {} has {} bytes, expected {expected} ({width}x{height} RGB f32)",
                path.display(),
                bytes.len()
            ),
        ));
    }
    let pixels = bytes
        .chunks_exact(12)
        .map(|p| {
            let channel = |i: usize| f32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
            [channel(0), channel(4), channel(8)]
        })
        .collect();
    Ok(Image::from_pixels(width, height, pixels))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `Some(reason)` when no working interpreter is available, in which case tests skip.
    fn no_python() -> Option<Error> {
        module_available("json").err()
    }

    #[test]
    fn failing_script_reports_its_stderr() {
        if let Some(reason) = no_python() {
            testkit::skip(&format!("no Python interpreter ({reason})"));
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let script = "import sys\nsys.stderr.write('boom\\n')\nsys.exit(1)\n";
        let error = run_script(script, &serde_json::json!({}), dir.path()).unwrap_err().to_string();
        assert!(error.contains("boom"), "{error}");
        assert!(error.contains(SCRIPT_FILE), "{error}");
    }

    #[test]
    fn script_arguments_and_result_round_trip() {
        if let Some(reason) = no_python() {
            testkit::skip(&format!("no Python interpreter ({reason})"));
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let script = "import json, sys\nargs = json.loads(sys.argv[1])\nprint('chatter')\n\
                      print(json.dumps({'sum': args['a'] + args['b'], 'name': args['name']}))\n";
        let args = serde_json::json!({"a": 2, "b": 40, "name": "é \"quoted\""});
        let value = run_script(script, &args, dir.path()).unwrap();
        assert_eq!(value["sum"], 42);
        assert_eq!(value["name"], "é \"quoted\"");

        let error = run_script("print('not json')\n", &args, dir.path()).unwrap_err().to_string();
        assert!(error.contains("JSON object"), "{error}");
    }

    #[test]
    fn images_round_trip_through_numpy_layout() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("image.f32");
        let mut image = Image::new(3, 2);
        image.set(2, 1, [1.5, -2.0, f32::INFINITY]);
        image.set(0, 0, [0.25, 0.5, 0.75]);
        write_image_f32(&path, &image).unwrap();
        assert_eq!(fs::metadata(&path).unwrap().len(), 3 * 2 * 12);
        assert_eq!(read_image_f32(&path, 3, 2).unwrap(), image);
        // The last pixel's last channel is the file's last four bytes.
        let bytes = fs::read(&path).unwrap();
        assert_eq!(&bytes[bytes.len() - 4..], &f32::INFINITY.to_le_bytes());
    }

    #[test]
    fn wrong_length_image_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.f32");
        fs::write(&path, [0u8; 20]).unwrap();
        let error = read_image_f32(&path, 2, 2).unwrap_err().to_string();
        assert!(error.contains(&path.display().to_string()), "{error}");
        assert!(error.contains("48"), "{error}");
        let missing = dir.path().join("missing.f32");
        let error = read_image_f32(&missing, 2, 2).unwrap_err().to_string();
        assert!(error.contains("missing.f32"), "{error}");
    }

    #[test]
    fn missing_interpreter_is_named() {
        let python = "/nonexistent/lfr-test-python3";
        let error = module_available_with(python, "pyoidn").unwrap_err().to_string();
        assert!(error.contains(python), "{error}");
        assert!(error.contains(PYTHON_ENV), "{error}");
        let dir = tempfile::tempdir().unwrap();
        let error = run_script_with(python, "print('{}')", &serde_json::json!({}), dir.path()).unwrap_err().to_string();
        assert!(error.contains(python), "{error}");
    }

    #[test]
    fn missing_module_names_the_module_and_how_to_install() {
        if let Some(reason) = no_python() {
            testkit::skip(&format!("no Python interpreter ({reason})"));
            return;
        }
        let module = "lfr_no_such_module_for_tests";
        let error = module_available_with(&interpreter(), module).unwrap_err().to_string();
        assert!(error.contains(module), "{error}");
        assert!(error.contains("pip install lfr-no-such-module-for-tests"), "{error}");
        assert!(module_available_with(&interpreter(), "os; import sys").is_err());
    }

    #[test]
    fn install_hints_use_distribution_names() {
        assert_eq!(install_hint("pyoidn"), "pip install pyoidn");
        assert_eq!(install_hint("flip_evaluator"), "pip install flip-evaluator");
        assert_eq!(install_hint("numpy"), "pip install numpy");
    }
}
