//! The positional writer: many threads write runs of encoded records straight to their final
//! place in the file (every record has the same size, so sample `i` starts at a known offset),
//! in any order. The chunk table's CRC-32s are assembled at the end from each run's CRCs, cut at
//! chunk boundaries and combined in file order, so the file is byte for byte what
//! [`SampleWriter`](crate::SampleWriter) writes from the same records pushed in order.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::error::{Result, SampleError};
use crate::header::{Header, HeaderSpec};
use crate::writer::{end_of_file, rename_into_place, start, Durability, Started};

/// The CRC-32 of samples `first .. first + count`, all inside one chunk.
#[derive(Clone, Debug)]
struct Run {
    first: u64,
    count: u64,
    crc: crc32fast::Hasher,
}

/// Writes one sample file from several threads: create it with [`PositionalWriter::create`],
/// write every sample exactly once with [`write_records_at`](Self::write_records_at) (shared
/// references; any thread, any order), then [`finish`](Self::finish). Holds no samples: the
/// records go to the file as they come, and the writer keeps one CRC per written run and chunk.
/// Dropping a writer that was not finished removes its temporary file.
#[derive(Debug)]
pub struct PositionalWriter {
    path: PathBuf,
    tmp: PathBuf,
    _interrupt: crate::interrupt::Registered,
    file: Option<File>,
    header: Header,
    header_crc: u32,
    /// Byte offset of sample 0.
    data_offset: u64,
    runs: Mutex<Vec<Run>>,
    finished: bool,
}

impl PositionalWriter {
    /// Validates the header, computes the field layout and writes the preamble and header to
    /// `<path>.<pid>.tmp` beside `path`.
    pub fn create(path: &Path, header: HeaderSpec) -> Result<PositionalWriter> {
        let Started { header, header_crc, tmp, registration, file, preamble_and_header } = start(path, header)?;
        file.write_all_at(&preamble_and_header, 0).map_err(|e| SampleError::io(&tmp, "write", e))?;
        Ok(PositionalWriter {
            path: path.to_path_buf(),
            tmp,
            _interrupt: registration,
            file: Some(file),
            header,
            header_crc,
            data_offset: preamble_and_header.len() as u64,
            runs: Mutex::new(Vec::new()),
            finished: false,
        })
    }

    /// The header being written (with computed offsets and record size).
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The destination path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `records` (whole records, laid out as [`encode_record`](crate::encode_record)
    /// does) as samples `first_sample ..` of the file.
    pub fn write_records_at(&self, first_sample: u64, records: &[u8]) -> Result<()> {
        let size = self.header.record_size as usize;
        if size == 0 || records.len() % size != 0 {
            return Err(SampleError::WrongLength {
                path: self.path.clone(),
                sample: first_sample,
                what: "record bytes (a whole number of records)",
                expected: size * (records.len() / size.max(1) + 1),
                actual: records.len(),
            });
        }
        let count = (records.len() / size) as u64;
        let past_the_end = match first_sample.checked_add(count) {
            Some(end) => end > self.header.sample_count,
            None => true,
        };
        if past_the_end {
            return Err(SampleError::TooManySamples { path: self.path.clone(), expected: self.header.sample_count });
        }
        let file = self.file.as_ref().expect("the writer is open until finished");
        let offset = self.data_offset + first_sample * size as u64;
        file.write_all_at(records, offset).map_err(|e| SampleError::io(&self.tmp, "write", e))?;
        // One CRC per piece of the run inside one chunk.
        let chunk = u64::from(self.header.chunk_samples);
        let mut runs = Vec::new();
        let (mut sample, mut rest) = (first_sample, records);
        while !rest.is_empty() {
            let in_this_chunk = (chunk - sample % chunk).min(count - (sample - first_sample));
            let (now, later) = rest.split_at(in_this_chunk as usize * size);
            let mut crc = crc32fast::Hasher::new();
            crc.update(now);
            runs.push(Run { first: sample, count: in_this_chunk, crc });
            (sample, rest) = (sample + in_this_chunk, later);
        }
        self.runs.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).extend(runs);
        Ok(())
    }

