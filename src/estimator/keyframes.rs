//! The keyframe life cycle (README.md §4): a keyframe is created from the
//! current pose every `keyframe.interval_s` with its frame's observations,
//! its observations become usable once their landmark has left view, a later
//! track uses each once (a loop closure), and the oldest is marginalised when
//! the map is full. The compressed mode's entry points for global updates
//! (forced, benchmark hooks) are here too; their machinery is
//! `compressed/`'s.

use std::collections::BTreeMap;

use nalgebra::Vector3;

use super::{Estimator, GlobalReason, Keyframe, KfObs, Mode, NormObs, RebaseJob, RebaseResult};

impl Estimator {
    pub(super) fn create_keyframe(&mut self, t_s: f64, obs: &[NormObs]) -> u64 {
        if self.keyframes.len() >= self.s.keyframe_max {
            if let Some(&oldest) = self.keyframes.keys().next() {
                self.remove_keyframe(oldest);
            }
        }
        let id = self.next_kf_id;
        self.next_kf_id += 1;
        let at = self.clones_offset();
        self.augment_view(at);
        self.local_kfs.push(id);
        let mut kobs = BTreeMap::new();
        for o in obs {
            kobs.insert(
                o.landmark_id,
                KfObs {
                    obs: *o,
                    eligible: false,
                },
            );
            self.kf_by_landmark.entry(o.landmark_id).or_default().insert(id);
            self.pending_eligible.insert(o.landmark_id);
        }
        self.keyframes.insert(
            id,
            Keyframe {
                id,
                t_s,
                q0_W_B: self.imu.q_W_B,
                delta: Vector3::zeros(),
                p_B_in_W: self.imu.p_B_in_W,
                p_fej_in_W: self.p_first_estimate(),
                obs: kobs,
                last_used_s: t_s,
            },
        );
        self.last_kf_t_s = t_s;
        self.stats.keyframes_created += 1;
        id
    }

    /// Marginalises a keyframe: a local one's block leaves `P`, a global
    /// one's goes dead until the next rebase drops it (§5 G5).
    pub fn remove_keyframe(&mut self, id: u64) {
        if let Some(j) = self.local_kfs.iter().position(|&k| k == id) {
            let at = self.kf_offset(j);
            self.remove_block(at, 6);
            self.local_kfs.remove(j);
        } else if let Some(g) = self.global.as_mut() {
            // Deleting a global state commutes with Ψ and q (§5, eq. G5): its
            // block goes dead and the next rebase drops it.
            g.live.remove(&id);
            g.sigma_m.remove(&id);
        }
        if let Some(kf) = self.keyframes.remove(&id) {
            for l in kf.obs.keys() {
                if let Some(s) = self.kf_by_landmark.get_mut(l) {
                    s.remove(&id);
                    if s.is_empty() {
                        self.kf_by_landmark.remove(l);
                    }
                }
            }
        }
        self.stats.keyframes_marginalised += 1;
    }

    /// Forces a global update (compressed mode; on shutdown or for a log).
    pub fn force_global_update(&mut self) {
        if self.s.mode == Mode::Compressed {
            self.finish_rebase_inline();
            self.begin_rebase(GlobalReason::Forced);
            self.finish_rebase_inline();
        }
    }

    /// Marginalises the oldest global keyframes (compressed mode) until at
    /// most `keep` remain (§5 G5: their blocks go dead and the next rebase
    /// drops them). Returns their ids. The local part is not touched, so
    /// the scaling benchmark uses it to give one filter maps of several
    /// sizes with the same local part.
    pub fn marginalise_oldest_global_keyframes(&mut self, keep: usize) -> Vec<u64> {
        let Some(g) = self.global.as_ref() else {
            return Vec::new();
        };
        let drop: Vec<u64> = g.live.keys().copied().take(g.live.len().saturating_sub(keep)).collect();
        for id in &drop {
            self.remove_keyframe(*id);
        }
        drop
    }

    /// Starts a forced rebase and hands out its job instead of running it
    /// (benchmarks time the job alone). `None` outside compressed mode.
    pub fn forced_rebase_job(&mut self) -> Option<std::sync::Arc<RebaseJob>> {
        if self.s.mode != Mode::Compressed {
            return None;
        }
        self.finish_rebase_inline();
        let was = self.s.async_rebase;
        self.s.async_rebase = true;
        self.begin_rebase(GlobalReason::Forced);
        self.s.async_rebase = was;
        self.take_rebase_job()
    }

    /// What runs a synchronous filter's rebase jobs (the evaluation times
    /// them with a wrapper; the result must be the job's `run()`).
    pub fn set_rebase_runner(&mut self, f: fn(&RebaseJob) -> RebaseResult) {
        self.rebase_runner = f;
    }

    /// Asynchronous rebases (§5 R4): see [`Settings::async_rebase`].
    pub fn set_async_rebase(&mut self, on: bool) {
        self.s.async_rebase = on;
    }

    /// Keyframe observations of landmarks no longer in view
    /// (`present_sorted`: this frame's, sorted and distinct) become usable
    /// by a later track of the same landmark:
    /// that re-detection is the loop closure (§4).
    pub(super) fn release_keyframe_observations(&mut self, present_sorted: &[u64]) {
        // In place (no list of the released ones): a landmark still in view
        // stays pending; one that left has its observations made eligible.
        let (kf_by_landmark, keyframes) = (&self.kf_by_landmark, &mut self.keyframes);
        self.pending_eligible.retain(|l| {
            if present_sorted.binary_search(l).is_ok() {
                return true;
            }
            if let Some(kfs) = kf_by_landmark.get(l) {
                for k in kfs {
                    if let Some(o) = keyframes.get_mut(k).and_then(|kf| kf.obs.get_mut(l)) {
                        o.eligible = true;
                    }
                }
            }
            false
        });
    }
}
