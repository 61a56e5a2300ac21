//! The feature socket: a Unix-domain stream socket on which one camera front
//! end at a time writes newline-delimited JSON frames,
//! `{"v":1,"t_us":..,"cam":0,"features":[[landmark_id,u_px,v_px],...]}`,
//! each feature optionally with a fourth number, its σ in pixels
//! (`[landmark_id,u_px,v_px,sigma_px]`, `cmsckf_models::feature_wire`).
//!
//! It exists to keep everything the front end sends, and everyone else who
//! can reach the socket, at the boundary:
//!
//! - Every line is checked here (length, syntax, version, feature count,
//!   finite numbers); a bad line is rejected with a reason and the
//!   connection goes on. A front end may disconnect and reconnect at any time.
//! - One writer is served at a time. A client that connects while another is
//!   served waits in the listener's accept backlog (it is not accepted, and
//!   what it writes waits in its socket buffer) and is served, in the order
//!   of arrival, when the one served goes away.
//! - A writer is dropped when it has sent no accepted frame for
//!   `features.idle_timeout_s` (wall time) since it connected or since its
//!   last accepted frame — silence, a line never finished and lines that are
//!   all rejected alike (`feature_idle_dropped`, with a warning naming its
//!   pid and uid) — so a client that connected first and never writes cannot
//!   keep the real front end out.
//! - [`bind`] refuses a directory another user could tamper with: it must be
//!   a real directory (not a symlink, and not reached through one), owned by
//!   the daemon's effective user and not writable by group or others. A
//!   missing directory is created with mode 0700.
//! - The socket file's device and inode are kept after binding; at shutdown
//!   the path is removed only if it is still that socket. Anything else found
//!   there is left alone (`feature_socket_replaced`, with a warning).

mod serve;
mod socket;

pub use serve::{serve, Limits};
pub use socket::{bind, FeatureSocket, SocketError};

use serde::Deserialize;

use cmsckf_models::feature_wire::{PixelFeature, SIGMA_MAX_PX, SIGMA_MIN_PX};

use crate::counters::Counter;

/// One camera frame as received.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureFrame {
    /// Timestamp in the front end's clock (µs).
    pub t_us: u64,
    pub cam: u32,
    /// Distorted pixels, each with the front-end's σ if it sent one.
    pub features: Vec<PixelFeature>,
}

/// Why a line was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LineError {
    #[error("line longer than {0} bytes")]
    TooLong(usize),
    #[error("not valid JSON for a feature frame: {0}")]
    Syntax(String),
    #[error("unsupported version {0} (expected 1)")]
    Version(u32),
    #[error("{0} features exceed the limit of {1}")]
    TooManyFeatures(usize, usize),
    #[error("non-finite pixel for landmark {0}")]
    NonFinite(u64),
    #[error("landmark {0}'s sigma_px is not a number from {SIGMA_MIN_PX} to {SIGMA_MAX_PX} px")]
    BadSigma(u64),
}

