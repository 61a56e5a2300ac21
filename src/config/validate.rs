//! Checks of every configuration value, and the signing key file: each
//! error names the field and the fix.

use cmsckf_models::check::{Check, FieldError, Validate};

use super::{Config, GnssSource};

impl Config {
    /// Checks every value; the error names the field and the fix. Sections
    /// are checked in file order and the first error is returned.
    pub fn validate(&self) -> Result<(), FieldError> {
        self.validate_mavlink()?;
        self.validate_features()?;
        self.camera.validate("camera")?;
        self.imu.validate("imu")?;
        self.validate_estimator()?;
        self.validate_zupt()?;
        self.validate_barometer()?;
        self.validate_init()?;
        self.validate_keyframe()?;
        self.validate_compressed()?;
        self.validate_gnss()?;
        self.validate_output()?;
        self.validate_live_view()
    }

    /// `[live_view]`: an address the server can listen on, and a log to
    /// stream.
    fn validate_live_view(&self) -> Result<(), FieldError> {
        let c = Check::new("live_view");
        if !self.live_view.enabled {
            return Ok(());
        }
        if self.live_view.address.parse::<std::net::SocketAddr>().is_err() {
            return Err(c.fail(
                "address",
                format!("'{}' is not an IP address and port", self.live_view.address),
                "use HOST:PORT with an IP address, e.g. 127.0.0.1:8765 (0.0.0.0:8765 to serve the network)",
            ));
        }
        if self.log.path.is_empty() {
            return Err(c.fail(
                "enabled",
                "streams the flight log's channels, and log.path is empty (no log)",
                "set log.path, or live_view.enabled = false",
            ));
        }
        Ok(())
    }

    /// `[output]`: the rate, and the removed `odometry` switch. (`message`
    /// is checked when parsed: an unknown name is refused with the names
    /// allowed.)
    fn validate_output(&self) -> Result<(), FieldError> {
        let c = Check::new("output");
        c.range("rate_hz", self.output.rate_hz, 1.0, 500.0)?;
        if self.output.odometry.is_some() {
            return Err(c.fail(
                "odometry",
                "was removed: output.message chooses the one message sent",
                "delete it and set message = \"odometry\" (the default; ArduPilot 4.1+, PX4) \
                 or \"vision_position_estimate\" (sent with VISION_SPEED_ESTIMATE)",
            ));
        }
        Ok(())
    }

    /// `[mavlink]`: the address, the ids, the IMU rate and the signing key.
    fn validate_mavlink(&self) -> Result<(), FieldError> {
        let m = &self.mavlink;
        let c = Check::new("mavlink");
        let schemes = ["udpin:", "udpout:", "udpbcast:", "tcpin:", "tcpout:", "serial:"];
        if !schemes.iter().any(|s| m.address.starts_with(s)) {
            return Err(c.fail(
                "address",
                format!("'{}' has no known scheme", m.address),
                "use udpin:HOST:PORT, udpout:HOST:PORT, tcpout:HOST:PORT or serial:DEVICE:BAUD",
            ));
        }
        if m.system_id == 0 {
            return Err(c.fail(
                "system_id",
                "0 is the broadcast id",
                "set the vehicle's system id, 1..255",
            ));
        }
        if m.component_id == 0 {
            return Err(c.fail(
                "component_id",
                "0 is the broadcast id",
                "use 197 (visual-inertial odometry)",
            ));
        }
        c.positive("imu_rate_hz", m.imu_rate_hz, 2000.0)?;
        c.range("link_down_after_s", m.link_down_after_s, 0.1, 3600.0)?;
        c.range("clock_jump_confirm_s", m.clock_jump_confirm_s, 0.0, 10.0)?;
        c.range("link_exit_after_s", m.link_exit_after_s, 0.0, 86_400.0)?;
        if m.link_exit_after_s > 0.0 && m.link_exit_after_s < m.link_down_after_s {
            return Err(c.fail(
                "link_exit_after_s",
                format!(
                    "{} s is shorter than link_down_after_s ({} s)",
                    m.link_exit_after_s, m.link_down_after_s
                ),
                "set it above link_down_after_s, or 0 to never exit",
            ));
        }
        if !m.signing_key_file.is_empty() {
            load_signing_key(std::path::Path::new(&m.signing_key_file))
                .map_err(|(problem, fix)| c.fail("signing_key_file", problem, fix))?;
        }
        Ok(())
    }

