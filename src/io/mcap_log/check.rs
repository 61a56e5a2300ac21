//! Opening a log that may be hostile or damaged. Why this exists: a flight
//! log comes from outside (a crashed companion, a card, a mail), and the
//! `mcap` reader trusts the lengths a file declares. A 111-byte file that
//! declared a 2⁶⁰-byte record aborted `review`, and a 6 KB zstd chunk that
//! declared 200 MB took `log recover` to 2.4 GB.
//!
//! [`read_checked`] walks the file before any reader sees it:
//! - every declared length (records, strings, byte arrays, maps) is checked
//!   against what holds it, before anything is allocated;
//! - a chunk may declare at most [`MAX_CHUNK_UNCOMPRESSED`] bytes, is
//!   decompressed into at most what it declares, and must then hold whole
//!   records;
//! - a chunk that fails is dropped and named, never guessed at;
//! - where a damaged length breaks the file's framing, the summary's chunk
//!   index (a finished log has one) finds the chunks after it;
//! - input that is not MCAP is refused by name (a PX4 ULog, text).
//!
//! What the readers get is the file itself when all of it checks out, else a
//! copy of the records that do, with no summary (read linearly).

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::MCAP_MAGIC;

/// The most a chunk may declare uncompressed (bytes). The daemon's chunks
/// close at 8 MiB; other writers' are smaller by default (Foxglove's 4 MiB).
pub const MAX_CHUNK_UNCOMPRESSED: u64 = 64 << 20;

/// All of a file's chunks may declare at most this many times its size
/// uncompressed (and at least [`MIN_TOTAL_UNCOMPRESSED`]): the JSON of a
/// real log compresses about 2.5-fold (the demo's logs: 2.5–2.6), and a
/// file that claims more is a decompression bomb, whose chunks past the
/// bound are dropped (each one within the chunk cap would still cost the
/// reader memory and time).
pub const MAX_COMPRESSION_RATIO: u64 = 20;
/// The total every file may declare whatever its size (bytes): one chunk
/// at the cap.
pub const MIN_TOTAL_UNCOMPRESSED: u64 = MAX_CHUNK_UNCOMPRESSED;

/// Why a file cannot be read as a log at all.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    #[error("cannot read '{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("'{path}' is not an MCAP flight log: it looks like {looks_like}")]
    NotMcap { path: PathBuf, looks_like: &'static str },
}

/// What the check found, for the reader to report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CheckReport {
    /// The file ends with its footer and magic.
    pub finished: bool,
    /// Chunks whose records checked out.
    pub chunks_ok: u64,
    /// Chunks dropped: `(offset in the file, why)`.
    pub chunks_dropped: Vec<(u64, String)>,
    /// Where a record's length went past the end of the file: the framing
    /// was broken there (a damaged length, or a log cut off mid-write).
    pub framing_broken_at: Option<u64>,
    /// Chunks found after that point through the summary's chunk index.
    pub chunks_from_summary: u64,
    /// Bytes after the last whole record that nothing could frame.
    pub tail_bytes_dropped: u64,
}

impl CheckReport {
    /// Says what was left out (each dropped chunk, a broken length), so
    /// that a reader of the log `name` knows what it is not seeing.
    pub fn warn(&self, name: &str) {
        for (offset, why) in &self.chunks_dropped {
            tracing::warn!(log = name, offset, "a damaged chunk is left out: {why}");
        }
        if let (Some(at), true) = (self.framing_broken_at, self.finished) {
            tracing::warn!(log = name, offset = at, from_summary = self.chunks_from_summary,
                "a damaged record length breaks the file there; the chunks after it were found through the summary's index");
        }
    }
}

/// A log's bytes that every reader may be given, and what was left out.
pub struct CheckedLog {
    /// The file as it is, or the records that checked out (magic first, no
    /// summary, no end magic: read it linearly, ignoring the end magic).
    pub bytes: Vec<u8>,
    /// The file was used as it is (it has its summary and end magic).
    pub whole: bool,
    pub report: CheckReport,
}

