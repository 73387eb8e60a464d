//! Headers that claim absurd sizes are rejected from the claim alone (or from comparing it with
//! the file's length), without allocating anything of the claimed size. This binary counts the
//! largest single allocation, so it runs everything in one test.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use common::{small_header_value, with_header, write_small};
use sampleio::{SampleError, SampleFile};
use serde_json::json;

struct Tracking;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: delegates to the system allocator unchanged; only records the largest request.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: same contract as ours.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Tracking = Tracking;

/// What the edit should produce: `Invalid` naming this header key, or `Truncated`.
enum Want {
    Invalid(&'static str),
    Truncated,
}

#[test]
fn absurd_claims_are_rejected_without_allocating_them() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = write_small(dir.path(), "ok.lfrs");
    let path = dir.path().join("absurd.lfrs");

    let field = |name: &str, ty: &str, components: u64, offset: u64| json!({"name": name, "type": ty, "components": components, "offset": offset, "meaning": "", "unit": ""});
    let many: Vec<_> = (0..65).map(|i| field(&format!("f{i}"), "f32", 1, 4 * i)).collect();
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, Want)> = vec![
        ("sample_count 2^60", Box::new(|h| h["sample_count"] = json!(1u64 << 60)), Want::Invalid("sample_count")),
        ("sample_count u64::MAX", Box::new(|h| h["sample_count"] = json!(u64::MAX)), Want::Invalid("sample_count")),
        ("width 2^20", Box::new(|h| h["width"] = json!(1 << 20)), Want::Invalid("width")),
        ("width u32::MAX", Box::new(|h| h["width"] = json!(u32::MAX)), Want::Invalid("width")),
        ("width over u32", Box::new(|h| h["width"] = json!(1u64 << 40)), Want::Invalid("header")),
        ("height 0", Box::new(|h| h["height"] = json!(0)), Want::Invalid("height")),
        ("spp 2^21", Box::new(|h| h["spp"] = json!(1 << 21)), Want::Invalid("spp")),
        ("spp 0", Box::new(|h| h["spp"] = json!(0)), Want::Invalid("spp")),
        ("record_size mismatch", Box::new(|h| h["record_size"] = json!(28)), Want::Invalid("record_size")),
        ("record_size huge", Box::new(|h| h["record_size"] = json!(u32::MAX)), Want::Invalid("record_size")),
        ("components 5", Box::new(|h| h["fields"][0]["components"] = json!(5)), Want::Invalid("fields[0].components")),
        ("components 0", Box::new(|h| h["fields"][0]["components"] = json!(0)), Want::Invalid("fields[0].components")),
        ("duplicate names", Box::new(|h| h["fields"][1]["name"] = json!("x")), Want::Invalid("fields[1].name")),
        ("misaligned offset", Box::new(|h| h["fields"][0]["offset"] = json!(1)), Want::Invalid("fields[0].offset")),
        ("overlap", Box::new(|h| h["fields"][1]["offset"] = json!(2)), Want::Invalid("fields[1].offset")),
        (
            "offset past the record",
            Box::new(|h| h["fields"][4]["offset"] = json!(u32::MAX - 3)),
            Want::Invalid("fields[4].offset"),
        ),
        ("65 fields", Box::new(move |h| h["fields"] = json!(many.clone())), Want::Invalid("fields")),
        ("no fields", Box::new(|h| h["fields"] = json!([])), Want::Invalid("fields")),
        ("unknown type", Box::new(|h| h["fields"][0]["type"] = json!("f64")), Want::Invalid("header")),
        ("unknown key", Box::new(|h| h["colour"] = json!("red")), Want::Invalid("header")),
        (
            "missing key",
            Box::new(|h| {
                h.as_object_mut().unwrap().remove("spp");
            }),
            Want::Invalid("header"),
        ),
        ("order", Box::new(|h| h["order"] = json!("sample-major")), Want::Invalid("header")),
        ("format", Box::new(|h| h["format"] = json!("exr")), Want::Invalid("format")),
        ("chunk_samples 0", Box::new(|h| h["chunk_samples"] = json!(0)), Want::Invalid("chunk_samples")),
        // Consistent but enormous claims: only the file length can refute them.
        (
            "65536 x 65536 x 2^20 samples",
            Box::new(|h| {
                h["width"] = json!(65536);
                h["height"] = json!(65536);
                h["spp"] = json!(1 << 20);
                h["sample_count"] = json!(1u64 << 52);
                h["chunk_samples"] = json!(1);
            }),
            Want::Truncated,
        ),
        (
            "2^52 records of 2 KiB",
            Box::new(|h| {
                h["width"] = json!(65536);
                h["height"] = json!(65536);
                h["spp"] = json!(1 << 20);
                h["sample_count"] = json!(1u64 << 52);
                h["fields"][4]["offset"] = json!(2044);
                h["record_size"] = json!(2048);
            }),
            Want::Truncated,
        ),
        (
            "sample_count * record_size overflows",
            Box::new(|h| {
                h["width"] = json!(65536);
                h["height"] = json!(65536);
                h["spp"] = json!(1 << 20);
                h["sample_count"] = json!(1u64 << 52);
                h["fields"][4]["offset"] = json!(65532);
                h["record_size"] = json!(65536);
            }),
            Want::Invalid("sample_count"),
        ),
    ];

    for (name, edit, want) in cases {
        let mut h = small_header_value(&bytes);
        edit(&mut h);
        std::fs::write(&path, with_header(&bytes, &h)).unwrap();
        LARGEST.store(0, Ordering::Relaxed);
        let result = SampleFile::open(&path);
        let largest = LARGEST.load(Ordering::Relaxed);
        match (&result, &want) {
            (Err(SampleError::Invalid { field, .. }), Want::Invalid(key)) => assert_eq!(field, key, "{name}"),
            (Err(SampleError::Truncated { .. }), Want::Truncated) => {}
            _ => panic!("{name}: unexpected {result:?}"),
        }
        assert!(largest < 1 << 20, "{name}: allocated {largest} bytes at once");
        let e = result.unwrap_err();
        assert!(e.to_string().contains("absurd.lfrs"), "{e}");
    }
}
