//! `cmsckf replay`: re-runs the fusion loop on the inputs of an MCAP flight
//! log and writes a new log.
//!
//! The daemon logs each input as its fusion loop consumes it, from that one
//! thread, so the file holds the inputs in the order they were used. Replay
//! feeds them through the same [`Fusion::handle`] in that order: with the
//! same mode and config, the estimates and filter events come out bit for bit
//! the same (only the wall time spent per update differs); with another mode
//! or config, the two logs can be compared.

use std::path::Path;
use std::sync::mpsc::SyncSender;
use std::time::Instant;

use nalgebra::Vector3;
use serde::Serialize;
use tokio::sync::mpsc;

use crate::config::{Config, FeatureClock};
use crate::counters::Counters;
use crate::daemon::{Ctx, Fusion, FusionMsg};
use crate::estimator::frontend::Normaliser;
use crate::estimator::ImuMeas;
use crate::estimator::Mode;
use crate::io::feature_pipe::FeatureFrame;
use crate::io::mcap_log::input::{
    cmsckf_metadata, log_format_of, AutopilotRecord, InputRecord, RecordError, FORMAT_TIME_ORDERED,
};
use crate::io::mcap_log::reorder::SequenceOrder;
use crate::io::mcap_log::{McapLogger, Topic};
use crate::io::messages::{Outbound, SimTruth};

/// Errors of a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("cannot read '{0}': {1}")]
    Io(String, std::io::Error),
    #[error("'{0}' is not a readable MCAP log: {1}")]
    Mcap(String, String),
    #[error("'{0}' has no cmsckf config in its header; give --config")]
    NoConfig(String),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Log(#[from] crate::io::mcap_log::LogError),
    #[error("'{0}': {1}")]
    Format(String, RecordError),
}

/// Inputs per batch handed from the reading thread to the fusion loop.
const REPLAY_BATCH: usize = 256;
/// Batches the reading thread may run ahead (bounds its memory).
const REPLAY_QUEUE_BATCHES: usize = 16;

/// Throughput of a replay.
#[derive(Clone, Debug, Serialize)]
pub struct ReplayReport {
    pub messages_in: u64,
    pub estimates_out: u64,
    pub flight_s: f64,
    pub wall_s: f64,
    pub realtime_factor: f64,
    /// Input records that did not parse, skipped (each named in a warning).
    pub malformed_inputs: u64,
    /// Inputs given to the fusion loop at or before the sequence number of
    /// one given before them: the log's sequences are not as cmsckf writes
    /// them (parts of a flight joined, a log sorted by another tool), so the
    /// replay may not follow the flight's order (said in a warning).
    pub out_of_sequence_inputs: u64,
}

/// The config stored in a log's `cmsckf` metadata record (as
/// [`cmsckf_metadata`] read it from the log `name`).
pub fn logged_config(metadata: &Metadata, name: &str) -> Result<Config, ReplayError> {
    let m = metadata
        .as_ref()
        .map_err(|e| ReplayError::Mcap(name.into(), e.to_string()))?;
    match m.as_ref().and_then(|m| m.get("config_toml")) {
        Some(t) => {
            let mut cfg = Config::from_toml(t, name)?;
            // A log from before the barometer was fused (its config has no
            // `[barometer]`) replays as it flew: without it.
            if !t.lines().any(|l| l.trim() == "[barometer]") {
                cfg.barometer.fuse = false;
            }
            Ok(cfg)
        }
        None => Err(ReplayError::NoConfig(name.into())),
    }
}

/// A log's `cmsckf` metadata as [`cmsckf_metadata`] reads it.
type Metadata = Result<Option<std::collections::BTreeMap<String, String>>, mcap::McapError>;

