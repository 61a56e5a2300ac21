//! Recovering a flight log that was never finished: why this exists is that
//! the logs people most need to read are the crash logs. A daemon killed,
//! or a companion computer that lost power, leaves an MCAP file without its
//! summary section: readers that seek (PlotJuggler, Python's `make_reader`
//! on a file) find no chunk index and read nothing. Every complete chunk is
//! still in the file, because the writer closes one at least every second.
//!
//! [`recover`] walks the file's top-level records by their length prefixes
//! (opcode `u8`, length `u64` LE, body), so it knows exactly where the last
//! complete record ends. It reads the records before that point: schemas,
//! channels, metadata, attachments, and the messages in each chunk whose
//! contents decompress. It then writes them to a new MCAP file through the
//! `mcap` writer, with message and chunk indexes, statistics and a summary.
//! A chunk that does not decompress, and the cut-off tail, are dropped and
//! reported, never guessed at.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use serde::Serialize;

/// MCAP's magic, at the start and the end of a finished file.
pub const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Why a log could not be recovered.
#[derive(Debug, thiserror::Error)]
pub enum RecoverError {
    #[error("'{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Check(#[from] super::CheckError),
    #[error("'{path}': {message}")]
    Mcap { path: PathBuf, message: String },
    #[error(transparent)]
    Output(#[from] super::OutputError),
}

/// What [`recover`] kept and dropped.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RecoverReport {
    pub input_bytes: u64,
    /// The input already ended with its footer and magic: nothing was lost.
    pub input_was_complete: bool,
    /// The input had damaged chunks or a damaged record length (what was
    /// lost is in `chunks_dropped`).
    pub input_was_damaged: bool,
    pub messages_kept: u64,
    pub messages_by_topic: BTreeMap<String, u64>,
    pub schemas: u64,
    pub channels: u64,
    pub metadata: u64,
    pub attachments: u64,
    pub chunks_kept: u64,
    /// Log times of the first and last message kept (ns).
    pub first_log_time_ns: Option<u64>,
    pub last_log_time_ns: Option<u64>,
    /// Complete chunks whose contents did not decompress or parse.
    pub chunks_dropped: u64,
    /// Chunks found through the summary's chunk index after a damaged
    /// length broke the file's framing.
    pub chunks_from_summary: u64,
    /// Messages whose channel was never declared.
    pub messages_dropped_unknown_channel: u64,
    /// Bytes after the last complete record: a record cut off mid-write.
    pub tail_bytes_dropped: u64,
    pub output_bytes: u64,
}

/// Whether the file at `path` ends with MCAP's magic, as a finished log
/// does. `Ok(false)` also for a file too short to hold it.
pub fn is_finished(path: &Path) -> std::io::Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    // Never open a FIFO or a device to read it: that can block for ever.
    if !std::fs::metadata(path)?.is_file() {
        return Ok(false);
    }
    let mut f = File::open(path)?;
    let len = f.metadata()?.len();
    if len < 16 {
        return Ok(false);
    }
    f.seek(SeekFrom::End(-8))?;
    let mut end = [0u8; 8];
    f.read_exact(&mut end)?;
    Ok(&end == MCAP_MAGIC)
}

/// The `.mcap` files in `dir` that were left unfinished (no end magic),
/// newest first, at most `max` of them, other than `except`. Unreadable
/// entries are skipped: this only informs.
pub fn unfinished_logs(dir: &Path, except: &Path, max: usize) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<(std::time::SystemTime, PathBuf)> = entries
        .filter_map(Result::ok)
        .take(10_000)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .filter(|p| std::fs::metadata(p).is_ok_and(|m| m.is_file()))
        .filter(|p| !super::same_file(p, except))
        .filter(|p| matches!(is_finished(p), Ok(false)))
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .collect();
    found.sort_by_key(|f| std::cmp::Reverse(f.0));
    found.into_iter().take(max).map(|(_, p)| p).collect()
}

/// The end offset of the last complete top-level record after the leading
/// magic: records are `opcode (1) | length (8, LE) | body`.
fn complete_prefix_len(bytes: &[u8]) -> usize {
    let mut pos = MCAP_MAGIC.len();
    while pos + 9 <= bytes.len() {
        let mut len = [0u8; 8];
        len.copy_from_slice(&bytes[pos + 1..pos + 9]);
        let body = u64::from_le_bytes(len);
        let Some(end) = (pos as u64 + 9).checked_add(body) else {
            break;
        };
        if end > bytes.len() as u64 {
            break;
        }
        pos = end as usize;
    }
    pos
}