/// Reads and checks the log at `path` (see the module's doc).
pub fn read_checked(path: &Path) -> Result<CheckedLog, CheckError> {
    let bytes = std::fs::read(path).map_err(|source| CheckError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    check_bytes(bytes).map_err(|looks_like| CheckError::NotMcap {
        path: path.to_path_buf(),
        looks_like,
    })
}

/// What a file that is not MCAP looks like, for the error.
fn looks_like(bytes: &[u8]) -> &'static str {
    if bytes.is_empty() {
        "an empty file"
    } else if bytes.starts_with(b"ULog") {
        "a PX4 ULog (review it with PX4's Flight Review or pyulog)"
    } else if bytes.starts_with(b"\xa3\x95") {
        "an ArduPilot dataflash log (.bin)"
    } else if bytes.len() < MCAP_MAGIC.len() && MCAP_MAGIC.starts_with(bytes) {
        "the start of an MCAP file cut off before its header"
    } else if std::str::from_utf8(&bytes[..bytes.len().min(4096)]).is_ok() {
        "a text file"
    } else {
        "binary data with no MCAP magic at its start"
    }
}

/// Checks `bytes` (a whole file); `Err` names what a non-MCAP file looks
/// like.
pub fn check_bytes(bytes: Vec<u8>) -> Result<CheckedLog, &'static str> {
    if !bytes.starts_with(MCAP_MAGIC) {
        return Err(looks_like(&bytes));
    }
    let mut report = CheckReport {
        finished: bytes.len() >= 2 * MCAP_MAGIC.len() && bytes.ends_with(MCAP_MAGIC),
        ..Default::default()
    };
    // Good top-level records, as (offset, end).
    let mut good: Vec<(usize, usize)> = Vec::new();
    let mut pos = MCAP_MAGIC.len();
    let mut dropped_any = false;
    let end_of_records = if report.finished {
        bytes.len() - MCAP_MAGIC.len()
    } else {
        bytes.len()
    };
    let mut saw_footer = false;
    let budget = (bytes.len() as u64)
        .saturating_mul(MAX_COMPRESSION_RATIO)
        .max(MIN_TOTAL_UNCOMPRESSED);
    let mut declared_total: u64 = 0;
    while pos < end_of_records {
        let Some((op, body)) = frame(&bytes, pos, end_of_records) else {
            report.framing_broken_at = Some(pos as u64);
            break;
        };
        let end = pos + 9 + body.len();
        let over_budget = op == OP_CHUNK && {
            declared_total = declared_total.saturating_add(chunk_declared(body));
            declared_total > budget
        };
        let checked = if over_budget {
            Err(format!(
                "the chunks so far declare {declared_total} bytes uncompressed, over {MAX_COMPRESSION_RATIO} times the \
                 file's size: a decompression bomb, not a log"
            ))
        } else {
            check_record(op, body)
        };
        match checked {
            Ok(()) => {
                if op == OP_CHUNK {
                    report.chunks_ok += 1;
                }
                saw_footer |= op == OP_FOOTER;
                good.push((pos, end));
            }
            Err(why) => {
                if op == OP_CHUNK {
                    report.chunks_dropped.push((pos as u64, why));
                }
                dropped_any = true;
            }
        }
        pos = end;
    }
    let broken = report.framing_broken_at.is_some();
    if broken {
        report.tail_bytes_dropped = (end_of_records - pos) as u64;
    }
    if !broken && !dropped_any && report.finished && saw_footer {
        return Ok(CheckedLog {
            bytes,
            whole: true,
            report,
        });
    }
    // The records that checked out, in order, then (past a break) what the
    // summary still finds. Summary and footer records are left out: their
    // offsets would point into the old file.
    let mut out = MCAP_MAGIC.to_vec();
    for &(a, b) in &good {
        if !is_summary_op(bytes[a]) {
            out.extend_from_slice(&bytes[a..b]);
        }
    }
    if let Some(at) = report.framing_broken_at {
        for (a, b) in from_summary(&bytes, at as usize) {
            if bytes[a] == OP_CHUNK {
                report.chunks_from_summary += 1;
            }
            out.extend_from_slice(&bytes[a..b]);
        }
    }
    Ok(CheckedLog {
        bytes: out,
        whole: false,
        report,
    })
}

