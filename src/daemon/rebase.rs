//! Compressed mode's global updates off the IMU and camera path: the rebase
//! worker thread, handing it jobs and installing its results between inputs
//! (estimator README §5 R4), and replay's installs where the log says the
//! daemon installed them.

use std::sync::Arc;
use std::time::Instant;

use crate::config::Config;
use crate::counters::{Counter, Counters};
use crate::estimator::{Estimator, RebaseJob, RebaseResult};
use crate::io::mcap_log::input::{InputRecord, RebaseRecord};
use crate::io::mcap_log::McapLogger;

/// What the rebase thread is asked to do.
pub(super) enum RebaseWork {
    /// Compute this job for the estimator of this generation.
    Run(u64, Arc<RebaseJob>),
    /// Free an installed job's inputs (the old base, hundreds of MB at 1000
    /// keyframes) here rather than on the fusion thread.
    Free(Arc<RebaseJob>),
}

/// Where compressed-mode rebase jobs run (estimator README §5 R4).
pub(super) enum RebaseExec {
    /// In the estimator, at once.
    Inline,
    /// On a worker thread, off the IMU and camera path; results come back
    /// tagged with the estimator generation that asked.
    Thread {
        tx: std::sync::mpsc::Sender<RebaseWork>,
        /// `(generation, result, compute time ms)`.
        rx: std::sync::mpsc::Receiver<(u64, RebaseResult, f64)>,
    },
    /// Replay: computed at once, installed where the log says the daemon
    /// installed it, so a replay reproduces the flight bit for bit.
    Logged { held: Option<RebaseResult> },
}

impl RebaseExec {
    pub(super) fn for_config(cfg: &Config) -> Self {
        if cfg.estimator.mode != crate::estimator::Mode::Compressed || !cfg.compressed.rebase_thread {
            return RebaseExec::Inline;
        }
        let (tx, job_rx) = std::sync::mpsc::channel::<RebaseWork>();
        let (res_tx, rx) = std::sync::mpsc::channel();
        let spawned = std::thread::Builder::new().name("cmsckf-rebase".into()).spawn(move || {
            // Ends when the fusion loop drops its sender.
            while let Ok(work) = job_rx.recv() {
                let (gen, job) = match work {
                    RebaseWork::Run(gen, job) => (gen, job),
                    RebaseWork::Free(job) => {
                        drop(job);
                        continue;
                    }
                };
                let started = Instant::now();
                let res = job.run();
                if res_tx.send((gen, res, started.elapsed().as_secs_f64() * 1e3)).is_err() {
                    break;
                }
            }
        });
        match spawned {
            Ok(_) => RebaseExec::Thread { tx, rx },
            Err(e) => {
                tracing::error!(error = %e, "no rebase thread: global updates run on the fusion thread");
                RebaseExec::Inline
            }
        }
    }
}

/// Where a rebase result is installed: the filter of generation `est_gen`
/// (if one runs), the log, and the autopilot time to log it at.
pub(super) struct InstallSite<'a> {
    pub est: Option<&'a mut Estimator>,
    pub est_gen: u64,
    pub log: Option<&'a McapLogger>,
    pub t_s: f64,
}

impl RebaseExec {
    /// For `cmsckf replay`: rebases are installed where the log says.
    pub(super) fn for_replay(self) -> Self {
        if matches!(self, RebaseExec::Inline) {
            self
        } else {
            RebaseExec::Logged { held: None }
        }
    }

    /// Installs the results the rebase thread has finished (logging where,
    /// for replay); results of a filter since restarted are dropped.
    pub(super) fn poll(&self, site: InstallSite<'_>, counters: &Counters) {
        let RebaseExec::Thread { rx, tx } = self else {
            return;
        };
        let mut est = site.est;
        while let Ok((gen, res, compute_ms)) = rx.try_recv() {
            let seq = res.seq;
            match est.as_deref_mut() {
                Some(est) if gen == site.est_gen => match est.install_rebase(res) {
                    Ok(job) => {
                        counters.add(Counter::RebasesInstalled, 1);
                        if let Some(job) = job {
                            // If the worker is gone the job is freed here.
                            let _ = tx.send(RebaseWork::Free(job));
                        }
                        if let Some(l) = site.log {
                            // With the worker's wall time for the job (replay
                            // reads only the sequence number).
                            let rec = InputRecord::RebaseInstalled(RebaseRecord {
                                seq,
                                compute_ms: Some(compute_ms),
                                global_keyframes: Some(est.n_global_keyframes()),
                            });
                            l.log(rec.topic(), site.t_s, &rec);
                        }
                    }
                    Err(e) => {
                        counters.add(Counter::RebaseStale, 1);
                        tracing::warn!(error = %e, "rebase result not installed");
                    }
                },
                _ => counters.add(Counter::RebaseStale, 1),
            }
        }
    }

    /// Replay: the daemon installed rebase `seq` here; install the result
    /// computed for it.
    pub(super) fn on_installed(&mut self, seq: u64, site: InstallSite<'_>, counters: &Counters) {
        if let RebaseExec::Logged { held } = self {
            if let (Some(res), Some(est)) = (held.take(), site.est) {
                if let Some(l) = site.log {
                    let rec = InputRecord::RebaseInstalled(RebaseRecord {
                        seq,
                        compute_ms: None,
                        global_keyframes: None,
                    });
                    l.log(rec.topic(), site.t_s, &rec);
                }
                if est.install_rebase(res).is_ok() {
                    counters.add(Counter::RebasesInstalled, 1);
                }
            }
        }
    }
}

/// Hands a rebase job the frame started to whoever computes it: the worker
/// thread, replay's logged install, or (inline, or with the worker gone)
/// the fusion thread at once.
pub(super) fn dispatch_rebase(rebase: &mut RebaseExec, est_gen: u64, est: &mut Estimator, counters: &Counters) {
    let Some(job) = est.take_rebase_job() else {
        return;
    };
    counters.add(Counter::RebasesStarted, 1);
    // A job not handed to the worker runs here and now.
    let here = match rebase {
        RebaseExec::Thread { tx, .. } => match tx.send(RebaseWork::Run(est_gen, job)) {
            Ok(()) => None,
            Err(std::sync::mpsc::SendError(work)) => {
                // The worker is gone: compute it here rather than never.
                counters.add(Counter::RebaseThreadLost, 1);
                match work {
                    RebaseWork::Run(_, job) => Some(job),
                    RebaseWork::Free(_) => None,
                }
            }
        },
        RebaseExec::Logged { held } => {
            *held = Some(job.run());
            None
        }
        RebaseExec::Inline => Some(job),
    };
    if let Some(job) = here {
        let _ = est.install_rebase(job.run());
    }
}
