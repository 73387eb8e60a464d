//! Sample dumps: the tracer's samples written through `sampleio` for the reconstructions and
//! for external tools. One file per kind (`lens_time.rs`, ...); this module holds what every
//! kind shares: the camera block of the header and the streaming driver that traces pieces of
//! the image (runs of whole pixels, or a range of one pixel's samples when a pixel alone is too
//! big) in parallel, each worker encoding its piece and writing it at its place in the file
//! (`sampleio::PositionalWriter`), so that memory stays bounded by one piece per worker (at most
//! 64 K values, 256 KiB, whatever the size and spp) and the file is identical for any thread
//! count and any cut.

pub mod guide;
pub mod lens_time;
pub mod light;
pub mod secondary;
pub mod selection;

pub use selection::FieldSelection;

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;
use sampleio::{Durability, HeaderSpec, PositionalWriter};

use crate::accel::Accel;
use crate::camera::{Camera, FovAxis};
use crate::error::RenderError;
use crate::integrator::Integrator;
use crate::lights::LightSampler;
use crate::render::RenderSettings;
use crate::scene::Scene;

/// The path integrator the dumps share, at the dump's resolution and path length.
pub fn integrator<'a>(
    scene: &'a Scene,
    accel: &'a Accel,
    lights: &'a LightSampler,
    settings: &RenderSettings,
) -> Integrator<'a> {
    Integrator::new(scene, accel, lights, settings.max_bounces, settings.width, settings.height)
}

/// What a dump wrote.
#[derive(Clone, Debug)]
pub struct DumpReport {
    pub samples: u64,
    pub bytes: u64,
    pub record_size: usize,
    pub fields: Vec<String>,
    pub seconds: f64,
    /// Of `seconds`, the time of the parallel pass (tracing, encoding and writing the records);
    /// the rest went to the chunk table, syncing and renaming the file.
    pub trace_seconds: f64,
    /// Path contributions that were NaN or infinite and were dropped (`TracedRay::dropped`).
    pub dropped_contributions: u64,
}

impl DumpReport {
    pub fn bytes_per_sample(&self) -> f64 {
        self.bytes as f64 / self.samples.max(1) as f64
    }
}

fn to_f64(v: glam::Vec3) -> [f64; 3] {
    [v.x as f64, v.y as f64, v.z as f64]
}

/// The header's camera block: pose, projection, circle of confusion and the matrices between
/// pixels, camera space and world space (camera space: X right, Y down, Z forward).
pub fn camera_header(camera: &Camera, width: u32, height: u32) -> sampleio::Camera {
    let (focal, centre) = camera.pixel_projection(width, height);
    let (c1, c2) = camera.circle_of_confusion(width, height);
    let (fx, fy, cx, cy) = (focal.x as f64, focal.y as f64, centre.x as f64, centre.y as f64);
    let down = -camera.up;
    let p = camera.position;
    let row = |axis: glam::Vec3| [axis.x as f64, axis.y as f64, axis.z as f64, -(axis.dot(p) as f64)];
    sampleio::Camera {
        position: to_f64(camera.position),
        forward: to_f64(camera.forward),
        up: to_f64(camera.up),
        right: to_f64(camera.right),
        fov_deg: camera.fov_deg as f64,
        fov_axis: match camera.fov_axis {
            FovAxis::X => sampleio::FovAxis::X,
            FovAxis::Y => sampleio::FovAxis::Y,
            FovAxis::Smaller => sampleio::FovAxis::Smaller,
            FovAxis::Larger => sampleio::FovAxis::Larger,
        },
        aperture_radius: camera.aperture_radius as f64,
        focus_distance: camera.focus_distance as f64,
        coc: sampleio::Coc { c1: c1 as f64, c2: c2 as f64 },
        shutter: [camera.shutter[0] as f64, camera.shutter[1] as f64],
        pixel_to_camera: [
            [1.0 / fx, 0.0, -cx / fx, 0.0],
            [0.0, 1.0 / fy, -cy / fy, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        world_to_camera: [row(camera.right), row(down), row(camera.forward), [0.0, 0.0, 0.0, 1.0]],
    }
}

/// Writes samples of `kind` for `scene` to `target`, the fields `fields` selects: the one entry
/// point from a sample kind to its dump (`lfr dump`, `lfr compare`). With `soft_shadows`,
/// `lens-time` samples carry the soft-shadow reconstruction's shading fields
/// (`lens_time::dump_for_soft_shadows`); other kinds refuse it.
pub fn dump<'a>(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    kind: sampleio::SampleKind,
    soft_shadows: bool,
    fields: &FieldSelection,
    target: impl Into<DumpTarget<'a>>,
) -> Result<DumpReport, RenderError> {
    use sampleio::SampleKind;
    use secondary::SecondaryKind;
    match kind {
        SampleKind::LensTime if soft_shadows => {
            lens_time::dump_for_soft_shadows(scene, accel, settings, fields, target)
        }
        _ if soft_shadows => Err(RenderError::Settings(format!(
            "the soft-shadow fields belong to lens-time samples, not {}",
            kind.name()
        ))),
        SampleKind::LensTime => lens_time::dump(scene, accel, settings, fields, target),
        SampleKind::Light => light::dump(scene, accel, settings, fields, target),
        SampleKind::Indirect => secondary::dump(scene, accel, settings, SecondaryKind::Indirect, fields, target),
        SampleKind::Ao => secondary::dump(scene, accel, settings, SecondaryKind::AmbientOcclusion, fields, target),
    }
}

/// Where a dump goes and whether the file must outlive the process.
#[derive(Clone, Copy, Debug)]
pub struct DumpTarget<'a> {
    pub path: &'a Path,
    pub durability: Durability,
}

