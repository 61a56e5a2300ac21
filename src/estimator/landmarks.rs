//! The landmarks the filter remembers (README §3e): each landmark's last
//! triangulated position and when, where a later track of it with too
//! little parallax is linearised. Bounded in age and in count.
//!
//! Why it exists: the bound is enforced every camera frame, and a dense
//! scene keeps the memory at its bound, so forgetting must not cost the
//! memory's size each frame (collecting 4096 times, selecting, and
//! retaining over the map was 3 % of a replay of the demo log). Entries
//! are also queued in the order they were stored, which is time order, so
//! the oldest are found at the queue's front: forgetting costs what it
//! forgets, amortised, and the same landmarks are forgotten as by a scan.

use std::collections::{BTreeMap, VecDeque};

use nalgebra::Vector3;

#[derive(Clone, Debug, Default)]
pub(super) struct LandmarkMemory {
    /// Each landmark's last position (m, world) and when it was stored (s).
    by_id: BTreeMap<u64, (Vector3<f64>, f64)>,
    /// `(t_s, id)` in the order stored (non-decreasing `t_s`). An entry is
    /// live while `by_id[id]` was stored at its `t_s`; a landmark stored
    /// again later leaves its earlier entry stale, skipped and dropped when
    /// it reaches the front.
    order: VecDeque<(f64, u64)>,
}

impl LandmarkMemory {
    pub(super) fn get(&self, id: u64) -> Option<Vector3<f64>> {
        self.by_id.get(&id).map(|(p, _)| *p)
    }

    /// Stores `id`'s position at `t_s`, the filter's time, which never
    /// goes back.
    pub(super) fn insert(&mut self, id: u64, p_W: Vector3<f64>, t_s: f64) {
        debug_assert!(
            self.order.back().is_none_or(|(t, _)| *t <= t_s),
            "stored out of time order"
        );
        let again_now = self.by_id.insert(id, (p_W, t_s)).is_some_and(|(_, t)| t == t_s);
        // Stored again at the same instant: its entry is already queued.
        if !again_now {
            self.order.push_back((t_s, id));
        }
    }

    fn live(&self, (t_s, id): (f64, u64)) -> bool {
        self.by_id.get(&id).is_some_and(|(_, t)| *t == t_s)
    }

    /// Forgets every landmark stored at or before `cut_s`.
    pub(super) fn forget_up_to(&mut self, cut_s: f64) {
        while let Some(&(t_s, id)) = self.order.front() {
            if t_s > cut_s {
                break;
            }
            if self.live((t_s, id)) {
                self.by_id.remove(&id);
            }
            self.order.pop_front();
        }
    }

    /// Above `max` landmarks, forgets the oldest `len − max` and any stored
    /// at the same instant as the last of them (a frame's landmarks share
    /// its time): the landmarks stored at or before the `(len − max)`-th
    /// oldest time.
    pub(super) fn bound(&mut self, max: usize) {
        let excess = self.by_id.len().saturating_sub(max);
        if excess == 0 {
            return;
        }
        let mut seen = 0;
        let mut cut_s = f64::NEG_INFINITY;
        for &e in &self.order {
            if self.live(e) {
                seen += 1;
                if seen == excess {
                    cut_s = e.0;
                    break;
                }
            }
        }
        self.forget_up_to(cut_s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The scan it replaces: retain by time, then the excess oldest by
    /// their times' order statistic.
    fn reference(map: &mut BTreeMap<u64, (Vector3<f64>, f64)>, oldest_s: Option<f64>, max: usize) {
        if let Some(o) = oldest_s {
            map.retain(|_, (_, t)| *t > o);
        }
        let excess = map.len().saturating_sub(max);
        if excess > 0 {
            let mut times: Vec<f64> = map.values().map(|(_, t)| *t).collect();
            let (_, cut, _) = times.select_nth_unstable_by(excess - 1, f64::total_cmp);
            let cut = *cut;
            map.retain(|_, (_, t)| *t > cut);
        }
    }

    /// Over 3000 frames of landmarks stored, stored again (the same frame
    /// or later) and forgotten by age and by count, the memory holds what
    /// the scan holds, entry for entry; and its queue stays bounded.
    #[test]
    fn the_memory_forgets_what_a_scan_forgets() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut ours = LandmarkMemory::default();
        let mut scan = BTreeMap::new();
        let mut forgotten_s = 0.0;
        for frame in 0..3000u64 {
            let t_s = frame as f64 * 0.05;
            for _ in 0..rng.random_range(0..40) {
                // Ids repeat: a landmark seen again is stored again.
                let id = rng.random_range(0..3000u64);
                let p = Vector3::new(rng.random(), rng.random(), t_s);
                ours.insert(id, p, t_s);
                scan.insert(id, (p, t_s));
            }
            let oldest = if t_s - forgotten_s >= 1.0 {
                forgotten_s = t_s;
                Some(t_s - 30.0)
            } else {
                None
            };
            if let Some(o) = oldest {
                ours.forget_up_to(o);
            }
            ours.bound(500);
            reference(&mut scan, oldest, 500);
            assert_eq!(ours.by_id, scan, "frame {frame}");
            assert!(
                ours.order.len() <= 40 * 620,
                "queue {} at frame {frame}",
                ours.order.len()
            );
        }
        assert!(ours.by_id.len() > 400, "the bound was reached: {}", ours.by_id.len());
    }
}
