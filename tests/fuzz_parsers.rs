//! Mutation fuzzing of every parser of outside input, in CI: feature-socket
//! lines, RTCM3 framing and decoding, GPS_RTCM_DATA reassembly, config files
//! and MAVLink frames into the adapter. Valid inputs are mutated (byte flips,
//! inserts, deletions, splices, truncations, random bytes) by a seeded RNG;
//! no input may panic, and buffers stay bounded.
//!
//! `CMSCKF_FUZZ_ITERS` sets the inputs per parser (default 20 000 in CI;
//! docs/reliability figures use 1 000 000).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use cmsckf::config::Config;
use cmsckf::gnss::reassembly::{Reassembled, Reassembler};
use cmsckf::gnss::rtcm::RtcmDecoder;

fn iters() -> usize {
    std::env::var("CMSCKF_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000)
}

fn mutate(rng: &mut ChaCha8Rng, seed: &[u8], max_len: usize) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..rng.random_range(1..8) {
        match rng.random_range(0..6) {
            0 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v[i] ^= 1 << rng.random_range(0..8);
            }
            1 if v.len() < max_len => {
                let i = rng.random_range(0..=v.len());
                v.insert(i, rng.random());
            }
            2 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v.remove(i);
            }
            3 if !v.is_empty() => {
                let n = rng.random_range(0..=v.len());
                v.truncate(n);
            }
            4 if !v.is_empty() => {
                let (a, b) = (rng.random_range(0..v.len()), rng.random_range(0..v.len()));
                let (lo, hi) = (a.min(b), a.max(b));
                let chunk = v[lo..hi].to_vec();
                let at = rng.random_range(0..=v.len());
                if v.len() + chunk.len() <= max_len {
                    v.splice(at..at, chunk);
                }
            }
            _ => {
                let i = rng.random_range(0..=v.len());
                let junk: Vec<u8> = (0..rng.random_range(0..16)).map(|_| rng.random()).collect();
                if v.len() + junk.len() <= max_len {
                    v.splice(i..i, junk);
                }
            }
        }
    }
    v
}

#[test]
fn feature_lines() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut long = String::from("{\"v\":1,\"t_us\":123,\"cam\":0,\"features\":[");
    for i in 0..50 {
        long += &format!("{}[{},{}.5,{}.25]", if i > 0 { "," } else { "" }, i, i * 3, i * 2);
    }
    long += "]}";
    let seeds = [
        br#"{"v":1,"t_us":1000,"cam":0,"features":[[1,10.5,20.0,0.06],[2,30,40]]}"#.to_vec(),
        long.into_bytes(),
    ];
    let (mut ok, mut err) = (0, 0);
    for k in 0..iters() {
        let s = mutate(&mut rng, &seeds[k % 2], 4096);
        match cmsckf::io::feature_pipe::parse_line(&s, 100) {
            Ok(f) => {
                assert!(f.features.len() <= 100);
                assert!(f.features.iter().all(|x| x.u_px.is_finite() && x.v_px.is_finite()));
                assert!(f
                    .features
                    .iter()
                    .all(|x| x.sigma_px.is_none_or(|s| (1e-3..=1e3).contains(&s))));
                ok += 1;
            }
            Err(_) => err += 1,
        }
    }
    eprintln!("feature lines: {} inputs, {ok} accepted, {err} rejected", iters());
    assert!(ok > 0 && err > 0);
}

#[test]
fn rtcm_stream() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let real = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join("GMSD7_20121014.rtcm3"),
    )
    .unwrap();
    let mut dec = RtcmDecoder::new();
    let mut out = Vec::new();
    let mut frames = 0u64;
    for _ in 0..iters() {
        let start = rng.random_range(0..real.len() - 2048);
        let seed = &real[start..start + rng.random_range(1..2048)];
        let s = mutate(&mut rng, seed, 4096);
        for piece in s.chunks(rng.random_range(1..600)) {
            dec.push(piece, &mut out);
            assert!(dec.buffered() <= 2 * 1029 + 1029, "decoder buffer {}", dec.buffered());
        }
        frames += out.len() as u64;
        out.clear();
    }
    eprintln!(
        "RTCM: {} inputs, {frames} messages decoded, {} CRC failures, {} bytes skipped",
        iters(),
        dec.stats.crc_failures,
        dec.stats.bytes_skipped
    );
    assert!(dec.stats.crc_failures > 0 && frames > 0);
}