impl<'a> DumpTarget<'a> {
    /// A scratch file the same process reads back and removes (`lfr compare`'s inputs): not
    /// synced to disk, still renamed into place only once complete.
    pub fn scratch(path: &'a Path) -> DumpTarget<'a> {
        DumpTarget { path, durability: Durability::Unsynced }
    }
}

impl<'a> From<&'a Path> for DumpTarget<'a> {
    /// A file for later: synced to disk before the dump reports success.
    fn from(path: &'a Path) -> DumpTarget<'a> {
        DumpTarget { path, durability: Durability::Synced }
    }
}

impl<'a> From<&'a std::path::PathBuf> for DumpTarget<'a> {
    fn from(path: &'a std::path::PathBuf) -> DumpTarget<'a> {
        path.as_path().into()
    }
}

/// How the dump is cut into pieces: at most `piece_values` values per piece (several whole
/// pixels, or a range of one pixel's samples), and at least `pieces_per_thread` pieces per
/// worker where the image has enough pixels, so that the workers end together.
#[derive(Clone, Copy, Debug)]
struct Pieces {
    piece_values: usize,
    pieces_per_thread: usize,
}

/// At most about 256 KiB of values per piece (a worker's buffers stay in memory already
/// touched), at least 16 pieces per worker.
const PIECES: Pieces = Pieces { piece_values: 1 << 16, pieces_per_thread: 16 };

/// A worker's buffers, kept from piece to piece: the piece's values, then its encoded records.
#[derive(Default)]
struct PieceBuffers {
    values: Vec<f32>,
    /// The piece's selected values, record after record (only with a field selection).
    selected: Vec<f32>,
    records: Vec<u8>,
}

/// A piece: `pixels` whole pixels from `first_pixel` (row-major), or, when `pixels` is 1, the
/// samples `samples` of that pixel.
#[derive(Clone, Debug, PartialEq)]
struct Piece {
    first_pixel: u64,
    pixels: u64,
    samples: std::ops::Range<u32>,
}

impl Piece {
    /// The piece's first sample in file order.
    fn first_sample(&self, spp: u32) -> u64 {
        self.first_pixel * spp as u64 + self.samples.start as u64
    }
}

/// The pieces of a `pixel_count`-pixel image at `spp`, in file order.
fn pieces(pixel_count: u64, spp: u32, values_per_sample: usize, piece_values: usize) -> impl Iterator<Item = Piece> {
    let per_sample = values_per_sample.max(1) as u64;
    let per_pixel = spp as u64 * per_sample;
    let budget = piece_values.max(1) as u64;
    let pixels_per_piece = (budget / per_pixel.max(1)).max(1);
    let samples_per_piece = (budget / per_sample).clamp(1, spp.max(1) as u64) as u32;
    let whole_pixels = per_pixel <= budget;
    let mut pixel = 0u64;
    let mut sample = 0u32;
    std::iter::from_fn(move || {
        if pixel >= pixel_count {
            return None;
        }
        if whole_pixels {
            let pixels = pixels_per_piece.min(pixel_count - pixel);
            let piece = Piece { first_pixel: pixel, pixels, samples: 0..spp };
            pixel += pixels;
            return Some(piece);
        }
        let end = sample.saturating_add(samples_per_piece).min(spp);
        let piece = Piece { first_pixel: pixel, pixels: 1, samples: sample..end };
        if end == spp {
            (pixel, sample) = (pixel + 1, 0);
        } else {
            sample = end;
        }
        Some(piece)
    })
}

/// The values per piece for an image of `total_values` values on `threads` workers: `cut`'s
/// cap, lowered so that each worker gets `cut.pieces_per_thread` pieces (at least one value).
fn piece_values(total_values: u64, threads: usize, cut: Pieces) -> usize {
    let wanted = (threads.max(1) * cut.pieces_per_thread.max(1)) as u64;
    (total_values.div_ceil(wanted).max(1)).min(cut.piece_values.max(1) as u64) as usize
}

/// Traces every pixel's samples with `sample_pixel` (which appends the records of the given
/// sample indices, `values_per_sample` values each, for pixel (x, y), every field of `spec`) in
/// parallel pieces, each encoded and written at its place in `target`'s file by the worker
/// that traced it, keeping the fields `fields` selects. The file is the same, byte for byte,
/// for any thread count and any cut.
pub fn write_samples<'a, F>(
    target: impl Into<DumpTarget<'a>>,
    spec: HeaderSpec,
    fields: &FieldSelection,
    settings: &RenderSettings,
    values_per_sample: usize,
    sample_pixel: F,
) -> Result<DumpReport, RenderError>
where
    F: Fn(u32, u32, std::ops::Range<u32>, &mut Vec<f32>) + Sync,
{
    write_samples_in(target.into(), spec, fields, settings, values_per_sample, sample_pixel, PIECES)
}

