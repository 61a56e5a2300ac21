//! Epochs from a stream of MSMs: why it exists is that an epoch's
//! observations arrive as several messages (one per constellation), and
//! both the rover's receiver and a base station must group them alike.

use super::rtcm::{MsmEpoch, SatObs, System};

/// Groups MSMs into epochs: by time of week, closed by the next epoch's
/// time or by an MSM without the multiple-message bit.
#[derive(Default)]
pub struct EpochAssembler {
    /// Station id, time of week (s) and satellites of the open epoch.
    pending: Option<(u16, f64, Vec<SatObs>)>,
}

impl EpochAssembler {
    /// Feeds one MSM, keeping its satellites if its constellation is one of
    /// `systems` (returns whether it was); calls `done` with each epoch it
    /// completes.
    pub fn push(&mut self, e: MsmEpoch, systems: &[System], mut done: impl FnMut(u16, f64, Vec<SatObs>)) -> bool {
        let selected = systems.contains(&e.system);
        // An unselected constellation's MSM may close the open epoch (same
        // time, last message) but never splits one: its time may be
        // mislabelled (GMSD7's BeiDou carries GPS time where BDT belongs).
        if !selected && self.pending.as_ref().is_some_and(|(_, t, _)| *t != e.tow_s) {
            return false;
        }
        if self.pending.as_ref().is_some_and(|(_, t, _)| *t != e.tow_s) {
            if let Some(p) = self.pending.take() {
                done(p.0, p.1, p.2);
            }
        }
        let entry = self.pending.get_or_insert_with(|| (e.station_id, e.tow_s, Vec::new()));
        if selected {
            entry.2.extend(e.sats);
        }
        if !e.multiple {
            if let Some(p) = self.pending.take() {
                done(p.0, p.1, p.2);
            }
        }
        selected
    }

    /// The open epoch, if any (at the end of a stream).
    pub fn take(&mut self) -> Option<(u16, f64, Vec<SatObs>)> {
        self.pending.take()
    }
}