/// CRC-24Q (RTCM 10403, Qualcomm's polynomial 0x1864CFB) of `bytes`.
fn crc24q(bytes: &[u8]) -> u32 {
    let mut crc = 0u32;
    for &b in bytes {
        crc ^= (b as u32) << 16;
        for _ in 0..8 {
            crc <<= 1;
            if crc & 0x100_0000 != 0 {
                crc ^= 0x186_4CFB;
            }
        }
    }
    crc & 0xFF_FFFF
}

/// Legacy (1004/1012/1005/1019/1020) and MSM7 frames with their payload
/// bits flipped and the CRC made good again, so that the decoder's
/// conversions, the receiver model, a base station and the differential
/// solution see hostile values (absurd codes and times, changed ids, NaN
/// where a field allows it), rover and base alike: nothing may panic.
#[test]
fn rtcm_payloads_with_good_crcs() {
    use cmsckf::gnss::spp::SppOptions;
    use cmsckf::gnss::{IonoMode, Receiver};
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let frames_of = |name: &str| -> Vec<Vec<u8>> {
        let b = std::fs::read(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data")
                .join(name),
        )
        .unwrap();
        let mut out = Vec::new();
        let mut i = 0;
        while i + 6 <= b.len() {
            if b[i] != 0xD3 {
                i += 1;
                continue;
            }
            let len = (((b[i + 1] & 3) as usize) << 8 | b[i + 2] as usize) + 6;
            if i + len > b.len() {
                break;
            }
            out.push(b[i..i + len].to_vec());
            i += len;
        }
        out
    };
    let mut frames = frames_of("testglo.rtcm3");
    frames.extend(frames_of("0759_base_msm7.rtcm3"));
    let opts = SppOptions {
        elevation_mask_deg: 10.0,
        iono: IonoMode::Auto,
        systems: cmsckf::gnss::parse_systems("G,E,R").unwrap(),
    };
    let mut rx = Receiver::new(opts, 1562, 0);
    let (mut dec, mut msgs, mut epochs) = (RtcmDecoder::new(), Vec::new(), Vec::new());
    let n = iters() / 4;
    for k in 0..n {
        let mut f = frames[rng.random_range(0..frames.len())].clone();
        let payload_bits = (f.len() - 6) * 8;
        for _ in 0..rng.random_range(0..4) {
            let bit = 24 + rng.random_range(0..payload_bits);
            f[bit / 8] ^= 0x80 >> (bit % 8);
        }
        let crc = crc24q(&f[..f.len() - 3]);
        let l = f.len();
        f[l - 3..].copy_from_slice(&[(crc >> 16) as u8, (crc >> 8) as u8, crc as u8]);
        dec.push(&f, &mut msgs);
        for m in msgs.drain(..) {
            // Every other message is taken as a base's.
            if k % 2 == 0 {
                rx.push(m, &mut epochs);
            } else {
                rx.push_base(m);
            }
        }
        epochs.clear();
    }
    rx.flush(&mut epochs);
    eprintln!(
        "RTCM payloads: {n} frames, {} epochs solved, {} differential, {} undecodable",
        rx.stats.solved, rx.stats.dgnss_solved, dec.stats.undecodable
    );
    assert_eq!(dec.stats.crc_failures, 0);
    assert!(rx.stats.epochs > 0, "epochs were assembled from the mutated frames");
}