impl LineError {
    /// Short counter name.
    pub fn reason(&self) -> Counter {
        match self {
            LineError::TooLong(_) => Counter::FeatureLineTooLong,
            LineError::Syntax(_) => Counter::FeatureLineSyntax,
            LineError::Version(_) => Counter::FeatureLineVersion,
            LineError::TooManyFeatures(..) => Counter::FeatureLineTooMany,
            LineError::NonFinite(_) => Counter::FeatureNonFinite,
            LineError::BadSigma(_) => Counter::FeatureBadSigma,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Wire {
    v: u32,
    t_us: u64,
    #[serde(default)]
    cam: u32,
    features: Vec<PixelFeature>,
}

/// Parses and checks one line (without its newline).
pub fn parse_line(line: &[u8], max_features: usize) -> Result<FeatureFrame, LineError> {
    let w: Wire = serde_json::from_slice(line).map_err(|e| LineError::Syntax(e.to_string()))?;
    if w.v != 1 {
        return Err(LineError::Version(w.v));
    }
    if w.features.len() > max_features {
        return Err(LineError::TooManyFeatures(w.features.len(), max_features));
    }
    if let Some(f) = w.features.iter().find(|f| !f.u_px.is_finite() || !f.v_px.is_finite()) {
        return Err(LineError::NonFinite(f.landmark_id));
    }
    if let Some(f) = w
        .features
        .iter()
        .find(|f| f.sigma_px.is_some_and(|s| !PixelFeature::sigma_usable(s)))
    {
        return Err(LineError::BadSigma(f.landmark_id));
    }
    Ok(FeatureFrame {
        t_us: w.t_us,
        cam: w.cam,
        features: w.features,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_checked() {
        let ok = br#"{"v":1,"t_us":1000,"cam":0,"features":[[1,10.5,20.0],[2,30,40]]}"#;
        let f = parse_line(ok, 10).unwrap();
        assert_eq!(f.features.len(), 2);
        assert_eq!(parse_line(ok, 1).unwrap_err().reason(), Counter::FeatureLineTooMany);
        assert_eq!(
            parse_line(b"garbage", 10).unwrap_err().reason(),
            Counter::FeatureLineSyntax
        );
        let v2 = br#"{"v":2,"t_us":1,"features":[]}"#;
        assert_eq!(parse_line(v2, 10).unwrap_err().reason(), Counter::FeatureLineVersion);
        let nan = br#"{"v":1,"t_us":1,"features":[[1,NaN,2]]}"#;
        assert!(parse_line(nan, 10).is_err());
        let huge = br#"{"v":1,"t_us":1,"features":[[1,1e999,2]]}"#;
        assert!(parse_line(huge, 10).is_err());
        let neg_t = br#"{"v":1,"t_us":-5,"features":[]}"#;
        assert!(parse_line(neg_t, 10).is_err());
        // A fourth number is the feature's σ; a fifth is refused.
        let sig = br#"{"v":1,"t_us":1,"features":[[1,10,20,0.06],[2,30,40]]}"#;
        let f = parse_line(sig, 10).unwrap();
        assert_eq!(f.features[0].sigma_px, Some(0.06));
        assert_eq!(f.features[1].sigma_px, None);
        for bad in [
            &br#"{"v":1,"t_us":1,"features":[[1,10,20,0]]}"#[..],
            br#"{"v":1,"t_us":1,"features":[[1,10,20,-0.5]]}"#,
            br#"{"v":1,"t_us":1,"features":[[1,10,20,1e-9]]}"#,
            br#"{"v":1,"t_us":1,"features":[[1,10,20,5e3]]}"#,
        ] {
            assert_eq!(parse_line(bad, 10).unwrap_err().reason(), Counter::FeatureBadSigma);
        }
        assert!(parse_line(br#"{"v":1,"t_us":1,"features":[[1,10,20,1e999]]}"#, 10).is_err());
        // The range's ends are taken, a hair outside them is not; a σ that
        // is not a number is a syntax error.
        for (sigma, usable) in [
            ("0.001", true),
            ("1000", true),
            ("0.000999", false),
            ("1000.001", false),
        ] {
            let line = format!(r#"{{"v":1,"t_us":1,"features":[[1,10,20,{sigma}]]}}"#);
            let got = parse_line(line.as_bytes(), 10);
            if usable {
                assert_eq!(got.unwrap().features[0].sigma_px, Some(sigma.parse().unwrap()));
            } else {
                assert_eq!(got.unwrap_err().reason(), Counter::FeatureBadSigma, "{sigma}");
            }
        }
        for odd in ["null", r#""0.1""#, "true"] {
            let line = format!(r#"{{"v":1,"t_us":1,"features":[[1,10,20,{odd}]]}}"#);
            assert_eq!(
                parse_line(line.as_bytes(), 10).unwrap_err().reason(),
                Counter::FeatureLineSyntax,
                "{odd}"
            );
        }
        let five = br#"{"v":1,"t_us":1,"features":[[1,10,20,0.1,3]]}"#;
        assert_eq!(parse_line(five, 10).unwrap_err().reason(), Counter::FeatureLineSyntax);
    }
}
