//! One tracked feature as the feature socket and the flight log carry it:
//! `[landmark_id, u_px, v_px]`, or `[landmark_id, u_px, v_px, sigma_px]`
//! when the front-end says how precisely it found that pixel. The daemon's
//! parser, its log and replay, and the estimator's normaliser share this one
//! type, so a σ cannot be dropped between the socket and the filter.
//!
//! Serialised as a JSON array of three or four numbers; a log written
//! before the σ existed reads as features without one.

use std::fmt;

use serde::de::{self, SeqAccess, Visitor};
use serde::ser::SerializeSeq;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The σ a feature may carry (px): below a thousandth of a pixel no
/// tracker measures (a σ of zero would weigh its pixel infinitely), and
/// above a thousand pixels it weighs nothing.
pub const SIGMA_MIN_PX: f64 = 1e-3;
pub const SIGMA_MAX_PX: f64 = 1e3;

/// One feature in distorted pixels, with the front-end's σ if it sent one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelFeature {
    pub landmark_id: u64,
    pub u_px: f64,
    pub v_px: f64,
    /// One standard deviation of this pixel's position (px), as the
    /// front-end measured it; `None` when it sent none (the daemon then
    /// takes `camera.pixel_noise_px`).
    pub sigma_px: Option<f64>,
}

impl PixelFeature {
    /// Whether `sigma_px` is a σ to weigh a pixel with
    /// (`SIGMA_MIN_PX..=SIGMA_MAX_PX`; false for NaN).
    pub fn sigma_usable(sigma_px: f64) -> bool {
        (SIGMA_MIN_PX..=SIGMA_MAX_PX).contains(&sigma_px)
    }

    /// A feature without a σ.
    pub fn new(landmark_id: u64, u_px: f64, v_px: f64) -> Self {
        Self {
            landmark_id,
            u_px,
            v_px,
            sigma_px: None,
        }
    }
}

impl Serialize for PixelFeature {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(3 + usize::from(self.sigma_px.is_some())))?;
        seq.serialize_element(&self.landmark_id)?;
        seq.serialize_element(&self.u_px)?;
        seq.serialize_element(&self.v_px)?;
        if let Some(sigma) = &self.sigma_px {
            seq.serialize_element(sigma)?;
        }
        seq.end()
    }
}

impl<'de> Deserialize<'de> for PixelFeature {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_seq(FeatureVisitor)
    }
}

struct FeatureVisitor;

impl<'de> Visitor<'de> for FeatureVisitor {
    type Value = PixelFeature;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("[landmark_id, u_px, v_px] or [landmark_id, u_px, v_px, sigma_px]")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<PixelFeature, A::Error> {
        let landmark_id = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(0, &self))?;
        let u_px = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(1, &self))?;
        let v_px = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(2, &self))?;
        let sigma_px = seq.next_element()?;
        if seq.next_element::<de::IgnoredAny>()?.is_some() {
            return Err(de::Error::invalid_length(5, &self));
        }
        Ok(PixelFeature {
            landmark_id,
            u_px,
            v_px,
            sigma_px,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_or_four_numbers_and_nothing_else() {
        let f: PixelFeature = serde_json::from_str("[7,10.5,20.25]").unwrap();
        assert_eq!(f, PixelFeature::new(7, 10.5, 20.25));
        assert_eq!(serde_json::to_string(&f).unwrap(), "[7,10.5,20.25]");
        let g: PixelFeature = serde_json::from_str("[7,10.5,20.25,0.06]").unwrap();
        assert_eq!(g.sigma_px, Some(0.06));
        assert_eq!(serde_json::to_string(&g).unwrap(), "[7,10.5,20.25,0.06]");
        for bad in [
            "[7,10.5]",
            "[7,10.5,20,0.1,9]",
            "[]",
            "{\"id\":7}",
            "[-1,2,3]",
            "[7,1,2,\"x\"]",
        ] {
            assert!(serde_json::from_str::<PixelFeature>(bad).is_err(), "{bad} accepted");
        }
    }
}