/// Mutated slices of the real u-blox log (UBX frames among NMEA) through
/// the UBX decoder in random pieces: no panic, a bounded buffer, frames
/// decoded and checksum failures counted.
#[test]
fn ubx_stream() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let real = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join("ubx_20080526.ubx"),
    )
    .unwrap();
    let mut dec = cmsckf::gnss::ubx::UbxDecoder::new();
    let mut out = Vec::new();
    let mut frames = 0u64;
    for _ in 0..iters() {
        let start = rng.random_range(0..real.len() - 4096);
        let seed = &real[start..start + rng.random_range(1..4096)];
        let s = mutate(&mut rng, seed, 8192);
        for piece in s.chunks(rng.random_range(1..600)) {
            dec.push(piece, &mut out);
            assert!(
                dec.buffered() <= 3 * (16 + 32 * 255 + 8),
                "decoder buffer {}",
                dec.buffered()
            );
        }
        frames += out.len() as u64;
        out.clear();
    }
    let good: u64 = dec.stats.frames_by_id.values().sum();
    eprintln!(
        "UBX: {} inputs, {good} good frames, {frames} messages, {} checksum failures, {} malformed, {} bytes skipped",
        iters(),
        dec.stats.checksum_failures,
        dec.stats.malformed,
        dec.stats.bytes_skipped
    );
    assert!(dec.stats.checksum_failures > 0 && frames > 0);
}

#[test]
fn rtcm_fragments() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut r = Reassembler::new();
    let (mut msgs, mut dropped) = (0u64, 0u64);
    for _ in 0..iters() {
        let flags: u8 = rng.random();
        let len = if rng.random_bool(0.5) {
            180
        } else {
            rng.random_range(0..=200)
        };
        let data: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        let mut res = r.push(flags, &data);
        loop {
            match res {
                Reassembled::Message(m) => {
                    assert!(m.len() <= 4 * 180);
                    msgs += 1;
                    break;
                }
                Reassembled::Dropped { then, .. } => {
                    dropped += 1;
                    res = *then;
                }
                _ => break,
            }
        }
    }
    eprintln!(
        "GPS_RTCM_DATA: {} fragments, {msgs} messages, {dropped} sequences dropped",
        iters()
    );
    assert!(msgs > 0 && dropped > 0);
}

#[test]
fn config_files() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let seed = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/config/default.toml")).unwrap();
    let (mut ok, mut err) = (0, 0);
    for _ in 0..iters() {
        let s = mutate(&mut rng, &seed, 16_384);
        match Config::from_toml(&String::from_utf8_lossy(&s), "fuzz") {
            Ok(c) => {
                c.validate().unwrap();
                ok += 1;
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                err += 1;
            }
        }
    }
    eprintln!("config: {} inputs, {ok} valid, {err} rejected", iters());
    assert!(err > 0);
}

#[test]
fn mavlink_frames() {
    use cmsckf::io::mavlink::{decode_bytes, encode_bytes};
    use cmsckf::io::messages::Outbound;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let seeds = [
        encode_bytes(
            &Outbound::Heartbeat {
                initialised: true,
                degraded: false,
            },
            1,
        ),
        encode_bytes(&Outbound::TimesyncRequest { ts1_ns: 12345 }, 2),
        encode_bytes(
            &Outbound::VisionPositionEstimate {
                t_us: 1,
                p_ned_m: nalgebra::Vector3::new(1.0, 2.0, 3.0),
                rpy_rad: nalgebra::Vector3::zeros(),
                covariance: [0.1; 21],
                reset_counter: 0,
            },
            3,
        ),
    ];
    let (mut ok, mut err) = (0u64, 0u64);
    for k in 0..iters() {
        let mut s = mutate(&mut rng, &seeds[k % seeds.len()], 1024);
        if rng.random_bool(0.3) {
            s.extend(seeds[(k + 1) % seeds.len()].iter());
        }
        for r in decode_bytes(&s) {
            if r.is_ok() {
                ok += 1;
            } else {
                err += 1;
            }
        }
    }
    eprintln!("MAVLink: {} inputs, {ok} messages decoded, {err} rejected", iters());
    assert!(ok > 0);
}
