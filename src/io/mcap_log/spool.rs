//! The in-memory spool between the MCAP writer and the file: the writer can
//! never fail on its output, and the file receives whole chunks only, so a
//! failed write leaves the file a readable prefix and the bytes to retry.

use std::io::{Seek, SeekFrom, Write};
use std::sync::{Arc, Mutex};

/// Bytes kept in memory while the file cannot be written; beyond this,
/// records are dropped (and counted) until a write succeeds.
pub(super) const SPOOL_MAX_BYTES: usize = 32 << 20;
/// The memory the spool keeps after a failure is over (bytes).
const SPOOL_KEEP_BYTES: usize = 8 << 20;

/// The bytes the MCAP writer has produced and the file does not have yet.
///
/// The MCAP writer cannot go on after an error of its output (it fails every
/// later call), so it writes to memory, which never fails; the writer thread
/// copies whole chunks to the file. A failed copy leaves the bytes here to be
/// retried, and the file a prefix of a well-formed log.
#[derive(Debug, Default)]
pub(super) struct Spool {
    buf: Vec<u8>,
    /// Offset in the log of `buf[0]`: the bytes before it are in the file.
    base: u64,
    /// The MCAP writer's position in `buf` (it goes back to fill in a
    /// chunk's header when it closes the chunk).
    pos: usize,
    /// Bytes of `buf` already in the file (a partial write).
    sent: usize,
}

impl Spool {
    /// Bytes not yet in the file.
    pub(super) fn unsent(&self) -> usize {
        self.buf.len() - self.sent
    }

    /// Bytes of the log in its file.
    pub(super) fn written(&self) -> u64 {
        self.base + self.sent as u64
    }
}

/// Locks the spool (a panic elsewhere poisons nothing the writer needs).
pub(super) fn lock(spool: &Mutex<Spool>) -> std::sync::MutexGuard<'_, Spool> {
    spool.lock().unwrap_or_else(|p| p.into_inner())
}

/// The MCAP writer's output: the [`Spool`], shared with the writer thread.
pub(super) struct SpoolSink(pub(super) Arc<Mutex<Spool>>);

impl Write for SpoolSink {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        let mut guard = lock(&self.0);
        let s = &mut *guard;
        let over = (s.buf.len() - s.pos).min(data.len());
        s.buf[s.pos..s.pos + over].copy_from_slice(&data[..over]);
        s.buf.extend_from_slice(&data[over..]);
        s.pos += data.len();
        Ok(data.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Seek for SpoolSink {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let mut s = lock(&self.0);
        let (base, len) = (i128::from(s.base), s.buf.len() as i128);
        let target = match to {
            SeekFrom::Start(n) => i128::from(n),
            SeekFrom::End(d) => base + len + i128::from(d),
            SeekFrom::Current(d) => base + s.pos as i128 + i128::from(d),
        };
        // Only within what the file does not have yet.
        if target < base + s.sent as i128 || target > base + len {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "MCAP log: seek outside the unwritten part",
            ));
        }
        s.pos = (target - base) as usize;
        Ok(target as u64)
    }
}

/// Writes the spool's unsent bytes to `file`; on success the spool is
/// emptied. A partial write is remembered, so a retry goes on from there.
pub(super) fn write_spool(spool: &Mutex<Spool>, file: &mut dyn Write) -> std::io::Result<()> {
    let mut guard = lock(spool);
    let s = &mut *guard;
    while s.sent < s.buf.len() {
        match file.write(&s.buf[s.sent..]) {
            Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
            Ok(n) => s.sent += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    file.flush()?;
    s.base += s.buf.len() as u64;
    s.buf.clear();
    if s.buf.capacity() > SPOOL_KEEP_BYTES {
        s.buf.shrink_to(SPOOL_KEEP_BYTES);
    }
    s.pos = 0;
    s.sent = 0;
    Ok(())
}