/// Turns one logged input back into what the fusion loop received.
fn to_msg(rec: InputRecord<'static>, normaliser: &Normaliser) -> FusionMsg {
    let v3 = Vector3::from;
    match rec {
        InputRecord::Imu(r) => FusionMsg::Imu(ImuMeas {
            t_s: r.t_us as f64 * 1e-6,
            accel_mps2: v3(r.accel_mps2),
            gyro_radps: v3(r.gyro_radps),
        }),
        InputRecord::Features(r) => {
            let fr = FeatureFrame {
                // The clock is already mapped: replay runs in autopilot time.
                t_us: r.t_ap_us.max(0) as u64,
                cam: r.cam,
                features: r.features.into_owned(),
            };
            // As the daemon does where a frame arrives: here, on the reader's thread.
            let norm = normaliser.frame(&fr.features);
            FusionMsg::Frame(fr, norm)
        }
        InputRecord::RebaseInstalled(r) => FusionMsg::RebaseInstalled { seq: r.seq },
        InputRecord::Rtcm(r) => FusionMsg::Rtcm {
            bytes: r.bytes.into_owned(),
            stream: r.stream,
        },
        InputRecord::SystemTime(r) => FusionMsg::SystemTime {
            unix_us: r.unix_us,
            boot_ms: r.boot_ms,
        },
        InputRecord::Autopilot(a) => match a {
            AutopilotRecord::Attitude([roll, pitch, yaw]) => FusionMsg::Attitude { roll, pitch, yaw },
            AutopilotRecord::Magnetometer(m) => FusionMsg::Magnetometer { mag_B: v3(m) },
            AutopilotRecord::Armed(a) => FusionMsg::VehicleState {
                armed: Some(a),
                on_ground: None,
                kind: None,
                mode: None,
            },
            AutopilotRecord::OnGround(g) => FusionMsg::VehicleState {
                armed: None,
                on_ground: Some(g),
                kind: None,
                mode: None,
            },
            AutopilotRecord::Autopilot(k) => FusionMsg::VehicleState {
                armed: None,
                on_ground: None,
                kind: Some(k),
                mode: None,
            },
            AutopilotRecord::UnixDays(unix_days) => FusionMsg::Date { unix_days },
            // Unknown accuracies are logged as null (NaN).
            AutopilotRecord::GpsAccuracy([h, v]) => FusionMsg::GpsAccuracy {
                h_acc_m: h.unwrap_or(f64::NAN),
                v_acc_m: v.unwrap_or(f64::NAN),
            },
            AutopilotRecord::Pressure(p) => FusionMsg::Pressure(p),
            AutopilotRecord::LocalPosition(l) => FusionMsg::LocalPosition {
                t_s: l.t_s,
                p_ned_m: v3(l.p_ned_m),
                v_ned_mps: v3(l.v_ned_mps),
            },
            AutopilotRecord::Origin([lat_deg, lon_deg, alt_m]) => FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            },
            AutopilotRecord::EstimatorStatus(s) => FusionMsg::EstimatorStatus(s),
            AutopilotRecord::Mode(m) => FusionMsg::VehicleState {
                armed: None,
                on_ground: None,
                kind: None,
                mode: Some(m),
            },
            AutopilotRecord::Param(p) => FusionMsg::AutopilotParam(crate::io::messages::ParamValue {
                name: p.name,
                raw: f32::from_bits(p.raw_bits),
                param_type: p.param_type,
            }),
            AutopilotRecord::StatusText(t) => FusionMsg::AutopilotText {
                severity: t.severity,
                text: t.text,
            },
            AutopilotRecord::SimState(s) => FusionMsg::SimState(SimTruth {
                lat_deg: s.lat_deg,
                lon_deg: s.lon_deg,
                alt_m: s.alt_m,
                q_wxyz: s.q_wxyz,
                v_ned_mps: v3(s.v_ned_mps),
            }),
        },
    }
}

/// The number of inputs in a log, from its summary's statistics (`None`
/// for a log without one, e.g. a killed daemon's).
fn input_total(bytes: &[u8]) -> Option<u64> {
    let summary = mcap::Summary::read(bytes).ok()??;
    let stats = summary.stats?;
    Some(
        summary
            .channels
            .iter()
            .filter(|(_, c)| Topic::from_name(&c.topic).is_some_and(Topic::is_input))
            .filter_map(|(id, _)| stats.channel_message_counts.get(id))
            .sum(),
    )
}

