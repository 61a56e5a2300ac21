//! GPS LNAV navigation-message subframes 1–3 into a broadcast ephemeris
//! (IS-GPS-200 20.3.3.3 and 20.3.3.4): what a u-blox receiver's RXM-SFRB(X)
//! carries instead of RTCM 1019, so that a receiver on the companion brings
//! its own orbits.
//!
//! A subframe here is ten 24-bit words with the parity removed, packed
//! big-endian into 30 bytes: bit 0 is the first bit (D1) of word 1, the TLM
//! word, and word `k` holds bits `24(k−1) .. 24k−1`. Field positions below
//! are in that numbering, scales as in the ICD (angles in semicircles).

use std::collections::BTreeMap;

use cmsckf_models::gnss::{BroadcastEphemeris, System};

use super::rtcm::RawEph;

/// The TLM word's preamble.
const PREAMBLE: u32 = 0x8B;
/// IS-GPS-200's π, by which semicircles become radians.
const SC: f64 = std::f64::consts::PI;

/// One subframe: ten 24-bit words, parity removed.
pub type Subframe = [u32; 10];

/// `len` bits (≤ 32) from bit `pos` of a subframe, unsigned.
fn bits(sf: &Subframe, pos: usize, len: usize) -> u32 {
    let mut v: u64 = 0;
    for b in pos..pos + len {
        let word = sf[b / 24];
        let bit = (word >> (23 - b % 24)) & 1;
        v = (v << 1) | bit as u64;
    }
    v as u32
}

/// `len` bits from bit `pos`, two's complement.
fn sbits(sf: &Subframe, pos: usize, len: usize) -> i64 {
    let v = bits(sf, pos, len) as i64;
    if v >> (len - 1) & 1 == 1 {
        v - (1i64 << len)
    } else {
        v
    }
}

/// `v · 2^pow2`: a field in its ICD units.
fn scaled(v: i64, pow2: i32) -> f64 {
    v as f64 * 2f64.powi(pow2)
}

/// The subframe id in the HOW word (1–5), if the TLM preamble is there.
pub fn subframe_id(sf: &Subframe) -> Option<u8> {
    if bits(sf, 0, 8) != PREAMBLE {
        return None;
    }
    Some(bits(sf, 43, 3) as u8)
}

/// Subframes 1, 2 and 3 of each satellite, kept until they make an
/// ephemeris of one issue (IODC's low 8 bits = IODE in 2 = IODE in 3).
#[derive(Default)]
pub struct LnavAssembler {
    by_prn: BTreeMap<u8, [Option<Subframe>; 3]>,
    /// The last ephemeris issued per satellite (IODE, toe), so that a
    /// repeated broadcast is not issued again.
    issued: BTreeMap<u8, (u16, f64)>,
    /// Subframes whose TLM preamble was wrong.
    pub bad_preamble: u64,
    /// Complete sets whose issues did not agree (a new upload mid-set).
    pub mismatched_issue: u64,
}

impl LnavAssembler {
    /// Feeds one subframe of GPS satellite `prn`; returns a new ephemeris
    /// when it completes one.
    pub fn push(&mut self, prn: u8, sf: Subframe) -> Option<RawEph> {
        if !(1..=32).contains(&prn) {
            return None;
        }
        let Some(id) = subframe_id(&sf) else {
            self.bad_preamble += 1;
            return None;
        };
        if !(1..=3).contains(&id) {
            return None;
        }
        let set = self.by_prn.entry(prn).or_default();
        set[id as usize - 1] = Some(sf);
        let [Some(s1), Some(s2), Some(s3)] = *set else {
            return None;
        };
        let iodc = (bits(&s1, 70, 2) << 8) | bits(&s1, 168, 8);
        let (iode2, iode3) = (bits(&s2, 48, 8), bits(&s3, 216, 8));
        if iode2 != iode3 || iode2 != iodc & 0xFF {
            self.mismatched_issue += 1;
            return None;
        }
        let raw = decode(prn, &s1, &s2, &s3);
        let key = (raw.eph.iode, raw.eph.toe_s);
        if self.issued.get(&prn) == Some(&key) {
            return None;
        }
        self.issued.insert(prn, key);
        Some(raw)
    }
}