    /// `[features]`: the socket path and the size limits.
    fn validate_features(&self) -> Result<(), FieldError> {
        let c = Check::new("features");
        if self.features.socket.is_empty() {
            return Err(c.fail("socket", "is empty", "give a path such as /run/cmsckf/features.sock"));
        }
        c.within(
            "max_line_bytes",
            self.features.max_line_bytes as u64,
            256,
            16 << 20,
            "set 256..16777216",
        )?;
        c.within(
            "max_features",
            self.features.max_features as u64,
            1,
            100_000,
            "set 1..100000",
        )?;
        c.range("idle_timeout_s", self.features.idle_timeout_s, 0.1, 3600.0)?;
        Ok(())
    }

    /// `[estimator]`: the window, the track length, the gate and the depths.
    fn validate_estimator(&self) -> Result<(), FieldError> {
        let e = &self.estimator;
        let c = Check::new("estimator");
        c.within("max_clones", e.max_clones as u64, 2, 100, "set 2..100 (11 is typical)")?;
        c.within(
            "min_track_len",
            e.min_track_len as u64,
            2,
            e.max_clones as u64 + 1,
            "set 2..=max_clones+1",
        )?;
        c.range("chi2_gate_prob", e.chi2_gate_prob, 0.5, 0.999_999)?;
        c.positive("min_depth_m", e.min_depth_m, 1e3)?;
        c.positive("max_depth_m", e.max_depth_m, 1e6)?;
        if e.max_depth_m <= e.min_depth_m {
            return Err(c.fail(
                "max_depth_m",
                "is not above min_depth_m",
                "set max_depth_m > min_depth_m",
            ));
        }
        c.range("max_triangulation_cond", e.max_triangulation_cond, 10.0, 1e12)?;
        c.range("min_parallax_deg", e.min_parallax_deg, 0.0, 10.0)?;
        c.range("time_offset_s", e.time_offset_s, -0.5, 0.5)?;
        c.positive("time_offset_sigma_s", e.time_offset_sigma_s, 0.5)?;
        c.range("health_grace_s", e.health_grace_s, 0.0, 60.0)?;
        c.positive("imu_gap_sigma_rate_radps", e.imu_gap_sigma_rate_radps, 20.0)?;
        c.positive("imu_gap_sigma_accel_mps2", e.imu_gap_sigma_accel_mps2, 200.0)
    }

    /// `[zupt]`: the stillness thresholds and the measurement sigma.
    fn validate_zupt(&self) -> Result<(), FieldError> {
        let z = &self.zupt;
        let c = Check::new("zupt");
        c.positive("max_gyro_radps", z.max_gyro_radps, 10.0)?;
        c.positive("max_accel_deviation_mps2", z.max_accel_deviation_mps2, 50.0)?;
        c.positive("max_vibration_gyro_radps", z.max_vibration_gyro_radps, 10.0)?;
        c.positive("max_vibration_accel_mps2", z.max_vibration_accel_mps2, 100.0)?;
        c.positive("max_disparity_px", z.max_disparity_px, 1000.0)?;
        c.positive("max_speed_mps", z.max_speed_mps, 100.0)?;
        c.positive("sigma_mps", z.sigma_mps, 10.0)
    }

    /// `[barometer]`: the reading's noise and the offset's walk.
    fn validate_barometer(&self) -> Result<(), FieldError> {
        let b = &self.barometer;
        let c = Check::new("barometer");
        c.positive("noise_m", b.noise_m, 100.0)?;
        c.positive("offset_rw_m_per_sqrt_s", b.offset_rw_m_per_sqrt_s, 10.0)
    }

