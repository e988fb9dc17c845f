//! TensorBoard event files written by code that returns its errors.
//!
//! An event file is a TFRecord stream: each record is `length: u64 LE`, `masked CRC32C of the length:
//! u32 LE`, the bytes of one `Event` protobuf, `masked CRC32C of the bytes: u32 LE`. The first event
//! holds `file_version = "brain.Event:2"`; the others hold a `Summary` with scalar values, or a
//! `SessionLog` (status `START` tells TensorBoard that a run restarted at that step and that events
//! at later steps from before the restart are orphans to discard).
//!
//! Scalars are encoded into memory by [`EventWriter::add_scalar`] (which cannot fail) and reach the
//! file on [`EventWriter::flush`], which reports I/O errors (full disk, read-only folder) instead of
//! panicking. [`EventWriter::position`] names the file and its length after a flush; a checkpoint
//! stores it so a resume cuts the file back to that length and no update is logged twice.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use prost::Message;
use serde::{Deserialize, Serialize};

use crate::AgentError;

/// The `file_version` TensorBoard expects in the first event of a file.
const FILE_VERSION: &str = "brain.Event:2";
/// `SessionLog.SessionStatus.START`.
const SESSION_START: i32 = 1;
/// Bytes of a record around its payload: length, its CRC, the payload's CRC.
const FRAME_BYTES: usize = 8 + 4 + 4;
/// Largest event the reader accepts (ours are a few hundred bytes).
const MAX_EVENT_BYTES: u64 = 1 << 24;

/// `tensorflow.Event`, restricted to the fields written here.
#[derive(Clone, PartialEq, Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(oneof = "EventKind", tags = "3, 5, 7")]
    kind: Option<EventKind>,
}