/// Rewrites the log `input` to `output` with full indexes and a summary,
/// keeping every complete record (see the module's doc).
pub fn recover(input: &Path, output: &Path, overwrite: bool) -> Result<RecoverReport, RecoverError> {
    let io_err = |path: &Path| {
        let path = path.to_path_buf();
        move |source| RecoverError::Io { path, source }
    };
    let input_bytes = std::fs::metadata(input).map_err(io_err(input))?.len();
    // Every declared length checked, damaged chunks left out and named, and
    // past a broken length the chunks the summary indexes.
    let checked = super::read_checked(input)?;
    let bytes = checked.bytes;
    let damaged_length = checked.report.framing_broken_at.is_some() && checked.report.chunks_from_summary > 0;
    let mut rep = RecoverReport {
        input_bytes,
        input_was_complete: checked.report.finished
            && checked.report.framing_broken_at.is_none()
            && checked.report.chunks_dropped.is_empty(),
        input_was_damaged: !checked.report.chunks_dropped.is_empty() || damaged_length,
        // The chunk whose length was damaged is lost with it.
        chunks_dropped: checked.report.chunks_dropped.len() as u64 + u64::from(damaged_length),
        chunks_from_summary: checked.report.chunks_from_summary,
        tail_bytes_dropped: if checked.report.chunks_from_summary > 0 {
            0
        } else {
            checked.report.tail_bytes_dropped
        },
        ..Default::default()
    };
    let prefix = complete_prefix_len(&bytes);

    let mcap_err = |e: mcap::McapError| RecoverError::Mcap {
        path: output.to_path_buf(),
        message: e.to_string(),
    };
    // Never over the input, nor over another file unless asked.
    let file = super::create_output(output, input, overwrite)?;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(1)
        .chunk_size(Some(super::writer::CHUNK_MAX_BYTES))
        .profile("")
        .library(format!("cmsckf {} (log recover)", env!("CMSCKF_BUILD")))
        .create(BufWriter::new(file))
        .map_err(mcap_err)?;

    let mut out = Recovered::default();
    let records =
        mcap::read::LinearReader::new_with_options(&bytes[..prefix], mcap::read::Options::IgnoreEndMagic.into())
            .map_err(|e| RecoverError::Mcap {
                path: input.to_path_buf(),
                message: e.to_string(),
            })?;
    for rec in records {
        // The prefix holds whole records only, so an error here is a
        // malformed record: what follows cannot be framed either.
        let Ok(rec) = rec else { break };
        match rec {
            Record::Chunk { header, data } => {
                // Parse the whole chunk before writing any of it: a chunk
                // is kept whole or dropped whole.
                let inner: Result<Vec<Record<'static>>, _> = mcap::read::ChunkReader::new(header, &data)
                    .and_then(|r| r.map(|x| x.map(Record::into_owned)).collect());
                match inner {
                    Ok(recs) => {
                        rep.chunks_kept += 1;
                        for r in recs {
                            out.write(&mut w, r, &mut rep).map_err(mcap_err)?;
                        }
                        // One output chunk per input chunk (about a second
                        // each): a seeking reader loads only what it needs.
                        w.flush().map_err(mcap_err)?;
                    }
                    Err(_) => rep.chunks_dropped += 1,
                }
            }
            other => out.write(&mut w, other, &mut rep).map_err(mcap_err)?,
        }
    }
    w.finish().map_err(mcap_err)?;
    drop(w);
    rep.output_bytes = std::fs::metadata(output).map_err(io_err(output))?.len();
    Ok(rep)
}

/// The schemas and channels written so far (by their ids in the input).
#[derive(Default)]
struct Recovered {
    schemas: std::collections::BTreeSet<u16>,
    channels: BTreeMap<u16, String>,
}

impl Recovered {
    fn write(
        &mut self,
        w: &mut mcap::Writer<BufWriter<File>>,
        rec: Record<'_>,
        rep: &mut RecoverReport,
    ) -> Result<(), mcap::McapError> {
        match rec {
            Record::Schema { header, data } if !self.schemas.contains(&header.id) => {
                self.schemas.insert(header.id);
                w.add_schema_with_id(header.id, &header.name, &header.encoding, &data)?;
                rep.schemas += 1;
            }
            Record::Channel(c) => {
                let schema_known = c.schema_id == 0 || self.schemas.contains(&c.schema_id);
                if schema_known && !self.channels.contains_key(&c.id) {
                    w.add_channel_with_id(c.id, c.schema_id, &c.topic, &c.message_encoding, &c.metadata)?;
                    self.channels.insert(c.id, c.topic);
                    rep.channels += 1;
                }
            }
            Record::Message { header, data } => match self.channels.get(&header.channel_id) {
                Some(topic) => {
                    w.write_to_known_channel(&header, &data)?;
                    rep.messages_kept += 1;
                    *rep.messages_by_topic.entry(topic.clone()).or_default() += 1;
                    let t = header.log_time;
                    rep.first_log_time_ns = Some(rep.first_log_time_ns.map_or(t, |x| x.min(t)));
                    rep.last_log_time_ns = Some(rep.last_log_time_ns.map_or(t, |x| x.max(t)));
                }
                None => rep.messages_dropped_unknown_channel += 1,
            },
            Record::Metadata(m) => {
                w.write_metadata(&m)?;
                rep.metadata += 1;
            }
            Record::Attachment { header, data, .. } => {
                w.attach(&mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name,
                    media_type: header.media_type,
                    data: data.into_owned().into(),
                })?;
                rep.attachments += 1;
            }
            // Indexes, statistics and the summary are rebuilt by the writer.
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn complete_prefix_stops_at_a_cut_record() {
        let mut b = MCAP_MAGIC.to_vec();
        // Two whole records (opcode, length 3, body), then one cut short.
        for _ in 0..2 {
            b.push(0x0f);
            b.extend_from_slice(&3u64.to_le_bytes());
            b.extend_from_slice(&[1, 2, 3]);
        }
        let whole = b.len();
        b.push(0x06);
        b.extend_from_slice(&100u64.to_le_bytes());
        b.extend_from_slice(&[0; 10]);
        assert_eq!(complete_prefix_len(&b), whole);
        // A length that would overflow is a cut, not a panic.
        let mut c = MCAP_MAGIC.to_vec();
        c.push(0x06);
        c.extend_from_slice(&u64::MAX.to_le_bytes());
        assert_eq!(complete_prefix_len(&c), MCAP_MAGIC.len());
    }
}