const OP_HEADER: u8 = 0x01;
const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_CHUNK: u8 = 0x06;
const OP_MESSAGE_INDEX: u8 = 0x07;
const OP_CHUNK_INDEX: u8 = 0x08;
const OP_ATTACHMENT: u8 = 0x09;
const OP_ATTACHMENT_INDEX: u8 = 0x0a;
const OP_STATISTICS: u8 = 0x0b;
const OP_METADATA: u8 = 0x0c;
const OP_METADATA_INDEX: u8 = 0x0d;
const OP_SUMMARY_OFFSET: u8 = 0x0e;
const OP_DATA_END: u8 = 0x0f;

/// Records that only index the file: dropped from a copy.
fn is_summary_op(op: u8) -> bool {
    matches!(
        op,
        OP_FOOTER
            | OP_MESSAGE_INDEX
            | OP_CHUNK_INDEX
            | OP_ATTACHMENT_INDEX
            | OP_STATISTICS
            | OP_METADATA_INDEX
            | OP_SUMMARY_OFFSET
    )
}

/// The record at `pos` (opcode and body), if its length stays before `end`.
fn frame(bytes: &[u8], pos: usize, end: usize) -> Option<(u8, &[u8])> {
    let op = *bytes.get(pos)?;
    let len = u64::from_le_bytes(bytes.get(pos + 1..pos + 9)?.try_into().ok()?);
    let body_end = (pos as u64 + 9).checked_add(len)?;
    if body_end > end as u64 {
        return None;
    }
    Some((op, &bytes[pos + 9..body_end as usize]))
}

/// A cursor over a record's body that checks each declared length against
/// what is left before taking it.
struct Fields<'a> {
    b: &'a [u8],
}

impl<'a> Fields<'a> {
    fn take(&mut self, n: u64, what: &str) -> Result<&'a [u8], String> {
        if n > self.b.len() as u64 {
            return Err(format!("{what} declares {n} bytes, {} are left", self.b.len()));
        }
        let (a, rest) = self.b.split_at(n as usize);
        self.b = rest;
        Ok(a)
    }

    fn u16(&mut self, what: &str) -> Result<u16, String> {
        let s = self.take(2, what)?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        let s = self.take(4, what)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64, String> {
        let s = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }

    fn skip(&mut self, n: u64, what: &str) -> Result<(), String> {
        self.take(n, what).map(|_| ())
    }

    /// A `u32`-prefixed string.
    fn string(&mut self, what: &str) -> Result<&'a [u8], String> {
        let n = self.u32(what)?;
        self.take(u64::from(n), what)
    }

    /// A `u32`-prefixed byte array.
    fn bytes32(&mut self, what: &str) -> Result<&'a [u8], String> {
        self.string(what)
    }

    /// A `u64`-prefixed byte array.
    fn bytes64(&mut self, what: &str) -> Result<&'a [u8], String> {
        let n = self.u64(what)?;
        self.take(n, what)
    }

    /// A `Map<string, string>`: its byte length, then whole pairs.
    fn string_map(&mut self, what: &str) -> Result<(), String> {
        let mut m = Fields { b: self.bytes32(what)? };
        while !m.b.is_empty() {
            m.string(what)?;
            m.string(what)?;
        }
        Ok(())
    }

    /// A map of fixed-size entries (`entry` bytes each).
    fn fixed_map(&mut self, entry: usize, what: &str) -> Result<(), String> {
        let m = self.bytes32(what)?;
        if m.len() % entry != 0 {
            return Err(format!("{what}: {} bytes is not whole entries of {entry}", m.len()));
        }
        Ok(())
    }
}