    /// Checks that the written runs cover every sample exactly once, writes the chunk table and
    /// trailer, syncs the file if `durability` asks and renames it into place. Returns the final
    /// path. On error the temporary file is removed and nothing is left at `path`.
    pub fn finish(mut self, durability: Durability) -> Result<PathBuf> {
        let mut runs = std::mem::take(self.runs.get_mut().unwrap_or_else(|poisoned| poisoned.into_inner()));
        runs.sort_unstable_by_key(|run| run.first);
        let chunk = u64::from(self.header.chunk_samples);
        let mut chunk_crcs = Vec::with_capacity(self.header.chunk_count() as usize);
        let mut covered = 0u64;
        let mut current: Option<crc32fast::Hasher> = None;
        for run in runs {
            if run.first > covered {
                return Err(self.never_written(covered, run.first));
            }
            if run.first < covered {
                return Err(SampleError::Invalid {
                    path: self.path.clone(),
                    field: "records".into(),
                    message: format!("sample {} was written twice", run.first),
                });
            }
            match current.as_mut() {
                Some(crc) => crc.combine(&run.crc),
                None => current = Some(run.crc),
            }
            covered += run.count;
            if covered % chunk == 0 || covered == self.header.sample_count {
                chunk_crcs.push(current.take().expect("a run was just added").finalize());
            }
        }
        if covered != self.header.sample_count {
            return Err(self.never_written(covered, self.header.sample_count));
        }
        let end = end_of_file(&self.header, self.header_crc, &chunk_crcs);
        let file = self.file.take().expect("the writer is open until finished");
        let offset = self.data_offset + covered * u64::from(self.header.record_size);
        file.write_all_at(&end, offset).map_err(|e| SampleError::io(&self.tmp, "write", e))?;
        rename_into_place(file, &self.tmp, &self.path, durability)?;
        self.finished = true;
        Ok(self.path.clone())
    }
}

impl PositionalWriter {
    fn never_written(&self, first: u64, end: u64) -> SampleError {
        let samples =
            if end == first + 1 { format!("sample {first} was") } else { format!("samples {first}..{end} were") };
        SampleError::Invalid {
            path: self.path.clone(),
            field: "records".into(),
            message: format!("{samples} never written"),
        }
    }
}

