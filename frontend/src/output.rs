//! The daemon's feature protocol, written: one JSON line a frame,
//! `{"v":1,"t_us":…,"cam":0,"features":[[id,u_px,v_px],…]}` (docs/design.md,
//! "Feature pipe"), so the front-end needs nothing from the daemon but its
//! socket path.

use std::io::Write;

use crate::tracker::Feature;

/// One frame as the protocol's line (with its newline).
pub fn frame_line(t_us: u64, cam: u32, features: &[Feature]) -> String {
    let feats: Vec<serde_json::Value> = features
        .iter()
        .map(|f| serde_json::json!([f.id, f64::from(f.u_px), f64::from(f.v_px)]))
        .collect();
    let mut s = serde_json::json!({"v": 1, "t_us": t_us, "cam": cam, "features": feats}).to_string();
    s.push('\n');
    s
}

/// Writes one frame to `w`.
pub fn write_frame(w: &mut impl Write, t_us: u64, cam: u32, features: &[Feature]) -> std::io::Result<()> {
    w.write_all(frame_line(t_us, cam, features).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_one_protocol_line() {
        let f = [Feature {
            id: 7,
            u_px: 10.5,
            v_px: 20.25,
            age: 3,
        }];
        let line = frame_line(1_000_000, 0, &f);
        assert_eq!(
            line,
            "{\"cam\":0,\"features\":[[7,10.5,20.25]],\"t_us\":1000000,\"v\":1}\n"
        );
    }
}