/// Replays `input` into `output`, under `mode` and `config` if given (else
/// the logged ones). `progress` gets the number of inputs replayed so far
/// and, when the log's summary gives it, their total.
pub fn replay(
    input: &Path,
    output: &Path,
    mode: Option<Mode>,
    config: Option<Config>,
    overwrite: bool,
    mut progress: impl FnMut(u64, Option<u64>),
) -> Result<ReplayReport, ReplayError> {
    let name = input.display().to_string();
    let checked = crate::io::mcap_log::read_checked(input).map_err(crate::io::mcap_log::LogError::from)?;
    checked.report.warn(&name);
    let bytes = checked.bytes;
    // Refused before anything is written, whichever config is replayed under.
    let metadata = cmsckf_metadata(&bytes);
    let format = log_format_of(metadata.as_ref().ok().and_then(Option::as_ref))
        .map_err(|e| ReplayError::Format(name.clone(), e))?;
    let time_ordered = format >= FORMAT_TIME_ORDERED;
    let total = input_total(&bytes);
    let cfg = replay_config(&metadata, &name, mode, config)?;
    // Never over the input (whatever `overwrite` says), nor over another
    // file unless asked.
    let file =
        crate::io::mcap_log::create_output(output, input, overwrite).map_err(crate::io::mcap_log::LogError::from)?;
    let log = McapLogger::create_stamped(file, output, &cfg.log_header())?.blocking();
    let (out_tx, mut out_rx) = tokio::sync::mpsc::channel(1024);
    let ctx = Ctx {
        counters: Counters::default(),
        out: out_tx,
        status: Default::default(),
        mono_offset_us: std::sync::Arc::new(std::sync::atomic::AtomicI64::new(i64::MIN)),
        start: Instant::now(),
    };
    let normaliser = Normaliser::new(&cfg.camera);
    let mut fusion = Fusion::new(cfg, Some(log)).for_replay();
    let start = Instant::now();
    let mut tally = Tally::new();
    let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
        .map_err(|e| ReplayError::Mcap(name.clone(), e.to_string()))?;
    // Reading the log (decompressing its chunks and parsing each input's
    // JSON) runs on a thread of its own, a batch at a time, so the fusion
    // loop here does nothing but fuse; the order is kept.
    let (batch_tx, batch_rx) = std::sync::mpsc::sync_channel::<Vec<FusionMsg>>(REPLAY_QUEUE_BATCHES);
    let malformed = std::thread::scope(|scope| {
        let reader = scope.spawn(move || read_inputs(stream, &normaliser, batch_tx, time_ordered));
        for batch in batch_rx {
            for msg in batch {
                tally.fuse(msg, &mut fusion, &ctx, &mut out_rx);
                if tally.n_in.is_multiple_of(4096) {
                    progress(tally.n_in, total);
                }
            }
        }
        // A reader that panicked must not pass for a log that ended.
        reader.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
    });
    fusion.finish_log(&ctx.counters);
    let mut report = tally.report(start.elapsed().as_secs_f64());
    let (malformed, out_of_sequence) = malformed;
    if out_of_sequence > 0 {
        tracing::warn!(
            out_of_sequence,
            "{name}: its sequence numbers are not as cmsckf writes them (joined or re-sorted?): \
             the replay may not follow the order the flight consumed its inputs"
        );
    }
    report.malformed_inputs = malformed;
    report.out_of_sequence_inputs = out_of_sequence;
    Ok(report)
}

/// The config to replay under: `config`, else the log's own; then `mode`
/// if given, and the feature clock already mapped to the autopilot's.
fn replay_config(
    metadata: &Metadata,
    name: &str,
    mode: Option<Mode>,
    config: Option<Config>,
) -> Result<Config, ReplayError> {
    let mut cfg = match config {
        Some(c) => c,
        None => logged_config(metadata, name)?,
    };
    if let Some(m) = mode {
        cfg.estimator.mode = m;
    }
    cfg.features.clock = FeatureClock::Autopilot;
    Ok(cfg)
}