    /// `[init]`: the static window, the yaw and the initial sigmas.
    fn validate_init(&self) -> Result<(), FieldError> {
        let i = &self.init;
        let c = Check::new("init");
        c.range("static_window_s", i.static_window_s, 0.1, 60.0)?;
        c.range("gyro_bias_max_radps", i.gyro_bias_max_radps, 0.001, 1.0)?;
        c.range("yaw_deg", i.yaw_deg, -360.0, 360.0)?;
        c.positive("sigma_tilt_deg", i.sigma_tilt_deg, 90.0)?;
        c.positive("sigma_yaw_deg", i.sigma_yaw_deg, 180.0)?;
        c.positive("sigma_position_m", i.sigma_position_m, 1e4)?;
        c.positive("sigma_yaw_autopilot_deg", i.sigma_yaw_autopilot_deg, 180.0)?;
        c.positive("sigma_yaw_compass_deg", i.sigma_yaw_compass_deg, 180.0)?;
        c.positive("restart_sigma_position_m", i.restart_sigma_position_m, 1e4)?;
        c.positive("restart_sigma_velocity_mps", i.restart_sigma_velocity_mps, 100.0)?;
        c.positive("sigma_position_autopilot_m", i.sigma_position_autopilot_m, 1e4)?;
        c.positive("sigma_velocity_mps", i.sigma_velocity_mps, 100.0)?;
        c.positive("sigma_accel_bias_mps2", i.sigma_accel_bias_mps2, 10.0)?;
        c.positive("sigma_gyro_bias_radps", i.sigma_gyro_bias_radps, 1.0)?;
        c.positive(
            "sigma_gyro_bias_in_flight_radps",
            i.sigma_gyro_bias_in_flight_radps,
            1.0,
        )
    }

    /// `[keyframe]`: the interval and the count.
    fn validate_keyframe(&self) -> Result<(), FieldError> {
        let c = Check::new("keyframe");
        c.positive("interval_s", self.keyframe.interval_s, 3600.0)?;
        c.within("max", self.keyframe.max as u64, 0, 100_000, "set 0..100000")
    }

    /// `[compressed]`: the local radius and the local keyframe count.
    fn validate_compressed(&self) -> Result<(), FieldError> {
        let c = Check::new("compressed");
        c.positive("local_radius_m", self.compressed.local_radius_m, 1e5)?;
        c.within(
            "max_local_keyframes",
            self.compressed.max_local_keyframes as u64,
            2,
            10_000,
            "set 2..10000",
        )?;
        Ok(())
    }

