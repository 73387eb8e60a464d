//! Every size lfr accepts, in one place: the tracer's settings check them, scene files are
//! held to the same resolution, and the command line's other limits (the comparison's) are
//! named here too so that no second copy of a number can drift.

/// Largest image width or height (a render needs about 320 bytes a pixel: 32768² is ~340 GB,
/// beyond any machine; the memory check before tracing refuses what this one cannot hold).
pub const MAX_IMAGE_SIDE: u32 = 1 << 15;

/// Most samples per pixel of a render or a sample dump.
pub const MAX_SPP: u32 = 1 << 20;

/// Most worker threads: more than any machine has cores, few enough that starting them is
/// quick (`--threads 10000` spent most of a 16×16 render creating threads).
pub const MAX_THREADS: usize = 1024;

/// Largest width or height of a comparison (`lfr compare`), which holds a reference, a
/// path-tracing ladder and every method's image at once.
pub const MAX_COMPARE_SIDE: u32 = 1 << 14;

/// Most input samples per pixel of a comparison's methods and of its path-tracing ladder.
pub const MAX_COMPARE_SPP: u32 = 1 << 16;

/// Most reconstruction locations (or rays) per pixel.
pub const MAX_RECON_RAYS: u32 = 1 << 16;

/// Largest scene description (TOML) read, in bytes.
pub const MAX_SCENE_TEXT_BYTES: u64 = 64 << 20;

/// Largest model file (OBJ, MTL, glTF, GLB or a glTF buffer) or texture read, in bytes: a
/// bound so that a device such as /dev/zero named as an input is an error, not a read until
/// memory runs out.
pub const MAX_MODEL_BYTES: u64 = 8 << 30;