/// The ephemeris of subframes 1–3 of one issue (IS-GPS-200 Tables 20-I to
/// 20-III). The week is left as broadcast (10 bits), moved to `toe`'s week
/// when `toe` is in the week after the transmission time.
fn decode(prn: u8, s1: &Subframe, s2: &Subframe, s3: &Subframe) -> RawEph {
    let tow_tx_s = bits(s1, 24, 17) as f64 * 6.0;
    let toe_s = bits(s2, 216, 16) as f64 * 16.0;
    let mut week = bits(s1, 48, 10) as u16;
    if toe_s < tow_tx_s - 302_400.0 {
        week = (week + 1) % 1024;
    }
    let tgd_raw = sbits(s1, 160, 8);
    let eph = BroadcastEphemeris {
        system: System::Gps,
        prn,
        week: week as u32,
        iode: bits(s2, 48, 8) as u16,
        iodc: ((bits(s1, 70, 2) << 8) | bits(s1, 168, 8)) as u16,
        toc_s: bits(s1, 176, 16) as f64 * 16.0,
        af2_per_s: scaled(sbits(s1, 192, 8), -55),
        af1: scaled(sbits(s1, 200, 16), -43),
        af0_s: scaled(sbits(s1, 216, 22), -31),
        // −128 is "not available" (IS-QZSS); take it as no delay.
        tgd_s: if tgd_raw == -128 { 0.0 } else { scaled(tgd_raw, -31) },
        health: bits(s1, 64, 6) as u8,
        ura_index: bits(s1, 60, 4) as u8,
        crs_m: scaled(sbits(s2, 56, 16), -5),
        delta_n_radps: scaled(sbits(s2, 72, 16), -43) * SC,
        m0_rad: scaled(sbits(s2, 88, 32), -31) * SC,
        cuc_rad: scaled(sbits(s2, 120, 16), -29),
        e: scaled(bits(s2, 136, 32) as i64, -33),
        cus_rad: scaled(sbits(s2, 168, 16), -29),
        sqrt_a: scaled(bits(s2, 184, 32) as i64, -19),
        toe_s,
        fit_interval_4h: bits(s2, 232, 1) == 0,
        cic_rad: scaled(sbits(s3, 48, 16), -29),
        omega0_rad: scaled(sbits(s3, 64, 32), -31) * SC,
        cis_rad: scaled(sbits(s3, 96, 16), -29),
        i0_rad: scaled(sbits(s3, 112, 32), -31) * SC,
        crc_m: scaled(sbits(s3, 144, 16), -5),
        omega_rad: scaled(sbits(s3, 160, 32), -31) * SC,
        omega_dot_radps: scaled(sbits(s3, 192, 24), -43) * SC,
        idot_radps: scaled(sbits(s3, 224, 14), -43) * SC,
    };
    RawEph { week_field: week, eph }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Writes `len` bits of `v` at `pos` (the encoder of the tests).
    pub(in crate::gnss) fn put(sf: &mut Subframe, pos: usize, len: usize, v: i64) {
        for k in 0..len {
            let bit = ((v >> (len - 1 - k)) & 1) as u32;
            let b = pos + k;
            let shift = 23 - b % 24;
            sf[b / 24] = (sf[b / 24] & !(1 << shift)) | (bit << shift);
        }
    }

    /// Bits round-trip through the word packing, signed and unsigned, and
    /// across word boundaries.
    #[test]
    fn bit_fields_cross_words() {
        let mut sf = [0u32; 10];
        put(&mut sf, 88, 32, -123_456_789);
        put(&mut sf, 136, 32, 0xDEAD_BEEF);
        put(&mut sf, 224, 14, -5);
        assert_eq!(sbits(&sf, 88, 32), -123_456_789);
        assert_eq!(bits(&sf, 136, 32), 0xDEAD_BEEF);
        assert_eq!(sbits(&sf, 224, 14), -5);
        assert!(sf.iter().all(|w| *w < 1 << 24));
    }

    /// A set of subframes whose issues disagree makes no ephemeris, nor does
    /// a subframe without the preamble; a repeated broadcast is issued once.
    #[test]
    fn issues_must_agree_and_repeats_are_dropped() {
        let mut sfs = [[0u32; 10]; 3];
        for (k, sf) in sfs.iter_mut().enumerate() {
            put(sf, 0, 8, 0x8B);
            put(sf, 43, 3, k as i64 + 1);
        }
        put(&mut sfs[0], 168, 8, 7);
        put(&mut sfs[1], 48, 8, 7);
        put(&mut sfs[2], 216, 8, 8);
        let mut a = LnavAssembler::default();
        assert!(a.push(5, sfs[0]).is_none() && a.push(5, sfs[1]).is_none() && a.push(5, sfs[2]).is_none());
        assert_eq!(a.mismatched_issue, 1);
        put(&mut sfs[2], 216, 8, 7);
        assert!(a.push(5, sfs[2]).is_some());
        assert!(a.push(5, sfs[2]).is_none(), "the same issue again");
        let mut bad = sfs[0];
        put(&mut bad, 0, 8, 0x8A);
        assert!(a.push(5, bad).is_none());
        assert_eq!(a.bad_preamble, 1);
    }
}
