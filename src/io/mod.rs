//! I/O adapters: they convert between the outside world and the pure
//! estimator at the boundary. `mavlink/` is the only module that names
//! `mavlink::` types; `messages.rs` holds what crosses that boundary.

pub mod base64;
pub mod feature_pipe;
pub mod gnss_stream;
pub mod mavlink;
pub mod mcap_log;
pub mod messages;
pub mod udp_peer;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

/// Named event counters shared by the daemon's tasks (received, rejected by
/// reason, updates, …). Cheap to clone.
#[derive(Clone, Default, Debug)]
pub struct Counters(Arc<Mutex<BTreeMap<String, u64>>>);

impl Counters {
    pub fn add(&self, name: &str, n: u64) {
        let mut m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        match m.get_mut(name) {
            Some(v) => *v += n,
            None => {
                m.insert(name.to_string(), n);
            }
        }
    }
    pub fn get(&self, name: &str) -> u64 {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(name)
            .copied()
            .unwrap_or(0)
    }
    /// The sum of the counters whose names `pred` accepts (no allocation).
    pub fn sum_matching(&self, pred: impl Fn(&str) -> bool) -> u64 {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .filter(|(k, _)| pred(k))
            .map(|(_, v)| *v)
            .sum()
    }
    pub fn snapshot(&self) -> BTreeMap<String, u64> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}
