//! Hostile and damaged flight logs, as a user would open them with
//! `cmsckf review`, `replay` and `log recover`: each reproducer of the issue
//! (a 2⁶⁰-byte declared length, a zstd bomb, a damaged chunk length in a
//! finished log, a ULog or a TOML file given as a log) gets a clear error or
//! a bounded read, never an abort or gigabytes of memory; and a fuzzer
//! mutates the length fields of a real log through the same readers.

use std::path::{Path, PathBuf};
use std::process::Command;

use cmsckf::io::mcap_log::{check_bytes, McapLogger, Topic, MCAP_MAGIC};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn rec(op: u8, body: &[u8]) -> Vec<u8> {
    let mut r = vec![op];
    r.extend_from_slice(&(body.len() as u64).to_le_bytes());
    r.extend_from_slice(body);
    r
}

fn string(s: &str) -> Vec<u8> {
    let mut r = (s.len() as u32).to_le_bytes().to_vec();
    r.extend_from_slice(s.as_bytes());
    r
}

fn header() -> Vec<u8> {
    rec(0x01, &[string(""), string("hostile")].concat())
}

/// A chunk record holding `records`, compressed with zstd if `zstd`, that
/// declares `declared` bytes uncompressed.
fn chunk(records: &[u8], declared: u64, zstd: bool) -> Vec<u8> {
    let data = if zstd {
        zstd::bulk::compress(records, 19).unwrap()
    } else {
        records.to_vec()
    };
    let mut b = Vec::new();
    b.extend_from_slice(&0u64.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    b.extend_from_slice(&declared.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&string(if zstd { "zstd" } else { "" }));
    b.extend_from_slice(&(data.len() as u64).to_le_bytes());
    b.extend_from_slice(&data);
    rec(0x06, &b)
}

/// What running `cmsckf ARGS` did: exit code (None: killed by a signal),
/// stderr, and the peak memory of the largest child so far (KiB).
fn run(args: &[&str]) -> (Option<i32>, String, i64) {
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(args)
        .env("RUST_LOG", "warn")
        .env("NO_COLOR", "1")
        .output()
        .unwrap();
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) };
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        ru.ru_maxrss,
    )
}

/// The hostile files of the issue.
fn hostile_files(dir: &Path) -> Vec<(PathBuf, &'static str)> {
    let mut files = Vec::new();
    let mut put = |name: &str, bytes: Vec<u8>, what: &'static str| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        files.push((p, what));
    };
    let huge = (1u64 << 60) + 9;
    // A top-level record declaring 2⁶⁰ bytes.
    let mut b = [&MCAP_MAGIC[..], &header()].concat();
    b.push(0x03);
    b.extend_from_slice(&huge.to_le_bytes());
    b.extend_from_slice(&[0; 20]);
    put("huge_record.mcap", b, "a record declaring 2^60 bytes");
    // A record inside a chunk declaring 2⁶⁰ bytes.
    let mut inner = vec![0x05];
    inner.extend_from_slice(&huge.to_le_bytes());
    inner.extend_from_slice(&[0; 8]);
    let b = [
        &MCAP_MAGIC[..],
        &header(),
        &chunk(&inner, inner.len() as u64, false),
        &MCAP_MAGIC[..],
    ]
    .concat();
    put("huge_inner.mcap", b, "a record inside a chunk declaring 2^60 bytes");
    // A schema whose name declares 4 GiB.
    let mut sch = 1u16.to_le_bytes().to_vec();
    sch.extend_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    sch.extend_from_slice(b"abc");
    let b = [&MCAP_MAGIC[..], &header(), &rec(0x03, &sch), &MCAP_MAGIC[..]].concat();
    put("huge_string.mcap", b, "a schema name declaring 4 GiB");
    // A zstd bomb: 6 KB that declares and holds 200 MB.
    let zeros = vec![0u8; 200 << 20];
    let b = [
        &MCAP_MAGIC[..],
        &header(),
        &chunk(&zeros, 200 << 20, true),
        &MCAP_MAGIC[..],
    ]
    .concat();
    put("zstd_bomb.mcap", b, "a 6 KB chunk declaring 200 MB");
    // A chunk that declares 1 MB and holds 200 MB of zstd.
    let b = [
        &MCAP_MAGIC[..],
        &header(),
        &chunk(&zeros, 1 << 20, true),
        &MCAP_MAGIC[..],
    ]
    .concat();
    put("zstd_lies.mcap", b, "a chunk holding more than it declares");
    // Eight chunks each holding one 48 MB message (under the cap: read,
    // one chunk at a time).
    let mut msg = vec![0x05];
    msg.extend_from_slice(&((48u64 << 20) - 9).to_le_bytes());
    msg.resize(48 << 20, 0);
    let c = chunk(&msg, msg.len() as u64, true);
    let b = [&MCAP_MAGIC[..], &header(), &c.repeat(8), &MCAP_MAGIC[..]].concat();
    put("big_messages.mcap", b, "eight 48 MB messages in 6 KB chunks");
    drop(zeros);
    files
}