/// Checks one record's declared lengths (and a chunk's contents).
fn check_record(op: u8, body: &[u8]) -> Result<(), String> {
    let mut f = Fields { b: body };
    match op {
        OP_HEADER => {
            f.string("header profile")?;
            f.string("header library")?;
        }
        OP_FOOTER => {
            f.skip(20, "footer")?;
        }
        OP_SCHEMA => {
            f.u16("schema id")?;
            f.string("schema name")?;
            f.string("schema encoding")?;
            f.bytes32("schema data")?;
        }
        OP_CHANNEL => {
            f.u16("channel id")?;
            f.u16("channel schema id")?;
            f.string("channel topic")?;
            f.string("channel message encoding")?;
            f.string_map("channel metadata")?;
        }
        OP_MESSAGE => {
            f.skip(22, "message header")?;
        }
        OP_CHUNK => return check_chunk(&mut f),
        OP_MESSAGE_INDEX => {
            f.u16("message index channel")?;
            f.fixed_map(16, "message index records")?;
        }
        OP_CHUNK_INDEX => {
            f.skip(32, "chunk index")?;
            f.fixed_map(10, "chunk index message index offsets")?;
            f.u64("chunk index message index length")?;
            f.string("chunk index compression")?;
            f.skip(16, "chunk index sizes")?;
        }
        OP_ATTACHMENT => {
            f.skip(16, "attachment times")?;
            f.string("attachment name")?;
            f.string("attachment media type")?;
            f.bytes64("attachment data")?;
            f.u32("attachment crc")?;
        }
        OP_ATTACHMENT_INDEX => {
            f.skip(40, "attachment index")?;
            f.string("attachment index name")?;
            f.string("attachment index media type")?;
        }
        OP_STATISTICS => {
            // message count u64, schema u16, channel u32, attachment u32,
            // metadata u32, chunk u32, start and end times u64: 42 bytes.
            f.skip(42, "statistics")?;
            f.fixed_map(10, "statistics channel message counts")?;
        }
        OP_METADATA => {
            f.string("metadata name")?;
            f.string_map("metadata")?;
        }
        OP_METADATA_INDEX => {
            f.skip(16, "metadata index")?;
            f.string("metadata index name")?;
        }
        OP_SUMMARY_OFFSET => {
            f.skip(17, "summary offset")?;
        }
        OP_DATA_END => {
            f.u32("data end crc")?;
        }
        // An opcode this reader does not know: MCAP says skip it, and the
        // `mcap` reader does.
        _ => {}
    }
    Ok(())
}