    /// `[gnss]`: the source, the systems, the noise, the Klobuchar
    /// coefficients, the origin and the week hint.
    fn validate_gnss(&self) -> Result<(), FieldError> {
        let g = &self.gnss;
        let c = Check::new("gnss");
        if g.source == GnssSource::Stream && g.stream.is_empty() {
            return Err(c.fail(
                "stream",
                "is empty but source = \"stream\"",
                "give serial:DEV:BAUD, tcp:HOST:PORT or file:PATH",
            ));
        }
        if let Err(why) = crate::gnss::parse_systems(&g.systems) {
            return Err(c.fail("systems", why, "use letters of G, E, R, C, J, e.g. \"G,E,R,C\""));
        }
        c.range("elevation_mask_deg", g.elevation_mask_deg, 0.0, 60.0)?;
        c.range("dgnss_max_age_s", g.dgnss_max_age_s, 0.1, 60.0)?;
        c.range(
            "dgnss_correction_rate_sigma_mps",
            g.dgnss_correction_rate_sigma_mps,
            0.0,
            10.0,
        )?;
        c.range("base_max_position_error_m", g.base_max_position_error_m, 1.0, 10_000.0)?;
        c.range("base_position_sigma_m", g.base_position_sigma_m, 0.0, 100.0)?;
        c.range("base_holdoff_s", g.base_holdoff_s, 0.0, 3600.0)?;
        c.positive("pseudorange_sigma_m", g.pseudorange_sigma_m, 1e3)?;
        c.range("broadcast_sigma_m", g.broadcast_sigma_m, 0.0, 100.0)?;
        c.range("troposphere_sigma_m", g.troposphere_sigma_m, 0.0, 10.0)?;
        c.positive("range_bias_sigma_m", g.range_bias_sigma_m, 100.0)?;
        c.range("range_bias_rw_m_per_sqrt_s", g.range_bias_rw_m_per_sqrt_s, 0.0, 1.0)?;
        c.range("range_bias_timeout_s", g.range_bias_timeout_s, 1.0, 86_400.0)?;
        c.range("troposphere_rw_m_per_sqrt_s", g.troposphere_rw_m_per_sqrt_s, 0.0, 1.0)?;
        c.positive("range_rate_sigma_mps", g.range_rate_sigma_mps, 1e2)?;
        c.range("correlation_window_s", g.correlation_window_s, 0.0, 600.0)?;
        c.range("ionosphere_window_s", g.ionosphere_window_s, 0.0, 3600.0)?;
        c.range(
            "range_rate_correlated_sigma_mps",
            g.range_rate_correlated_sigma_mps,
            0.0,
            10.0,
        )?;
        c.positive("clock_bias_rw_m_per_sqrt_s", g.clock_bias_rw_m_per_sqrt_s, 1e3)?;
        c.positive("clock_drift_rw_mps_per_sqrt_s", g.clock_drift_rw_mps_per_sqrt_s, 1e3)?;
        c.positive("isb_rw_m_per_sqrt_s", g.isb_rw_m_per_sqrt_s, 1e3)?;
        for (k, v) in g.p_A_in_B_m.iter().enumerate() {
            c.range(&format!("p_A_in_B_m[{k}]"), *v, -10.0, 10.0)?;
        }
        c.positive("epoch_rate_hz", g.epoch_rate_hz, 100.0)?;
        c.range("max_delay_s", g.max_delay_s, 0.0, 10.0)?;
        self.validate_klobuchar(&c)?;
        self.validate_origin(&c)?;
        if g.week_hint != 0 {
            c.within(
                "week_hint",
                g.week_hint as u64,
                1024,
                10_000,
                "give a full GPS week (e.g. 2443) or 0",
            )?;
        }
        Ok(())
    }

    /// `gnss.klobuchar_alpha` and `gnss.klobuchar_beta`: four finite
    /// coefficients each, or both empty.
    fn validate_klobuchar(&self, c: &Check) -> Result<(), FieldError> {
        let g = &self.gnss;
        for (name, v) in [
            ("klobuchar_alpha", &g.klobuchar_alpha),
            ("klobuchar_beta", &g.klobuchar_beta),
        ] {
            if !(v.is_empty() || v.len() == 4) {
                return Err(c.fail(name, format!("has {} values", v.len()), "give four coefficients or []"));
            }
            c.all_finite(name, v, -1e7, 1e7)?;
        }
        if g.klobuchar_alpha.len() != g.klobuchar_beta.len() {
            return Err(c.fail(
                "klobuchar_beta",
                "is set without klobuchar_alpha (or the reverse)",
                "give both or neither",
            ));
        }
        Ok(())
    }

    /// `gnss.origin_llh`: empty, or a latitude, longitude and height in range.
    fn validate_origin(&self, c: &Check) -> Result<(), FieldError> {
        let g = &self.gnss;
        if !g.origin_llh.is_empty() {
            if g.origin_llh.len() != 3 {
                return Err(c.fail(
                    "origin_llh",
                    format!("has {} values", g.origin_llh.len()),
                    "give [lat_deg, lon_deg, h_m] or []",
                ));
            }
            c.range("origin_llh[0]", g.origin_llh[0], -90.0, 90.0)?;
            c.range("origin_llh[1]", g.origin_llh[1], -180.0, 180.0)?;
            c.range("origin_llh[2]", g.origin_llh[2], -500.0, 1e4)?;
        }
        Ok(())
    }
}