#[test]
fn hostile_logs_get_an_error_or_a_bounded_read_never_an_abort() {
    let dir = tempfile::tempdir().unwrap();
    for (p, what) in hostile_files(dir.path()) {
        let size = std::fs::metadata(&p).unwrap().len();
        let f = p.to_str().unwrap();
        let out = dir.path().join("out.mcap");
        let _ = std::fs::remove_file(&out);
        let o = out.to_str().unwrap();
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "").unwrap();
        for args in [
            vec!["review", f, "--json"],
            vec!["log", "recover", f, o],
            vec!["replay", f, "--out", o, "--force", "--config", cfg.to_str().unwrap()],
        ] {
            let (code, stderr, rss_kib) = run(&args);
            eprintln!(
                "{what} ({size} B): {} -> exit {code:?}, peak {} MiB; {}",
                args[0],
                rss_kib >> 10,
                stderr.lines().last().unwrap_or("")
            );
            assert!(
                code.is_some(),
                "{what}: `{}` was killed by a signal: {stderr}",
                args.join(" ")
            );
            assert!(!stderr.contains("memory allocation"), "{what}: {stderr}");
            assert!(
                rss_kib < 600 << 10,
                "{what}: `{}` took {} MiB",
                args.join(" "),
                rss_kib >> 10
            );
        }
    }
}

/// A log written by the daemon's logger: many chunks, with its summary.
fn real_log(path: &Path) -> u64 {
    let f = std::fs::File::create(path).unwrap();
    let header = cmsckf::io::mcap_log::LogHeader {
        version: "test".into(),
        mode: "compressed".into(),
        config_toml: String::new(),
    };
    let log = McapLogger::create(f, path, &header).unwrap().blocking();
    let n = 3000u64;
    for k in 0..n {
        // 1 s of sensor time per chunk: 30 chunks.
        log.log(
            Topic::InputImu,
            20.0 + k as f64 * 0.01,
            &serde_json::json!({"t_us": 20_000_000 + k * 10_000, "accel_mps2": [0.0, 0.0, -9.81], "gyro_radps": [0.0, 0.0, 0.0]}),
        );
    }
    log.finish().unwrap();
    n
}

/// The issue: one damaged size field in the first chunk of a finished log
/// made `log recover` keep 0 of its messages, although the summary indexes
/// every chunk. Now only that chunk's messages are lost.
#[test]
fn a_damaged_chunk_length_loses_that_chunk_only() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    let n = real_log(&good);
    let mut bytes = std::fs::read(&good).unwrap();
    // The first chunk after the header: its record length, made absurd.
    let mut pos = MCAP_MAGIC.len();
    let mut chunks_seen = 0;
    let mut damaged = None;
    while pos + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == 0x06 {
            chunks_seen += 1;
            // The second chunk: the first holds the schemas and channels,
            // which the summary repeats; the second holds messages.
            if chunks_seen == 2 {
                damaged = Some(pos);
                break;
            }
        }
        pos += 9 + len;
    }
    let at = damaged.expect("a second chunk");
    bytes[at + 1..at + 9].copy_from_slice(&(u64::MAX / 3).to_le_bytes());
    let bad = dir.path().join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    let fixed = dir.path().join("fixed.mcap");
    let r = cmsckf::io::mcap_log::recover(&bad, &fixed, false).unwrap();
    eprintln!("{r:?}");
    assert!(r.chunks_from_summary >= 25, "{r:?}");
    // One chunk (about a second, 100 records) is lost, no more.
    assert!(r.messages_kept >= n - 120, "kept {} of {n}", r.messages_kept);
    let rv = cmsckf::review::review(&fixed, None, None, None).unwrap();
    assert_eq!(rv.messages, r.messages_kept);
    // Review and replay read the damaged file itself the same way.
    let rv = cmsckf::review::review(&bad, None, None, None).unwrap();
    assert_eq!(rv.messages, r.messages_kept);
    assert_eq!(rv.log_check.chunks_from_summary, r.chunks_from_summary);
    // And the first chunk damaged: the schemas and channels come from the
    // summary.
    let mut bytes = std::fs::read(&good).unwrap();
    let first = MCAP_MAGIC.len()
        + 9
        + u64::from_le_bytes(bytes[MCAP_MAGIC.len() + 1..MCAP_MAGIC.len() + 9].try_into().unwrap()) as usize;
    // Skip the header (and the metadata, if it comes before) to the first chunk.
    let mut pos = first;
    while bytes[pos] != 0x06 {
        pos += 9 + u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
    }
    bytes[pos + 1..pos + 9].copy_from_slice(&(1u64 << 62).to_le_bytes());
    std::fs::write(&bad, &bytes).unwrap();
    let fixed2 = dir.path().join("fixed2.mcap");
    let r = cmsckf::io::mcap_log::recover(&bad, &fixed2, false).unwrap();
    assert!(r.messages_kept >= n - 120 && r.channels > 0, "{r:?}");
}