/// What a chunk record's body declares uncompressed (0 if it cannot say).
fn chunk_declared(body: &[u8]) -> u64 {
    body.get(16..24)
        .and_then(|b| b.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

/// A chunk: its header's lengths, its size within [`MAX_CHUNK_UNCOMPRESSED`],
/// its contents decompressed into at most what it declares, and whole,
/// well-formed records inside.
fn check_chunk(f: &mut Fields<'_>) -> Result<(), String> {
    f.skip(16, "chunk times")?;
    let uncompressed = f.u64("chunk uncompressed size")?;
    f.u32("chunk crc")?;
    let compression = f.string("chunk compression")?.to_vec();
    let data = f.bytes64("chunk records")?;
    if uncompressed > MAX_CHUNK_UNCOMPRESSED {
        return Err(format!(
            "the chunk declares {uncompressed} bytes uncompressed, over the {} MiB a log chunk may hold",
            MAX_CHUNK_UNCOMPRESSED >> 20
        ));
    }
    let plain;
    let records: &[u8] = match compression.as_slice() {
        b"" => {
            if data.len() as u64 != uncompressed {
                return Err(format!(
                    "an uncompressed chunk of {} bytes declares {uncompressed}",
                    data.len()
                ));
            }
            data
        }
        b"zstd" => {
            plain = unzstd_bounded(data, uncompressed)?;
            &plain
        }
        other => {
            return Err(format!(
                "chunk compression '{}' is not read here (zstd or none)",
                String::from_utf8_lossy(other)
            ))
        }
    };
    let mut pos = 0;
    while pos < records.len() {
        let Some((op, body)) = frame(records, pos, records.len()) else {
            return Err(format!("a record at byte {pos} of the chunk runs past its end"));
        };
        if op == OP_CHUNK {
            return Err("a chunk inside a chunk".into());
        }
        check_record(op, body)?;
        pos += 9 + body.len();
    }
    Ok(())
}

/// zstd-decompresses `data` into at most `declared` bytes: more is an
/// error, found without ever holding more than `declared + 1`.
fn unzstd_bounded(data: &[u8], declared: u64) -> Result<Vec<u8>, String> {
    let dec = zstd::stream::read::Decoder::with_buffer(data).map_err(|e| format!("zstd: {e}"))?;
    let mut out = Vec::new();
    dec.take(declared + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("the chunk does not decompress: {e}"))?;
    if out.len() as u64 != declared {
        return Err(format!(
            "the chunk decompresses to {}{} bytes, it declares {declared}",
            if out.len() as u64 > declared { "more than " } else { "" },
            out.len().min(declared as usize)
        ));
    }
    Ok(out)
}

/// The records after `broken_at` that the summary still finds: its schemas
/// and channels (in case theirs were lost) and every chunk and metadata
/// record it indexes at or past that point, each checked where it is.
fn from_summary(bytes: &[u8], broken_at: usize) -> Vec<(usize, usize)> {
    let mut found = Vec::new();
    let n = bytes.len();
    // The footer: opcode, length 20, summary start, summary offset start,
    // crc; then the magic.
    let footer_at = n.checked_sub(MCAP_MAGIC.len() + 29);
    let Some(footer_at) = footer_at.filter(|_| bytes.ends_with(MCAP_MAGIC)) else {
        return found;
    };
    let Some((OP_FOOTER, body)) = frame(bytes, footer_at, n - MCAP_MAGIC.len()) else {
        return found;
    };
    let mut f = Fields { b: body };
    let Ok(summary_start) = f.u64("footer") else {
        return found;
    };
    let summary_start = summary_start as usize;
    if summary_start < MCAP_MAGIC.len() || summary_start >= footer_at {
        return found;
    }
    let mut pos = summary_start;
    let mut indexed = Vec::new();
    while pos < footer_at {
        let Some((op, body)) = frame(bytes, pos, footer_at) else {
            break;
        };
        let end = pos + 9 + body.len();
        if check_record(op, body).is_ok() {
            match op {
                OP_SCHEMA | OP_CHANNEL => found.push((pos, end)),
                OP_CHUNK_INDEX | OP_METADATA_INDEX => {
                    let mut g = Fields { b: body };
                    let offset = if op == OP_CHUNK_INDEX {
                        g.skip(16, "").and_then(|_| g.u64(""))
                    } else {
                        g.u64("")
                    };
                    let length = g.u64("");
                    if let (Ok(o), Ok(l)) = (offset, length) {
                        indexed.push((o, l, if op == OP_CHUNK_INDEX { OP_CHUNK } else { OP_METADATA }));
                    }
                }
                _ => {}
            }
        }
        pos = end;
    }
    indexed.sort_unstable();
    // Each record once, none overlapping another: a summary that lists a
    // chunk twice (or ten thousand times) must not multiply it.
    let mut next_free = broken_at;
    for (offset, length, op) in indexed {
        let Ok(o) = usize::try_from(offset) else { continue };
        if o < next_free || o >= summary_start {
            continue;
        }
        if let Some((got, body)) = frame(bytes, o, summary_start) {
            if got == op && 9 + body.len() as u64 == length && check_record(op, body).is_ok() {
                found.push((o, o + 9 + body.len()));
                next_free = o + 9 + body.len();
            }
        }
    }
    found
}
