//! The feature socket: the front-end's camera frames, read by
//! `io::feature_pipe`, normalised here beside the socket (not on the fusion
//! thread) and forwarded to the fusion loop, at most `FRAMES_IN_FLIGHT` at
//! once (`fusion_frames_full` beyond). One front end is served at a time;
//! one silent for `features.idle_timeout_s` is dropped (`feature_idle_dropped`)
//! so that the next can connect.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{FusionMsg, FRAMES_IN_FLIGHT};
use crate::config::Config;
use crate::counters::{Counter, Counters};
use crate::estimator::frontend::Normaliser;
use crate::io::feature_pipe::{self, FeatureFrame, FeatureSocket};

/// `features.idle_timeout_s`'s default, for a config that skipped validation.
const DEFAULT_IDLE_TIMEOUT_S: u64 = 5;

/// The socket's serving task and the forwarder, until `stop` (the serving
/// task then removes the socket file, if it still is ours). `queued` counts
/// the frames in the fusion queue (the fusion loop takes them off).
pub(super) fn spawn(
    cfg: &Config,
    socket: FeatureSocket,
    fusion_tx: &mpsc::Sender<FusionMsg>,
    counters: &Counters,
    stop_rx: &watch::Receiver<bool>,
    queued: Arc<AtomicUsize>,
) -> (JoinHandle<()>, JoinHandle<()>) {
    let (frame_tx, mut frame_rx) = mpsc::channel::<FeatureFrame>(64);
    let limits = feature_pipe::Limits {
        max_line_bytes: cfg.features.max_line_bytes,
        max_features: cfg.features.max_features,
        // Validated with the config (0.1 s to an hour); the default if not.
        idle_timeout: Duration::try_from_secs_f64(cfg.features.idle_timeout_s)
            .unwrap_or(Duration::from_secs(DEFAULT_IDLE_TIMEOUT_S)),
    };
    let serve = tokio::spawn(feature_pipe::serve(
        socket,
        limits,
        frame_tx,
        counters.clone(),
        stop_rx.clone(),
    ));
    let fusion_tx = fusion_tx.clone();
    let counters = counters.clone();
    let mut stop = stop_rx.clone();
    let normaliser = Normaliser::new(&cfg.camera);
    let fwd = tokio::spawn(async move {
        loop {
            tokio::select! {
                f = frame_rx.recv() => match f {
                    Some(f) => {
                        if queued.load(Ordering::Relaxed) >= FRAMES_IN_FLIGHT {
                            counters.add(Counter::FusionFramesFull, 1);
                            continue;
                        }
                        let norm = normaliser.frame(&f.features);
                        queued.fetch_add(1, Ordering::Relaxed);
                        if fusion_tx.try_send(FusionMsg::Frame(f, norm)).is_err() {
                            queued.fetch_sub(1, Ordering::Relaxed);
                            counters.add(Counter::FusionQueueFull, 1);
                        }
                    }
                    None => return,
                },
                _ = stop.changed() => return,
            }
        }
    });
    (serve, fwd)
}
