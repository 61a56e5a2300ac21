//! The feature socket: the front-end's camera frames, read by
//! `io::feature_pipe`, normalised here beside the socket (not on the fusion
//! thread) and forwarded to the fusion loop, at most `FRAMES_IN_FLIGHT` at
//! once (`fusion_frames_full` beyond).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use tokio::net::UnixListener;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{FusionMsg, FRAMES_IN_FLIGHT};
use crate::config::Config;
use crate::estimator::frontend::Normaliser;
use crate::io::feature_pipe::{self, FeatureFrame};
use crate::io::Counters;

/// The socket's serving task and the forwarder, until `stop`. `queued`
/// counts the frames in the fusion queue (the fusion loop takes them off).
pub(super) fn spawn(
    cfg: &Config,
    listener: UnixListener,
    fusion_tx: &mpsc::Sender<FusionMsg>,
    counters: &Counters,
    stop_rx: &watch::Receiver<bool>,
    queued: Arc<AtomicUsize>,
) -> (JoinHandle<()>, JoinHandle<()>) {
    let (frame_tx, mut frame_rx) = mpsc::channel::<FeatureFrame>(64);
    let serve = tokio::spawn(feature_pipe::serve(
        listener,
        cfg.features.max_line_bytes,
        cfg.features.max_features,
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
                            counters.add("fusion_frames_full", 1);
                            continue;
                        }
                        let norm = normaliser.frame(&f.features);
                        queued.fetch_add(1, Ordering::Relaxed);
                        if fusion_tx.try_send(FusionMsg::Frame(f, norm)).is_err() {
                            queued.fetch_sub(1, Ordering::Relaxed);
                            counters.add("fusion_queue_full", 1);
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