/// Reads a MAVLink signing key: 64 hex digits (whitespace around them
/// ignored) in a file only its owner can read or write. Errors are
/// `(problem, fix)`.
pub fn load_signing_key(path: &std::path::Path) -> Result<[u8; 32], (String, String)> {
    use std::os::unix::fs::PermissionsExt;
    let shown = path.display();
    let meta = std::fs::metadata(path).map_err(|e| {
        (
            format!("cannot read {shown}: {e}"),
            "create it with: head -c 32 /dev/urandom | xxd -p -c 64 > FILE; chmod 600 FILE".into(),
        )
    })?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err((
            format!("{shown} has mode {mode:03o}: others can read the key"),
            format!("chmod 600 {shown}"),
        ));
    }
    // A key file is 64 hex digits and a newline: refuse to read a large file.
    if meta.len() > 256 {
        return Err((
            format!("{shown} is {} bytes", meta.len()),
            "it holds 64 hex digits".into(),
        ));
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| (format!("cannot read {shown}: {e}"), "check the file".into()))?;
    let hex = text.trim();
    let bad = || {
        (
            format!("{shown} does not hold 64 hex digits"),
            "write the 32-byte key as 64 hex digits".to_string(),
        )
    };
    if hex.len() != 64 || !hex.is_ascii() {
        return Err(bad());
    }
    let mut key = [0u8; 32];
    for (i, b) in key.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
    }
    Ok(key)
}

#[cfg(test)]
mod tests {
    use super::super::OutputMessage;
    use super::*;

    /// `[output]`: the position's covariance by the autopilot's parameters
    /// by default, whole or given our yaw when asked, and a wrong value
    /// refused with those it may be.
    #[test]
    fn output_position_covariance_follows_the_autopilot_unless_asked() {
        use crate::config::PositionCovariance;
        assert_eq!(Config::default().output.position_covariance, PositionCovariance::Auto);
        let c = Config::from_toml("[output]\nposition_covariance = \"given_yaw\"\n", "x").unwrap();
        assert_eq!(c.output.position_covariance, PositionCovariance::GivenYaw);
        let c = Config::from_toml("[output]\nposition_covariance = \"absolute\"\n", "x").unwrap();
        assert_eq!(c.output.position_covariance, PositionCovariance::Absolute);
        let e = Config::from_toml("[output]\nposition_covariance = \"yes\"\n", "x")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("position_covariance") && e.contains("`auto`") && e.contains("`given_yaw`"),
            "{e}"
        );
    }

    /// `[output]`: one message by name, the default ODOMETRY, and the
    /// removed `odometry` switch refused with what replaces it.
    #[test]
    fn output_message_is_named_and_the_old_switch_says_what_replaced_it() {
        assert_eq!(Config::default().output.message, OutputMessage::Odometry);
        let c = Config::from_toml("[output]\nmessage = \"vision_position_estimate\"\n", "x").unwrap();
        assert_eq!(c.output.message, OutputMessage::VisionPositionEstimate);
        let c = Config::from_toml("[output]\nmessage = \"odometry\"\n", "x").unwrap();
        assert_eq!(c.output.message, OutputMessage::Odometry);
        // A written config never has the old key.
        assert!(!toml::to_string(&c).unwrap().contains("odometry ="));
        let e = Config::from_toml("[output]\nmessage = \"vpe\"\n", "x")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("message") && e.contains("`odometry`") && e.contains("`vision_position_estimate`"),
            "{e}"
        );
        for old in ["true", "false"] {
            let e = Config::from_toml(&format!("[output]\nodometry = {old}\n"), "x")
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("output.odometry")
                    && e.contains("message = \"odometry\"")
                    && e.contains("vision_position_estimate"),
                "{e}"
            );
        }
    }
}
