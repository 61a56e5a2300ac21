//! The daemon's feature protocol, written: one JSON line a frame,
//! `{"v":1,"t_us":…,"cam":0,"features":[[id,u_px,v_px,sigma_px],…]}`
//! (docs/design.md, "Feature pipe"; the σ is the tracker's measure of each
//! position, `Feature::sigma_px`, and left out where it has none), so the
//! front-end needs nothing from the daemon but its socket path.

use std::fmt::Write as _;

use crate::tracker::Feature;

/// One frame as the protocol's line (with its newline) into `line`, which
/// is reused from frame to frame: no allocation once it has grown.
pub fn frame_line_into(line: &mut String, t_us: u64, cam: u32, features: &[Feature]) {
    line.clear();
    // Writing into a String cannot fail.
    let _ = write!(line, "{{\"v\":1,\"t_us\":{t_us},\"cam\":{cam},\"features\":[");
    for (i, f) in features.iter().enumerate() {
        let sep = if i > 0 { "," } else { "" };
        if f.sigma_px > 0.0 {
            let _ = write!(line, "{sep}[{},{},{},{}]", f.id, f.u_px, f.v_px, f.sigma_px);
        } else {
            let _ = write!(line, "{sep}[{},{},{}]", f.id, f.u_px, f.v_px);
        }
    }
    line.push_str("]}\n");
}

/// One frame as the protocol's line (with its newline).
pub fn frame_line(t_us: u64, cam: u32, features: &[Feature]) -> String {
    let mut s = String::new();
    frame_line_into(&mut s, t_us, cam, features);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_one_protocol_line() {
        let mut f = [Feature {
            id: 7,
            u_px: 10.5,
            v_px: 20.25,
            age: 3,
            sigma_px: 0.0,
        }];
        let line = frame_line(1_000_000, 0, &f);
        assert_eq!(
            line,
            "{\"v\":1,\"t_us\":1000000,\"cam\":0,\"features\":[[7,10.5,20.25]]}\n"
        );
        // With its σ, as a fourth number.
        f[0].sigma_px = 0.0625;
        assert_eq!(
            frame_line(5, 0, &f),
            "{\"v\":1,\"t_us\":5,\"cam\":0,\"features\":[[7,10.5,20.25,0.0625]]}\n"
        );
        // It is JSON, and an empty frame is too.
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["features"][0][2], 20.25);
        let empty = frame_line(5, 1, &[]);
        assert_eq!(serde_json::from_str::<serde_json::Value>(&empty).unwrap()["cam"], 1);
    }
}
