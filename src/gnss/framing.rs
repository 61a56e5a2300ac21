//! The framer the RTCM3 and UBX decoders share: bytes are fed through a
//! bounded buffer, a frame is looked for at each sync pattern, its length
//! read from its header and checked against the buffer, the whole frame
//! handed to the format to check and decode, and on any failure the stream
//! resynchronises, every byte passed over counted as skipped.
//!
//! What differs between the formats is a [`Format`]'s to say: the sync
//! pattern, the header's length and what makes it no frame's (RTCM3's
//! reserved bits, UBX's oversize payload), the checksum and its counts, and
//! whether the first byte of a frame whose checksum fails counts as skipped
//! (UBX counts it, RTCM3 does not). A sync pattern's first bytes at the very
//! end of the buffer are kept, as they may start the next frame (UBX's
//! trailing 0xB5; RTCM3's one-byte preamble has no such prefix).
//!
//! The buffer is the format's own (each decoder reports `buffered()`): the
//! framer takes it out for the while it walks it, so that the format can be
//! handed a frame of it and still count into itself.

/// One framed format: its sync pattern, header and checksum, and its counts.
pub(super) trait Format {
    /// The bytes every frame starts with.
    const SYNC: &'static [u8];
    /// Bytes from the frame's start up to and including its length field.
    const HEADER: usize;
    /// The largest frame: bytes are fed in pieces of this size, and the
    /// buffer never keeps more than one frame's worth of unframed bytes.
    const MAX_FRAME: usize;
    /// Whether the first byte of a frame whose checksum fails is counted as
    /// skipped (the bytes after it, up to the next sync, always are).
    const COUNT_FAILED_FRAME_SKIPPED: bool;
    /// What a frame decodes into.
    type Message;

    /// The buffer of bytes not yet framed.
    fn buffer(&mut self) -> &mut Vec<u8>;
    /// The count of bytes passed over between frames.
    fn bytes_skipped(&mut self) -> &mut u64;
    /// The whole frame's length from its first `HEADER` bytes, or, when the
    /// header is no frame's, how many bytes to pass over (all counted as
    /// skipped; the format counts anything else itself).
    fn frame_len(&mut self, header: &[u8]) -> Result<usize, usize>;
    /// A whole frame: checks its checksum and decodes it into `out`. False
    /// when the checksum fails (the format counts the failure itself).
    fn frame(&mut self, frame: &[u8], out: &mut Vec<Self::Message>) -> bool;
}

/// Feeds bytes to `f`; returns the bytes left buffered (a truncated frame).
pub(super) fn push<F: Format>(f: &mut F, bytes: &[u8], out: &mut Vec<F::Message>) -> usize {
    for chunk in bytes.chunks(F::MAX_FRAME) {
        f.buffer().extend_from_slice(chunk);
        drain(f, out);
    }
    f.buffer().len()
}

/// Frames what the buffer holds, keeps the unfinished rest, and bounds it.
fn drain<F: Format>(f: &mut F, out: &mut Vec<F::Message>) {
    let mut buf = std::mem::take(f.buffer());
    let mut skipped = 0u64;
    let mut i = 0;
    loop {
        match buf[i..].windows(F::SYNC.len()).position(|w| w == F::SYNC) {
            Some(p) => {
                skipped += p as u64;
                i += p;
            }
            None => {
                let end = buf.len() - sync_prefix_at_end::<F>(&buf[i..]);
                skipped += (end - i) as u64;
                i = end;
                break;
            }
        }
        let rest = &buf[i..];
        if rest.len() < F::HEADER {
            break;
        }
        let len = match f.frame_len(&rest[..F::HEADER]) {
            Ok(len) => len,
            Err(pass) => {
                skipped += pass as u64;
                i += pass;
                continue;
            }
        };
        if rest.len() < len {
            break;
        }
        if f.frame(&rest[..len], out) {
            i += len;
        } else {
            skipped += u64::from(F::COUNT_FAILED_FRAME_SKIPPED);
            i += 1;
        }
    }
    buf.drain(..i);
    if buf.len() > 2 * F::MAX_FRAME {
        let cut = buf.len() - F::MAX_FRAME;
        skipped += cut as u64;
        buf.drain(..cut);
    }
    *f.buffer() = buf;
    *f.bytes_skipped() += skipped;
}

/// How many of `rest`'s last bytes begin the sync pattern (and may begin
/// the next frame once more bytes come).
fn sync_prefix_at_end<F: Format>(rest: &[u8]) -> usize {
    (1..F::SYNC.len().min(rest.len() + 1))
        .rev()
        .find(|&n| rest.ends_with(&F::SYNC[..n]))
        .unwrap_or(0)
}