#[derive(Clone, PartialEq, prost::Oneof)]
enum EventKind {
    #[prost(string, tag = "3")]
    FileVersion(String),
    #[prost(message, tag = "5")]
    Summary(Summary),
    #[prost(message, tag = "7")]
    SessionLog(SessionLog),
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` with a `simple_value` (a member of a oneof in the original, hence
/// `optional`: a scalar of 0.0 must still be written).
#[derive(Clone, PartialEq, Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, optional, tag = "2")]
    simple_value: Option<f32>,
}

/// `tensorflow.SessionLog`.
#[derive(Clone, PartialEq, Message)]
struct SessionLog {
    #[prost(int32, tag = "1")]
    status: i32,
    #[prost(string, tag = "2")]
    checkpoint_path: String,
    #[prost(string, tag = "3")]
    msg: String,
}

/// How the name of a run's event file starts.
pub(crate) const EVENTS_PREFIX: &str = "events.out.tfevents.";

/// Where a run's event file stood at a checkpoint.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EventsPosition {
    /// File name inside the run folder (`events.out.tfevents.*`).
    pub file: String,
    /// Bytes of whole records written up to the checkpoint.
    pub len: u64,
}

/// One scalar read back from an event file.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarEvent {
    /// Environment step it was logged at.
    pub step: i64,
    /// Tag, e.g. `losses/value_loss`.
    pub tag: String,
    /// Value.
    pub value: f32,
}

/// Appends scalar summaries to one event file in a run folder.
pub struct EventWriter {
    path: PathBuf,
    file: File,
    pending: Vec<u8>,
    len: u64,
}

fn masked_crc(bytes: &[u8]) -> u32 {
    let crc = crc32c::crc32c(bytes);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

fn wall_time() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

impl EventWriter {
    /// Starts a new event file in `run_dir` (with its `file_version` event, flushed).
    pub fn create(run_dir: &Path) -> Result<Self, AgentError> {
        let secs = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        // The process id and a counter keep names unique; TensorBoard reads files in name order.
        static CREATED: AtomicU64 = AtomicU64::new(0);
        let name = format!(
            "{EVENTS_PREFIX}{secs:010}.rlpkg.{}.{}",
            std::process::id(),
            CREATED.fetch_add(1, Ordering::Relaxed)
        );
        let path = run_dir.join(name);
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|e| AgentError::io(&path, e))?;
        let mut writer = Self {
            path,
            file,
            pending: Vec::new(),
            len: 0,
        };
        writer.push(Event {
            wall_time: wall_time(),
            step: 0,
            kind: Some(EventKind::FileVersion(FILE_VERSION.into())),
        });
        writer.flush()?;
        Ok(writer)
    }

    /// Continues the event file of a checkpoint: cuts it back to `position.len` (dropping what was
    /// logged after the checkpoint) and appends from there. When the file is shorter (cut by a full
    /// disk or a user), it is cut back to its last whole record and continued; when it is gone, a
    /// new file is started. Either way the restart is marked at `next_step` so that TensorBoard
    /// discards the orphaned events of any older file.
    pub fn resume(
        run_dir: &Path,
        position: Option<&EventsPosition>,
        next_step: u64,
    ) -> Result<Self, AgentError> {
        if let Some(position) = position {
            let mut parts = Path::new(&position.file).components();
            let plain_name = matches!(
                (parts.next(), parts.next()),
                (Some(std::path::Component::Normal(_)), None)
            );
            if !plain_name || !position.file.starts_with(EVENTS_PREFIX) {
                return Err(AgentError::Checkpoint {
                    path: run_dir.into(),
                    reason: format!(
                        "the checkpoint's event file `{}` is not an event file name inside the run folder",
                        position.file
                    ),
                });
            }
            let path = run_dir.join(&position.file);
            let existing = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            if existing >= position.len && position.len > 0 {
                let file = OpenOptions::new()
                    .write(true)
                    .open(&path)
                    .map_err(|e| AgentError::io(&path, e))?;
                file.set_len(position.len)
                    .map_err(|e| AgentError::io(&path, e))?;
                return Ok(Self {
                    path,
                    file,
                    pending: Vec::new(),
                    len: position.len,
                });
            }
            let whole = std::fs::read(&path).map_or(0, |bytes| whole_records_len(&bytes));
            if whole > 0 {
                let file = OpenOptions::new()
                    .write(true)
                    .open(&path)
                    .map_err(|e| AgentError::io(&path, e))?;
                file.set_len(whole as u64)
                    .map_err(|e| AgentError::io(&path, e))?;
                let mut writer = Self {
                    path,
                    file,
                    pending: Vec::new(),
                    len: whole as u64,
                };
                writer.mark_restart(next_step)?;
                return Ok(writer);
            }
        }
        let mut writer = Self::create(run_dir)?;
        writer.mark_restart(next_step)?;
        Ok(writer)
    }

    /// A `SessionLog` start at `step`: TensorBoard drops what older files logged from there on.
    fn mark_restart(&mut self, next_step: u64) -> Result<(), AgentError> {
        self.push(Event {
            wall_time: wall_time(),
            step: next_step as i64,
            kind: Some(EventKind::SessionLog(SessionLog {
                status: SESSION_START,
                checkpoint_path: String::new(),
                msg: "resumed from a checkpoint".into(),
            })),
        });
        self.flush()
    }

    /// Queues a scalar; it reaches the file on the next [`EventWriter::flush`].
    pub fn add_scalar(&mut self, tag: &str, value: f32, step: usize) {
        self.push(Event {
            wall_time: wall_time(),
            step: step as i64,
            kind: Some(EventKind::Summary(Summary {
                value: vec![SummaryValue {
                    tag: tag.into(),
                    simple_value: Some(value),
                }],
            })),
        });
    }

    fn push(&mut self, event: Event) {
        let payload = event.encode_to_vec();
        let length = (payload.len() as u64).to_le_bytes();
        self.pending.reserve(payload.len() + FRAME_BYTES);
        self.pending.extend_from_slice(&length);
        self.pending
            .extend_from_slice(&masked_crc(&length).to_le_bytes());
        self.pending.extend_from_slice(&payload);
        self.pending
            .extend_from_slice(&masked_crc(&payload).to_le_bytes());
    }

    /// Writes the queued events at the end of the file.
    pub fn flush(&mut self) -> Result<(), AgentError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        // Positioned writes: after a failed write the next flush starts at the last good length.
        use std::io::{Seek, SeekFrom};
        self.file
            .seek(SeekFrom::Start(self.len))
            .and_then(|_| self.file.write_all(&self.pending))
            .map_err(|e| AgentError::io(&self.path, e))?;
        self.len += self.pending.len() as u64;
        self.pending.clear();
        Ok(())
    }

    /// Flushes, forces the file to disk and returns where it stands, for a checkpoint.
    pub fn position(&mut self) -> Result<EventsPosition, AgentError> {
        self.flush()?;
        self.file
            .sync_data()
            .map_err(|e| AgentError::io(&self.path, e))?;
        Ok(EventsPosition {
            file: self
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            len: self.len,
        })
    }

    /// The event file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The records of an event file's bytes in order: each one's offset and payload, its framing
/// and CRCs checked; the first bad one ends the sequence with its offset and what is wrong.
fn records(bytes: &[u8]) -> impl Iterator<Item = Result<(usize, &[u8]), (usize, &'static str)>> {
    let mut offset = 0;
    let mut failed = false;
    std::iter::from_fn(move || {
        if failed || offset >= bytes.len() {
            return None;
        }
        let rest = &bytes[offset..];
        let record = (|| {
            if rest.len() < 12 {
                return Err("truncated header");
            }
            let length_bytes = &rest[..8];
            let stored = u32::from_le_bytes(rest[8..12].try_into().expect("4 bytes"));
            if masked_crc(length_bytes) != stored {
                return Err("length CRC mismatch");
            }
            let length = u64::from_le_bytes(length_bytes.try_into().expect("8 bytes"));
            if length > MAX_EVENT_BYTES || rest.len() < FRAME_BYTES + length as usize {
                return Err("truncated or oversized event");
            }
            let payload = &rest[12..12 + length as usize];
            let stored = u32::from_le_bytes(
                rest[12 + length as usize..FRAME_BYTES + length as usize]
                    .try_into()
                    .expect("4 bytes"),
            );
            if masked_crc(payload) != stored {
                return Err("payload CRC mismatch");
            }
            Ok(payload)
        })();
        match record {
            Ok(payload) => {
                let at = offset;
                offset += FRAME_BYTES + payload.len();
                Some(Ok((at, payload)))
            }
            Err(what) => {
                failed = true;
                Some(Err((offset, what)))
            }
        }
    })
}

/// The length of the whole records at the start of an event file's bytes.
fn whole_records_len(bytes: &[u8]) -> usize {
    records(bytes)
        .map_while(Result::ok)
        .last()
        .map_or(0, |(offset, payload)| offset + FRAME_BYTES + payload.len())
}

/// Reads every scalar of an event file, checking each record's framing and CRCs.
pub fn read_scalars(path: &Path) -> Result<Vec<ScalarEvent>, AgentError> {
    let mut bytes = Vec::new();
    File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|e| AgentError::io(path, e))?;
    let corrupt = |offset: usize, what: &str| AgentError::Checkpoint {
        path: path.into(),
        reason: format!("event record at byte {offset}: {what}"),
    };
    let mut scalars = Vec::new();
    for record in records(&bytes) {
        let (offset, payload) = record.map_err(|(offset, what)| corrupt(offset, what))?;
        let event = Event::decode(payload).map_err(|e| corrupt(offset, &e.to_string()))?;
        if let Some(EventKind::Summary(summary)) = event.kind {
            for value in summary.value {
                if let Some(v) = value.simple_value {
                    scalars.push(ScalarEvent {
                        step: event.step,
                        tag: value.tag,
                        value: v,
                    });
                }
            }
        }
    }
    Ok(scalars)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_crc_matches_tensorflow() {
        // CRC32C("123456789") = 0xe3069283 (RFC 3720); masked as in tensorflow/core/lib/hash/crc32c.h,
        // ((crc >> 15) | (crc << 17)) + 0xa282ead8, worked out by hand: 0xc78ab0e5.
        assert_eq!(masked_crc(b"123456789"), 0xc78a_b0e5);
    }

    #[test]
    fn scalars_round_trip_including_zero() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = EventWriter::create(dir.path()).unwrap();
        writer.add_scalar("losses/value_loss", 0.25, 256);
        writer.add_scalar("charts/SPS", 0.0, 256);
        writer.add_scalar("losses/value_loss", -1.5, 512);
        writer.flush().unwrap();
        let back = read_scalars(writer.path()).unwrap();
        let expected = [
            (256, "losses/value_loss", 0.25),
            (256, "charts/SPS", 0.0),
            (512, "losses/value_loss", -1.5),
        ];
        assert_eq!(back.len(), expected.len());
        for (event, (step, tag, value)) in back.iter().zip(expected) {
            assert_eq!(
                (event.step, event.tag.as_str(), event.value),
                (step, tag, value)
            );
        }
    }

    #[test]
    fn resume_cuts_the_file_back_to_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = EventWriter::create(dir.path()).unwrap();
        writer.add_scalar("a", 1.0, 1);
        let position = writer.position().unwrap();
        writer.add_scalar("a", 2.0, 2);
        writer.flush().unwrap();
        drop(writer);
        let mut resumed = EventWriter::resume(dir.path(), Some(&position), 2).unwrap();
        resumed.add_scalar("a", 3.0, 2);
        resumed.flush().unwrap();
        let back = read_scalars(resumed.path()).unwrap();
        let values: Vec<(i64, f32)> = back.iter().map(|e| (e.step, e.value)).collect();
        assert_eq!(values, [(1, 1.0), (2, 3.0)]);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_truncated_file_is_cut_back_to_its_last_whole_record_and_continued() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = EventWriter::create(dir.path()).unwrap();
        writer.add_scalar("a", 1.0, 1);
        writer.flush().unwrap();
        writer.add_scalar("a", 2.0, 2);
        let position = writer.position().unwrap();
        drop(writer);
        // A full disk cut the last record in the middle.
        let path = dir.path().join(&position.file);
        let file = OpenOptions::new().write(true).open(&path).unwrap();
        file.set_len(position.len - 3).unwrap();
        drop(file);
        assert!(read_scalars(&path).is_err());
        let mut resumed = EventWriter::resume(dir.path(), Some(&position), 2).unwrap();
        assert_eq!(resumed.path(), path);
        resumed.add_scalar("a", 3.0, 2);
        resumed.flush().unwrap();
        let back = read_scalars(&path).unwrap();
        let values: Vec<(i64, f32)> = back.iter().map(|e| (e.step, e.value)).collect();
        assert_eq!(values, [(1, 1.0), (2, 3.0)]);
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no second file"
        );
    }

    #[test]
    fn resume_without_the_file_starts_a_new_one_and_rejects_foreign_names() {
        let dir = tempfile::tempdir().unwrap();
        let gone = EventsPosition {
            file: "events.out.tfevents.1.rlpkg.1".into(),
            len: 100,
        };
        let writer = EventWriter::resume(dir.path(), Some(&gone), 7).unwrap();
        assert_ne!(writer.path(), dir.path().join(&gone.file));
        assert!(read_scalars(writer.path()).unwrap().is_empty());
        for file in ["../events.out.tfevents.1", "/tmp/x", "config.toml"] {
            let position = EventsPosition {
                file: file.into(),
                len: 10,
            };
            let err = EventWriter::resume(dir.path(), Some(&position), 7)
                .err()
                .unwrap();
            assert!(err.to_string().contains("not an event file name"), "{err}");
        }
    }

    #[test]
    fn an_unwritable_folder_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let not_a_folder = dir.path().join("file");
        std::fs::write(&not_a_folder, "").unwrap();
        let err = EventWriter::create(&not_a_folder).err().unwrap();
        assert!(matches!(err, AgentError::Io { .. }), "{err}");
    }
}