impl Drop for PositionalWriter {
    fn drop(&mut self) {
        if !self.finished {
            drop(self.file.take());
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FieldSpec, FieldType, SampleFile, SampleKind, SampleWriter};

    /// 5 x 3 pixels at 7 spp, chunks of 4 samples: runs cross chunk boundaries everywhere.
    fn spec() -> HeaderSpec {
        let mut spec = HeaderSpec::new(SampleKind::Ao, 5, 3, 7)
            .field(FieldSpec::new("index", FieldType::F32, 1))
            .field(FieldSpec::new("half", FieldType::F16, 1));
        spec.chunk_samples = 4;
        spec
    }

    /// Sample `index`'s record (padded to the layout's record size).
    fn record(index: u64) -> Vec<u8> {
        let header = spec().to_header().unwrap();
        let mut bytes = vec![0; header.record_size as usize];
        crate::encode_record(&header, &[index as f32, index as f32 * 0.5], &mut bytes).unwrap();
        bytes
    }

    /// The file the streaming writer gives for the same records pushed in order.
    fn streamed(path: &Path) -> Vec<u8> {
        let mut writer = SampleWriter::create(path, spec()).unwrap();
        for i in 0..105 {
            writer.push_record(&record(i)).unwrap();
        }
        writer.finish().unwrap();
        std::fs::read(path).unwrap()
    }

    /// Runs of every length, written in a scrambled order from several threads, give the
    /// streaming writer's file byte for byte, and the reader accepts its CRCs.
    #[test]
    fn runs_in_any_order_write_the_streaming_writers_file() {
        let dir = tempfile::tempdir().unwrap();
        let expected = streamed(&dir.path().join("streamed.lfrs"));
        for run_length in [1u64, 3, 4, 5, 13, 105] {
            let path = dir.path().join(format!("placed-{run_length}.lfrs"));
            let writer = PositionalWriter::create(&path, spec()).unwrap();
            let starts: Vec<u64> = (0..105).step_by(run_length as usize).collect();
            std::thread::scope(|scope| {
                for part in [0usize, 1, 2] {
                    let (writer, starts) = (&writer, &starts);
                    scope.spawn(move || {
                        // Each thread writes its third of the runs back to front.
                        for &first in starts.iter().rev().skip(part).step_by(3) {
                            let end = (first + run_length).min(105);
                            let bytes: Vec<u8> = (first..end).flat_map(record).collect();
                            writer.write_records_at(first, &bytes).unwrap();
                        }
                    });
                }
            });
            writer.finish(Durability::Unsynced).unwrap();
            assert_eq!(std::fs::read(&path).unwrap(), expected, "runs of {run_length}");
            assert_eq!(SampleFile::open(&path).unwrap().column("index").unwrap()[104], 104.0);
        }
    }

    /// Finishing over an existing file replaces it, synced or not (an unsynced scratch file
    /// removes the old one before the rename), and leaves nothing beside it.
    #[test]
    fn finishing_replaces_an_existing_file_either_way() {
        let dir = tempfile::tempdir().unwrap();
        let expected = streamed(&dir.path().join("streamed.lfrs"));
        let path = dir.path().join("again.lfrs");
        for durability in [Durability::Unsynced, Durability::Synced, Durability::Unsynced] {
            std::fs::write(&path, b"an older file").unwrap();
            let writer = PositionalWriter::create(&path, spec()).unwrap();
            let bytes: Vec<u8> = (0..105).flat_map(record).collect();
            writer.write_records_at(0, &bytes).unwrap();
            writer.finish(durability).unwrap();
            assert_eq!(std::fs::read(&path).unwrap(), expected, "{durability:?}");
            let mut names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
            names.sort();
            assert_eq!(names, ["again.lfrs", "streamed.lfrs"], "{durability:?}");
        }
    }

    /// A sample never written, a sample written twice, a run past the end or of a partial
    /// record: a clear error, and no file at the destination or beside it.
    #[test]
    fn gaps_overlaps_and_bad_runs_are_errors_that_leave_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.lfrs");
        let all = |skip: u64, twice: Option<u64>| {
            let writer = PositionalWriter::create(&path, spec()).unwrap();
            for i in (0..105).filter(|&i| i != skip) {
                writer.write_records_at(i, &record(i)).unwrap();
            }
            if let Some(i) = twice {
                writer.write_records_at(i, &record(i)).unwrap();
            }
            writer.finish(Durability::Synced).unwrap_err().to_string()
        };
        let gap = all(40, None);
        assert!(gap.contains("sample 40 was never written"), "{gap}");
        let last = all(104, None);
        assert!(last.contains("sample 104 was never written"), "{last}");
        let overlap = all(105, Some(7));
        assert!(overlap.contains("sample 7 was written twice"), "{overlap}");
        let writer = PositionalWriter::create(&path, spec()).unwrap();
        let past = writer.write_records_at(104, &[record(104), record(105)].concat()).unwrap_err().to_string();
        assert!(past.contains("too many samples"), "{past}");
        let partial = writer.write_records_at(0, &record(0)[..5]).unwrap_err().to_string();
        assert!(partial.contains("record bytes"), "{partial}");
        assert!(writer.write_records_at(u64::MAX, &record(0)).is_err());
        drop(writer);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no file and no temporary left");
    }
}
