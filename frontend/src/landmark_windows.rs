//! Each landmark's first look, for re-identification: why this exists is
//! that a re-identified feature (and a recognised place's landmark) is
//! checked against the window its landmark had when a keyframe first
//! stored it (`tracker.rs::check_against`, the affine check of
//! `affine.rs`), so errors do not pass from one re-identification to the
//! next. A landmark's window is held while any stored keyframe holds its
//! id, and dropped with the last.
//!
//! The windows are grey bytes (`affine::window_bytes`, 441 each) in slots
//! of one buffer; a dropped window's slot takes the next one, so the
//! buffer grows (by doubling) only to the most windows ever held, and a
//! full store allocates nothing. At most `max_keyframes × features`
//! windows.

use std::collections::HashMap;

use crate::affine::{window_bytes, RING_SIDE};
use crate::image::Gray;

/// A stored window's size: the anchor's window with its ring.
const WINDOW_BYTES: usize = RING_SIDE * RING_SIDE;

/// The landmarks' windows, by id.
#[derive(Clone, Debug, Default)]
pub struct LandmarkWindows {
    /// Each landmark's slot, and how many stored keyframes hold its id.
    by_id: HashMap<u64, (u32, u32)>,
    /// The windows, one slot of `WINDOW_BYTES` after another.
    slots: Vec<u8>,
    /// The slots of dropped windows.
    free: Vec<u32>,
    /// A window being cut, and the samples it is cut from (scratch).
    window: Vec<u8>,
    ring: Vec<f32>,
}

impl LandmarkWindows {
    /// Landmark `id`'s window, if one is held.
    pub fn get(&self, id: u64) -> Option<&[u8]> {
        let &(slot, _) = self.by_id.get(&id)?;
        self.slots
            .get(slot as usize * WINDOW_BYTES..(slot as usize + 1) * WINDOW_BYTES)
    }

    /// One more stored keyframe holds landmark `id`, seen at `uv` in
    /// `img`: its window is kept from the first that held it, so it is cut
    /// only if none is held (and only if it fits in the image).
    pub fn hold(&mut self, id: u64, img: &Gray, uv: [f32; 2]) {
        if let Some(held) = self.by_id.get_mut(&id) {
            held.1 += 1;
            return;
        }
        if !window_bytes(img, uv[0], uv[1], &mut self.ring, &mut self.window) || self.window.len() != WINDOW_BYTES {
            return;
        }
        let slot = match self.free.pop() {
            Some(slot) => slot,
            None => {
                self.slots.resize(self.slots.len() + WINDOW_BYTES, 0);
                (self.slots.len() / WINDOW_BYTES - 1) as u32
            }
        };
        let at = slot as usize * WINDOW_BYTES;
        self.slots[at..at + WINDOW_BYTES].copy_from_slice(&self.window);
        self.by_id.insert(id, (slot, 1));
    }

    /// A keyframe holding landmark `id` left the store: its window is
    /// dropped with the last.
    pub fn release(&mut self, id: u64) {
        let Some(held) = self.by_id.get_mut(&id) else { return };
        held.1 -= 1;
        if held.1 == 0 {
            if let Some((slot, _)) = self.by_id.remove(&id) {
                self.free.push(slot);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A window is kept from the first hold, survives until the last
    /// release, and its slot then takes the next landmark's.
    #[test]
    fn windows_live_while_held_and_slots_are_reused() {
        let img = crate::synthetic::textured(100, 80, 4, 0.0, 0.0);
        let mut w = LandmarkWindows::default();
        w.hold(1, &img, [40.0, 40.0]);
        let first = w.get(1).expect("held").to_vec();
        // Held again elsewhere: the first look stays.
        w.hold(1, &img, [60.0, 30.0]);
        assert_eq!(w.get(1), Some(first.as_slice()));
        // Too near the border: not held.
        w.hold(2, &img, [3.0, 3.0]);
        assert!(w.get(2).is_none());
        w.release(1);
        assert!(w.get(1).is_some());
        w.release(1);
        assert!(w.get(1).is_none());
        w.hold(3, &img, [60.0, 30.0]);
        assert_eq!(w.slots.len(), WINDOW_BYTES, "the dropped slot is reused");
        assert_ne!(w.get(3), Some(first.as_slice()));
    }
}