/// The reading thread: turns the log's inputs back into fusion messages, in
/// the order the fusion loop consumed them (a log written in log-time order
/// is put back in the order of its sequence numbers), and sends them in
/// batches of [`REPLAY_BATCH`] until the log ends (or the fusion loop hangs
/// up). Returns the number of malformed inputs skipped and of inputs given
/// out of sequence ([`SequenceOrder::out_of_sequence`]).
fn read_inputs(
    stream: mcap::MessageStream,
    normaliser: &Normaliser,
    batch_tx: SyncSender<Vec<FusionMsg>>,
    time_ordered: bool,
) -> (u64, u64) {
    let mut malformed = 0u64;
    let mut batch = Vec::with_capacity(REPLAY_BATCH);
    let mut order = SequenceOrder::default();
    // Queues one message; false once the fusion loop has hung up.
    let emit = |msg: FusionMsg, batch: &mut Vec<FusionMsg>| {
        batch.push(msg);
        if batch.len() < REPLAY_BATCH {
            return true;
        }
        let full = std::mem::replace(batch, Vec::with_capacity(REPLAY_BATCH));
        batch_tx.send(full).is_ok()
    };
    for m in stream {
        // A log cut short ends the replay at its last whole chunk.
        let Ok(m) = m else { break };
        let topic = Topic::from_name(&m.channel.topic).filter(|t| t.is_input());
        let msg = topic.and_then(|topic| match InputRecord::parse(topic, &m.data) {
            Ok(rec) => Some(to_msg(rec, normaliser)),
            Err(e) => {
                // Counted in the report; the replay goes on without it.
                malformed += 1;
                if malformed <= 10 {
                    tracing::warn!(error = %e, "input record skipped");
                }
                None
            }
        });
        if time_ordered {
            // Every record's sequence counts, kept or not.
            order.push(m.sequence, msg);
            while let Some(msg) = order.pop(false) {
                if !emit(msg, &mut batch) {
                    return (malformed, order.out_of_sequence);
                }
            }
        } else if let Some(msg) = msg {
            if !emit(msg, &mut batch) {
                return (malformed, order.out_of_sequence);
            }
        }
    }
    while let Some(msg) = order.pop(true) {
        if !emit(msg, &mut batch) {
            return (malformed, order.out_of_sequence);
        }
    }
    if !batch.is_empty() {
        let _ = batch_tx.send(batch);
    }
    (malformed, order.out_of_sequence)
}

/// What the fusion loop counts: inputs in, estimates out, and the span of
/// the IMU times (s).
struct Tally {
    n_in: u64,
    n_out: u64,
    t_first: f64,
    t_last: f64,
}

impl Tally {
    fn new() -> Self {
        Self {
            n_in: 0,
            n_out: 0,
            t_first: f64::NAN,
            t_last: f64::NAN,
        }
    }

    /// Fuses one input and drains the outbound messages it produced,
    /// counting both.
    fn fuse(&mut self, msg: FusionMsg, fusion: &mut Fusion, ctx: &Ctx, out_rx: &mut mpsc::Receiver<Outbound>) {
        if let FusionMsg::Imu(s) = &msg {
            if self.t_first.is_nan() {
                self.t_first = s.t_s;
            }
            self.t_last = s.t_s;
        }
        self.n_in += 1;
        fusion.handle(msg, ctx);
        while let Ok(o) = out_rx.try_recv() {
            if o.is_estimate() {
                self.n_out += 1;
            }
        }
    }

