//! The traced steps report their progress to the process-wide stage (`shading::progress`) that
//! `lfr compare` draws with the time left, and end it when they return. One test in its own
//! binary: the stage is process-wide, so no other test may run a step beside it.

use shading::progress::{snapshot, Snapshot};
use tracer::samples::{lens_time, FieldSelection};
use tracer::{Accel, RenderSettings, Scene};

/// Runs `step` while another thread records every stage it sees.
fn watched<T>(step: impl FnOnce() -> T) -> (T, Vec<Snapshot>) {
    let finished = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|scope| {
        let watcher = scope.spawn(|| {
            let mut seen = Vec::new();
            while !finished.load(std::sync::atomic::Ordering::Relaxed) {
                seen.extend(snapshot());
                std::thread::sleep(std::time::Duration::from_micros(100));
            }
            seen
        });
        let result = step();
        finished.store(true, std::sync::atomic::Ordering::Relaxed);
        (result, watcher.join().expect("the watcher does not panic"))
    })
}

/// Every snapshot is of `stage` in `unit` out of `total`, its count never falls, and at least
/// one was seen part way.
fn check(seen: &[Snapshot], stage: &str, unit: &str, total: u64) {
    assert!(!seen.is_empty(), "no {stage} stage was seen");
    for s in seen {
        assert_eq!((s.stage, s.unit, s.total), (stage, unit, total), "{s:?}");
    }
    assert!(seen.windows(2).all(|w| w[0].done <= w[1].done), "{seen:?}");
    assert!(seen.iter().all(|s| s.done <= total));
    assert_eq!(snapshot(), None, "the stage ends with the step");
}

#[test]
fn render_and_dump_report_their_stage_and_end_it() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = Scene::load(&root.join("scenes/cornell.toml")).unwrap();
    let accel = Accel::build(&scene).unwrap();
    let settings =
        RenderSettings { width: 96, height: 80, spp: 8, seed: 1, max_bounces: 3, threads: 1, progress: false };

    let (frame, seen) = watched(|| tracer::render(&scene, &accel, &settings).unwrap());
    assert_eq!(frame.width, 96);
    // 16-pixel tiles: 6 across, 5 down.
    check(&seen, "render", "tiles", 30);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("samples.lfrs");
    let (report, seen) = watched(|| lens_time::dump(&scene, &accel, &settings, &FieldSelection::All, &path).unwrap());
    assert_eq!(report.samples, 96 * 80 * 8);
    check(&seen, "dump", "samples", 96 * 80 * 8);
}