#[test]
fn what_is_not_a_log_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes, says) in [
        (
            "flight.ulg",
            [&b"ULog\x01\x12\x35\x01"[..], &[7u8; 500][..]].concat(),
            "PX4 ULog",
        ),
        ("cmsckf.toml", b"[log]\npath = \"x.mcap\"\n".to_vec(), "text file"),
        (
            "random.bin",
            (0..5000u32)
                .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
                .collect(),
            "binary data",
        ),
        ("empty.mcap", Vec::new(), "empty file"),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let (code, stderr, _) = run(&["review", p.to_str().unwrap()]);
        assert_eq!(code, Some(1), "{name}: {stderr}");
        assert!(
            stderr.contains("not an MCAP flight log") && stderr.contains(says),
            "{name}: {stderr}"
        );
        let (code, stderr, _) = run(&[
            "log",
            "recover",
            p.to_str().unwrap(),
            dir.path().join("o.mcap").to_str().unwrap(),
        ]);
        assert_eq!(code, Some(1), "{name}: {stderr}");
    }
}

/// Random damage to a real log's length fields and bytes, through the check
/// and every reader the tools use: no panic, no abort, and whatever passes
/// the check reads without error-free garbage sizes.
#[test]
fn mutated_logs_never_panic_the_readers() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    real_log(&good);
    let seed = std::fs::read(&good).unwrap();
    let iters: usize = std::env::var("CMSCKF_FUZZ_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .map_or(300, |n: usize| n / 50);
    let mut rng = ChaCha8Rng::seed_from_u64(39);
    for _ in 0..iters.max(50) {
        let mut b = seed.clone();
        for _ in 0..rng.random_range(1..4) {
            let at = rng.random_range(0..b.len());
            match rng.random_range(0..3) {
                // A length-like field: 8 bytes of something large.
                0 if at + 8 <= b.len() => {
                    let v: u64 = match rng.random_range(0..3) {
                        0 => rng.random(),
                        1 => rng.random_range(0..1 << 32),
                        _ => u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
                            .wrapping_add(rng.random_range(1..4096)),
                    };
                    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
                }
                1 => b[at] = rng.random(),
                _ => b.truncate(at.max(MCAP_MAGIC.len())),
            }
        }
        let Ok(checked) = check_bytes(b) else { continue };
        let bytes = checked.bytes;
        let _ = cmsckf::io::mcap_log::input::cmsckf_metadata(&bytes);
        let _ = mcap::Summary::read(&bytes);
        if let Ok(stream) = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into()) {
            for m in stream {
                if m.is_err() {
                    break;
                }
            }
        }
    }
}

/// Red-team 17: a log the daemon's logger writes checks out whole (its
/// statistics record included), so readers use the file and its summary as
/// they are.
#[test]
fn a_real_log_checks_out_whole() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    real_log(&good);
    let c = check_bytes(std::fs::read(&good).unwrap()).unwrap();
    assert!(c.whole, "{:?}", c.report);
    assert!(c.report.chunks_dropped.is_empty());
}

/// Red-team 15/18: a small file whose chunks each declare the 64 MiB cap
/// (a 125 KB file took review to 2.7 GB): past 20 times the file's size
/// (at least 64 MiB) the chunks are a decompression bomb and are dropped.
#[test]
fn a_bomb_of_chunks_each_under_the_cap_is_bounded_in_total() {
    let dir = tempfile::tempdir().unwrap();
    let zeros = vec![0u8; 64 << 20];
    let c = chunk(&zeros, 64 << 20, true);
    drop(zeros);
    let b = [&MCAP_MAGIC[..], &header(), &c.repeat(40), &MCAP_MAGIC[..]].concat();
    let size = b.len();
    let checked = check_bytes(b).unwrap();
    let kept = checked.report.chunks_ok;
    eprintln!("{size} B file: {kept} of 40 chunks of 64 MiB kept");
    assert!(kept <= 1, "{kept} chunks kept: more than 64 MiB declared");
    assert!(checked
        .report
        .chunks_dropped
        .iter()
        .any(|(_, why)| why.contains("decompression bomb")));
    let p = dir.path().join("bomb.mcap");
    std::fs::write(&p, &checked.bytes).unwrap();
}

/// Red-team 01: `review --html` and `--tum` never write over the log they
/// review, nor over another file without --force.
#[test]
fn review_never_writes_over_its_log() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.mcap");
    real_log(&log);
    let before = std::fs::read(&log).unwrap();
    let l = log.to_str().unwrap();
    for args in [vec!["review", l, "--html", l], vec!["review", l, "--tum", l, "--force"]] {
        let (code, stderr, _) = run(&args);
        assert_eq!(code, Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains("is the log being reviewed"), "{stderr}");
    }
    let other = dir.path().join("notes.txt");
    std::fs::write(&other, "keep").unwrap();
    let (code, stderr, _) = run(&["review", l, "--html", other.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(std::fs::read_to_string(&other).unwrap(), "keep");
    assert_eq!(std::fs::read(&log).unwrap(), before);
}