fn write_samples_in<F>(
    target: DumpTarget,
    spec: HeaderSpec,
    fields: &FieldSelection,
    settings: &RenderSettings,
    values_per_sample: usize,
    sample_pixel: F,
    cut: Pieces,
) -> Result<DumpReport, RenderError>
where
    F: Fn(u32, u32, std::ops::Range<u32>, &mut Vec<f32>) + Sync,
{
    settings.validate()?;
    let path = target.path;
    let (spec, selected_ranges) = fields.apply(spec)?;
    let output_error =
        |e: sampleio::SampleError| RenderError::Output { path: path.to_path_buf(), message: e.to_string() };
    let writer = PositionalWriter::create(path, spec).map_err(output_error)?;
    let header = writer.header().clone();
    let record_size = header.record_size as usize;
    let fields = header.fields.iter().map(|f| f.name.clone()).collect();
    let pool = crate::render::thread_pool(settings.threads)?;
    let pixel_count = settings.width as u64 * settings.height as u64;
    let spp = settings.spp;
    let bar = crate::progress::StepProgress::begin(settings.progress, "dump", pixel_count * spp as u64, "samples");
    let start = Instant::now();
    let width = settings.width as u64;
    let total_values = pixel_count * spp as u64 * values_per_sample as u64;
    let piece_values = piece_values(total_values, pool.current_num_threads(), cut);
    let all: Vec<Piece> = pieces(pixel_count, spp, values_per_sample, piece_values).collect();
    // The first failing piece in file order; pieces after it are skipped, those before it still
    // run, so the error reported is the same whatever the threads' timing.
    let first_failure = std::sync::atomic::AtomicUsize::new(usize::MAX);
    let failures: std::sync::Mutex<Vec<(usize, sampleio::SampleError)>> = Default::default();
    let trace = |slot: &mut PieceBuffers, piece: &Piece| -> Result<(), sampleio::SampleError> {
        let size = piece.pixels as usize * piece.samples.len() * values_per_sample;
        slot.values.clear();
        slot.values.reserve(size);
        for pixel in piece.first_pixel..piece.first_pixel + piece.pixels {
            sample_pixel((pixel % width) as u32, (pixel / width) as u32, piece.samples.clone(), &mut slot.values);
        }
        debug_assert_eq!(slot.values.len(), size);
        let count = size / values_per_sample.max(1);
        slot.records.clear();
        slot.records.resize(count * record_size, 0);
        let first_sample = piece.first_sample(spp);
        let encoded = match &selected_ranges {
            None => &slot.values,
            Some(ranges) => {
                slot.selected.clear();
                for values in slot.values.chunks_exact(values_per_sample.max(1)) {
                    for range in ranges {
                        slot.selected.extend_from_slice(&values[range.clone()]);
                    }
                }
                &slot.selected
            }
        };
        sampleio::encode_records(&header, encoded, &mut slot.records)
            .map_err(|(at, bad)| bad.at(path, first_sample + at as u64))?;
        writer.write_records_at(first_sample, &slot.records)?;
        bar.advance(count as u64);
        Ok(())
    };
    // One set of buffers per worker, reused for all its pieces (fresh memory per piece costs
    // page faults); a worker only ever locks its own.
    let slots: Vec<std::sync::Mutex<PieceBuffers>> =
        (0..pool.current_num_threads()).map(|_| Default::default()).collect();
    pool.install(|| {
        all.par_iter().enumerate().for_each(|(index, piece)| {
            if index > first_failure.load(std::sync::atomic::Ordering::Relaxed) {
                return;
            }
            let worker = rayon::current_thread_index().unwrap_or(0) % slots.len();
            let mut slot = slots[worker].lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            if let Err(error) = trace(&mut slot, piece) {
                first_failure.fetch_min(index, std::sync::atomic::Ordering::Relaxed);
                failures.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).push((index, error));
            }
        })
    });
    let trace_seconds = start.elapsed().as_secs_f64();
    let failures = failures.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((_, error)) = failures.into_iter().min_by_key(|(index, _)| *index) {
        return Err(output_error(error));
    }
    let final_path = writer.finish(target.durability).map_err(output_error)?;
    bar.finish();
    let bytes = std::fs::metadata(&final_path).map(|m| m.len()).unwrap_or(0);
    let seconds = start.elapsed().as_secs_f64();
    let samples = pixel_count * spp as u64;
    Ok(DumpReport { samples, bytes, record_size, fields, seconds, trace_seconds, dropped_contributions: 0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, SampleKind};

    /// Every (pixel, sample) once, in file order, and no piece over the budget unless it is a
    /// single sample.
    #[test]
    fn pieces_cover_every_sample_once_in_order_within_the_budget() {
        for (pixels, spp, per_sample, budget) in [
            (1, 1, 3, 1),
            (7, 5, 3, 4),
            (7, 5, 3, 15),
            (7, 5, 3, 16),
            (3, 1000, 2, 64),
            (10, 3, 1, 1 << 20),
            (0, 4, 2, 8),
        ] {
            let mut expected = (0..pixels).flat_map(|p| (0..spp).map(move |s| (p, s)));
            for piece in pieces(pixels, spp, per_sample, budget) {
                let values = piece.pixels as usize * piece.samples.len() * per_sample;
                assert!(values <= budget.max(per_sample), "{piece:?} over {budget}");
                assert!(piece.pixels == 1 || piece.samples == (0..spp), "{piece:?}");
                for p in piece.first_pixel..piece.first_pixel + piece.pixels {
                    for s in piece.samples.clone() {
                        assert_eq!(expected.next(), Some((p, s)), "{pixels} {spp} {per_sample} {budget}");
                    }
                }
            }
            assert_eq!(expected.next(), None);
        }
    }

    /// The settings of the writer tests: 5x3 pixels at 7 spp on two threads.
    fn five_by_three_at_7_spp() -> RenderSettings {
        RenderSettings { width: 5, height: 3, spp: 7, seed: 1, max_bounces: 1, threads: 2, progress: false }
    }

    /// A 5x3, 7-spp header with the film position and then `third`.
    fn xy_and(third: FieldSpec) -> HeaderSpec {
        HeaderSpec::new(SampleKind::Ao, 5, 3, 7).field(FieldSpec::new("xy", FieldType::F32, 2)).field(third)
    }

    /// Tiny pieces, one to three threads and a scratch target write the same file, byte for
    /// byte, as the defaults: the file the streaming writer gives for the same records pushed
    /// in pixel-major order.
    #[test]
    fn the_file_does_not_depend_on_how_it_is_cut_or_on_the_threads() {
        let dir = tempfile::tempdir().unwrap();
        let settings = five_by_three_at_7_spp();
        let spec = || xy_and(FieldSpec::new("index", FieldType::F32, 1));
        let sample_pixel = |x: u32, y: u32, samples: std::ops::Range<u32>, out: &mut Vec<f32>| {
            for s in samples {
                out.extend_from_slice(&[x as f32 + 0.25, y as f32 + 0.5, s as f32]);
            }
        };
        let streamed = dir.path().join("streamed.lfrs");
        let mut writer = sampleio::SampleWriter::create(&streamed, spec()).unwrap();
        for (y, x, s) in (0..3).flat_map(|y| (0..5).flat_map(move |x| (0..7).map(move |s| (y, x, s)))) {
            writer.push(&[x as f32 + 0.25, y as f32 + 0.5, s as f32]).unwrap();
        }
        writer.finish().unwrap();
        let expected = std::fs::read(&streamed).unwrap();
        let whole = dir.path().join("whole.lfrs");
        write_samples(&whole, spec(), &FieldSelection::All, &settings, 3, sample_pixel).unwrap();
        assert_eq!(std::fs::read(&whole).unwrap(), expected);
        for threads in [1, 2, 3] {
            for cut in [
                PIECES,
                Pieces { piece_values: 6, pieces_per_thread: 1 },
                Pieces { piece_values: 1, pieces_per_thread: 1 },
            ] {
                let path = dir.path().join(format!("cut-{threads}-{}.lfrs", cut.piece_values));
                let settings = RenderSettings { threads, ..settings.clone() };
                write_samples_in(
                    DumpTarget::scratch(&path),
                    spec(),
                    &FieldSelection::All,
                    &settings,
                    3,
                    sample_pixel,
                    cut,
                )
                .unwrap();
                assert_eq!(std::fs::read(&path).unwrap(), expected, "{threads} threads, {cut:?}");
            }
        }
        let file = sampleio::SampleFile::open(&whole).unwrap();
        assert_eq!(file.len(), 5 * 3 * 7);
    }

    /// Pieces shrink so that every worker gets its share, never below one value, never above
    /// the cap.
    #[test]
    fn pieces_shrink_to_give_every_worker_its_share() {
        assert_eq!(piece_values(1 << 30, 2, PIECES), PIECES.piece_values);
        assert_eq!(piece_values(3200, 2, PIECES), 100);
        assert_eq!(piece_values(3201, 2, PIECES), 101);
        assert_eq!(piece_values(5, 4, PIECES), 1);
        assert_eq!(piece_values(0, 0, PIECES), 1);
    }

    /// A value its field cannot hold, traced while earlier batches are being written: the
    /// error names the file, the field and the sample in file order, and no file is left.
    #[test]
    fn a_value_no_field_can_hold_is_an_error_naming_its_sample_and_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let settings = five_by_three_at_7_spp();
        let spec = || xy_and(FieldSpec::new("count", FieldType::U8, 1));
        // Pixel (3, 2) is pixel 13; its sample 4 is sample 13 * 7 + 4 = 95 of the file.
        let sample_pixel = |x: u32, y: u32, samples: std::ops::Range<u32>, out: &mut Vec<f32>| {
            for s in samples {
                let count = if (x, y, s) == (3, 2, 4) { 300.0 } else { s as f32 };
                out.extend_from_slice(&[x as f32, y as f32, count]);
            }
        };
        for cut in [PIECES, Pieces { piece_values: 6, pieces_per_thread: 1 }] {
            let path = dir.path().join("bad.lfrs");
            let error = write_samples_in((&path).into(), spec(), &FieldSelection::All, &settings, 3, sample_pixel, cut)
                .unwrap_err()
                .to_string();
            assert!(error.contains("bad.lfrs") && error.contains("count") && error.contains("95"), "{error}");
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no file and no temporary left");
        }
    }
}
