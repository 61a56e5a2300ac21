//! Raw camera images on a byte stream: how a camera process (the SITL's
//! renderer, or any driver a user writes) hands grey images to
//! `cmsckf-frontend` over a Unix socket. Both ends share this one
//! definition, so they cannot drift apart.
//!
//! A frame is a 24-byte header and then `width × height` bytes of 8-bit
//! grey, row-major, top row first:
//!
//! | bytes | field                                   |
//! |-------|-----------------------------------------|
//! | 0–7   | magic `CMSKIMG1` (the version is its last byte) |
//! | 8–15  | `t_us`: the exposure's stamp (µs, u64 LE), on the clock the daemon's `features.clock` names |
//! | 16–19 | `width` (px, u32 LE)                    |
//! | 20–23 | `height` (px, u32 LE)                   |

/// The header's first eight bytes.
pub const MAGIC: [u8; 8] = *b"CMSKIMG1";
/// The header's length (bytes).
pub const HEADER_BYTES: usize = 24;
/// Largest side accepted (px): a bound on what a reader allocates.
pub const MAX_SIDE_PX: u32 = 8192;

/// One frame's header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameHeader {
    pub t_us: u64,
    pub width: u32,
    pub height: u32,
}

/// Why a header was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FrameHeaderError {
    #[error("not an image frame: the magic is {0:02x?}, expected \"CMSKIMG1\"")]
    Magic([u8; 8]),
    #[error("image of {width}x{height} px: each side must be 1..={MAX_SIDE_PX}")]
    Size { width: u32, height: u32 },
}

impl FrameHeader {
    /// The header's bytes.
    pub fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut b = [0u8; HEADER_BYTES];
        b[..8].copy_from_slice(&MAGIC);
        b[8..16].copy_from_slice(&self.t_us.to_le_bytes());
        b[16..20].copy_from_slice(&self.width.to_le_bytes());
        b[20..24].copy_from_slice(&self.height.to_le_bytes());
        b
    }

    /// Reads a header, checking its magic and its size.
    pub fn decode(b: &[u8; HEADER_BYTES]) -> Result<Self, FrameHeaderError> {
        let word = |r: std::ops::Range<usize>| {
            let mut w = [0u8; 4];
            w.copy_from_slice(&b[r]);
            u32::from_le_bytes(w)
        };
        let mut magic = [0u8; 8];
        magic.copy_from_slice(&b[..8]);
        if magic != MAGIC {
            return Err(FrameHeaderError::Magic(magic));
        }
        let mut t = [0u8; 8];
        t.copy_from_slice(&b[8..16]);
        let (width, height) = (word(16..20), word(20..24));
        if !(1..=MAX_SIDE_PX).contains(&width) || !(1..=MAX_SIDE_PX).contains(&height) {
            return Err(FrameHeaderError::Size { width, height });
        }
        Ok(Self {
            t_us: u64::from_le_bytes(t),
            width,
            height,
        })
    }

    /// Bytes of grey that follow the header.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_header_round_trips_and_bad_ones_are_refused() {
        let h = FrameHeader {
            t_us: 20_000_123,
            width: 752,
            height: 480,
        };
        assert_eq!(FrameHeader::decode(&h.encode()), Ok(h));
        assert_eq!(h.pixels(), 752 * 480);
        let mut bad = h.encode();
        bad[0] = b'X';
        assert!(matches!(FrameHeader::decode(&bad), Err(FrameHeaderError::Magic(_))));
        let huge = FrameHeader { width: 100_000, ..h }.encode();
        assert_eq!(
            FrameHeader::decode(&huge),
            Err(FrameHeaderError::Size {
                width: 100_000,
                height: 480
            })
        );
        let empty = FrameHeader { height: 0, ..h }.encode();
        assert!(FrameHeader::decode(&empty).is_err());
    }
}