    /// The report, given the wall time the replay took (s).
    fn report(&self, wall: f64) -> ReplayReport {
        let flight = if self.t_first.is_finite() {
            self.t_last - self.t_first
        } else {
            0.0
        };
        ReplayReport {
            messages_in: self.n_in,
            estimates_out: self.n_out,
            flight_s: flight,
            wall_s: wall,
            realtime_factor: if wall > 0.0 { flight / wall } else { 0.0 },
            malformed_inputs: 0,
            out_of_sequence_inputs: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A log whose `cmsckf` metadata names `log_format`, with no message.
    fn log_of_format(dir: &Path, log_format: &str) -> std::path::PathBuf {
        let path = dir.join(format!("format-{log_format}.mcap"));
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut w = mcap::Writer::new(file).unwrap();
        let mut meta = std::collections::BTreeMap::new();
        meta.insert("log_format".to_string(), log_format.to_string());
        meta.insert("config_toml".to_string(), toml::to_string(&Config::default()).unwrap());
        w.write_metadata(&mcap::records::Metadata {
            name: "cmsckf".into(),
            metadata: meta,
        })
        .unwrap();
        w.finish().unwrap();
        path
    }

    #[test]
    fn a_newer_log_format_is_refused_by_replay_and_review_whatever_the_config() {
        let dir = tempfile::tempdir().unwrap();
        let newer_format = LOG_FORMAT_NOW + 1;
        let newer = log_of_format(dir.path(), &newer_format.to_string());
        let out = dir.path().join("out.mcap");
        let named = format!("format {newer_format}");
        for config in [None, Some(Config::default())] {
            let e = replay(&newer, &out, None, config, false, |_, _| {}).unwrap_err();
            assert!(e.to_string().contains(&named), "{e}");
            assert!(!out.exists(), "nothing is written for a refused log");
        }
        let e = crate::review::review(&newer, None, None, None).unwrap_err();
        assert!(e.to_string().contains(&named), "{e}");
        // This build's own format is read.
        let own = log_of_format(dir.path(), &LOG_FORMAT_NOW.to_string());
        assert!(crate::review::review(&own, None, None, None).is_ok());
    }

    const LOG_FORMAT_NOW: u32 = crate::io::mcap_log::LOG_FORMAT;

    /// IMU samples (stamped 0, 1, 2, … ms in the order they came), written
    /// with `sequence` numbers in `file_order`, plus a non-input record per
    /// sample; what `read_inputs` gives the fusion loop, as sample stamps.
    fn read_back(file_order: &[u32], time_ordered: bool) -> (Vec<u32>, u64) {
        let mut buf = Vec::new();
        {
            let mut w = mcap::Writer::new(std::io::Cursor::new(&mut buf)).unwrap();
            let imu = w
                .add_channel(0, Topic::InputImu.name(), "json", &std::collections::BTreeMap::new())
                .unwrap();
            let pose = w
                .add_channel(0, Topic::Pose.name(), "json", &std::collections::BTreeMap::new())
                .unwrap();
            for &seq in file_order {
                // Odd sequences are the fusion loop's outputs, even ones its
                // inputs (sample seq / 2).
                let (channel_id, data) = if seq % 2 == 0 {
                    let t_us = u64::from(seq / 2) * 1000;
                    (
                        imu,
                        format!(r#"{{"t_us":{t_us},"accel_mps2":[0,0,-9.8],"gyro_radps":[0,0,0]}}"#),
                    )
                } else {
                    (pose, "{}".to_string())
                };
                let header = mcap::records::MessageHeader {
                    channel_id,
                    sequence: seq,
                    log_time: 0,
                    publish_time: 0,
                };
                w.write_to_known_channel(&header, data.as_bytes()).unwrap();
            }
            w.finish().unwrap();
        }
        let stream = mcap::MessageStream::new(&buf).unwrap();
        let normaliser = Normaliser::new(&Config::default().camera);
        let (tx, rx) = std::sync::mpsc::sync_channel(1 << 16);
        let (malformed, out_of_sequence) = read_inputs(stream, &normaliser, tx, time_ordered);
        assert_eq!(malformed, 0);
        let got = rx
            .iter()
            .flatten()
            .map(|m| match m {
                FusionMsg::Imu(i) => (i.t_s * 1000.0).round() as u32,
                _ => panic!("only IMU samples were logged"),
            })
            .collect();
        (got, out_of_sequence)
    }

    #[test]
    fn replay_gives_a_time_ordered_log_back_in_the_order_it_was_consumed() {
        // Each block of 2000 records written in reverse: a record as far as
        // 2000 records from its place, inside the writer's bound.
        let n = 30_000u32;
        let file_order: Vec<u32> = (1..=n)
            .collect::<Vec<_>>()
            .chunks(2000)
            .flat_map(|c| c.iter().rev().copied().collect::<Vec<_>>())
            .collect();
        let got = read_back(&file_order, true);
        let want: Vec<u32> = (1..=n).filter(|s| s % 2 == 0).map(|s| s / 2).collect();
        assert_eq!(got, (want, 0));
        // A log of format 2 or older is read in file order, as it was written.
        let got = read_back(&file_order, false);
        let file: Vec<u32> = file_order.iter().filter(|s| *s % 2 == 0).map(|s| s / 2).collect();
        assert_eq!(got, (file, 0));
        // A log whose sequences break the writer's bound (here all reversed:
        // re-sorted by another tool, or parts joined) is counted, not
        // silently taken as the flight's order.
        let reversed: Vec<u32> = (1..=n).rev().collect();
        let (_, out_of_sequence) = read_back(&reversed, true);
        assert!(out_of_sequence > 0);
    }
}
