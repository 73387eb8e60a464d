//! `open_file`: the input bytes are a whole file. They are written to a scratch file and opened
//! with `SampleFile::open` and `SampleFile::open_unchecked`; neither may panic, they must agree
//! (`open` = `open_unchecked` + `verify`), every error must name the file, and whatever opens is
//! put through every accessor within its documented preconditions (`sampleio_fuzz::exercise`).
//!
//! Seed it with valid files (`cargo run --example seed_corpus`, see `docs/fuzzing.md`):
//! random bytes rarely get past the magic, let alone the CRCs.

#![no_main]

use libfuzzer_sys::fuzz_target;
use sampleio::{SampleError, SampleFile};
use sampleio_fuzz::{check_error, exercise, scratch_file};

fuzz_target!(|data: &[u8]| {
    let path = scratch_file("input.lfrs");
    std::fs::write(&path, data).expect("write the scratch file");

    let checked = SampleFile::open(&path);
    let unchecked = SampleFile::open_unchecked(&path);
    match (&checked, &unchecked) {
        (Ok(file), Ok(same)) => {
            assert_eq!(file.header(), same.header());
            assert_eq!(file.data(), same.data());
            assert!(same.verify().is_ok(), "open() accepted what verify() rejects");
            assert!(data.starts_with(&sampleio::MAGIC));
            exercise(file);
        }
        (Err(e), Ok(file)) => {
            check_error(e, &path);
            // Only the data CRCs separate the two.
            assert!(matches!(e, SampleError::Corrupted { .. }), "open: {e}, but open_unchecked accepted the file");
            match file.verify() {
                Err(v) => assert_eq!(v.to_string(), e.to_string()),
                Ok(()) => panic!("open failed ({e}) but verify() passes"),
            }
            // The accessors promise nothing about the data's checksums: they must work anyway.
            exercise(file);
        }
        (Ok(_), Err(e)) => panic!("open accepted the file, open_unchecked did not: {e}"),
        (Err(a), Err(b)) => {
            check_error(a, &path);
            check_error(b, &path);
            assert_eq!(a.to_string(), b.to_string(), "open and open_unchecked disagree");
            assert!(!matches!(b, SampleError::Corrupted { .. }), "open_unchecked checked the data: {b}");
        }
    }
});
