//! When zero-velocity updates may be taken, by the autopilot's word (its
//! land detector, else its arming) and the camera's.
//!
//! Why it exists: the daemon (`daemon::autopilot`) and the simulator's
//! runner (`eval::Runner`) apply one rule, so that a simulated take-off
//! tests the flight's. It holds no clock of its own: every instant is the
//! caller's (IMU time, s).

/// How long after the landed state turns to "in the air" zero-velocity
/// updates stay allowed (s): a take-off's spin-up on the ground (see
/// [`LandedGate::zupt_allowed`]).
pub const TAKEOFF_GRACE_S: f64 = 2.0;

/// How long the landed state must have said "on the ground" for its turn
/// to "in the air" to open the take-off grace (s): a touch-and-go, ground
/// effect's flicker or a stale copy between two "in the air" opens none.
pub const LANDED_CONFIRM_S: f64 = 2.0;

/// The autopilot's landed and armed states, and the take-off grace they
/// open.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LandedGate {
    on_ground: Option<bool>,
    armed: Option<bool>,
    /// Since when its landed state has said "on the ground".
    on_ground_since: Option<f64>,
    /// When its landed state turned to "in the air" after
    /// [`LANDED_CONFIRM_S`] on the ground, while the take-off grace lasts:
    /// cleared when the camera sees motion.
    left_ground_t: Option<f64>,
}

impl LandedGate {
    /// The land detector's verdict at `t_s`. Returns `true` if it changed.
    pub fn set_on_ground(&mut self, t_s: f64, on_ground: bool) -> bool {
        if self.on_ground == Some(on_ground) {
            return false;
        }
        let confirmed = self.on_ground_since.is_some_and(|t0| t_s - t0 >= LANDED_CONFIRM_S);
        self.left_ground_t = (!on_ground && self.on_ground == Some(true) && confirmed).then_some(t_s);
        self.on_ground_since = on_ground.then_some(t_s);
        self.on_ground = Some(on_ground);
        true
    }

    /// The autopilot's armed state (from its HEARTBEAT).
    pub fn set_armed(&mut self, armed: bool) {
        self.armed = Some(armed);
    }

    /// The autopilot's armed state, once it has said.
    pub fn armed(&self) -> Option<bool> {
        self.armed
    }

    /// The land detector's last verdict, if it gave one.
    pub fn on_ground(&self) -> Option<bool> {
        self.on_ground
    }

    /// On the ground by the autopilot's word: its landed state, else its
    /// being disarmed; with neither known (an autopilot that says nothing),
    /// `true`, and the IMU and camera judge alone.
    pub fn landed(&self) -> bool {
        match (self.on_ground, self.armed) {
            (Some(on_ground), _) => on_ground,
            (None, Some(armed)) => !armed,
            (None, None) => true,
        }
    }

    /// Whether a zero-velocity update may be taken at `t_s`: on the ground
    /// by the autopilot's word, or within [`TAKEOFF_GRACE_S`] of its landed
    /// state turning to "in the air" after [`LANDED_CONFIRM_S`] on the
    /// ground, until the camera sees motion ([`Self::camera_moved`]).
    ///
    /// A land detector says "in the air" while the motors spin up, before
    /// the vehicle rises (PX4's beside its SIH: 1.1 s before): with the
    /// updates ended then, the IMU alone carried the velocity through that
    /// second and strayed by ±0.2 m/s. Within the grace the IMU, the
    /// camera's disparity, the estimated speed and the update's χ² gate
    /// decide, as they do for an autopilot that reports no landed state
    /// (`estimator::zupt`). A gentle climb that the camera does not see
    /// (far features only) may be held still until the grace's end: its
    /// length bounds that.
    pub fn zupt_allowed(&self, t_s: f64) -> bool {
        self.landed() || self.in_takeoff_grace(t_s)
    }

    /// In the air by the autopilot's word, within the take-off grace at
    /// `t_s` (see [`Self::zupt_allowed`]).
    fn in_takeoff_grace(&self, t_s: f64) -> bool {
        !self.landed()
            && self
                .left_ground_t
                .is_some_and(|t0| (0.0..TAKEOFF_GRACE_S).contains(&(t_s - t0)))
    }

    /// The camera saw motion at `t_s` (a frame's features moved past the
    /// stillness bound as the estimator README's Z0 measures it, a small
    /// turn mostly taken out, `FrameReport::camera_moved`): within the take-off
    /// grace, that ends it for good. The IMU's tests alone do not: the
    /// spin-up's thrust and vibration fail them on the ground (measured
    /// beside PX4's SITL: the first frame after the land detector's turn).
    /// `true` when this ended it.
    pub fn camera_moved(&mut self, t_s: f64) -> bool {
        let open = self.in_takeoff_grace(t_s);
        if open {
            self.left_ground_t = None;
        }
        open
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grace_opens_only_after_a_confirmed_standing_and_ends_with_the_camera_or_its_length() {
        let mut g = LandedGate::default();
        // Nothing said: the IMU and camera judge alone.
        assert!(g.landed() && g.zupt_allowed(0.0));
        g.set_armed(true);
        assert!(
            !g.landed() && !g.zupt_allowed(0.0),
            "armed, no landed state: in the air"
        );
        assert!(g.set_on_ground(0.0, true) && !g.set_on_ground(0.5, true));
        assert!(g.landed());
        // A turn after less than LANDED_CONFIRM_S on the ground opens nothing.
        g.set_on_ground(1.0, false);
        assert!(!g.zupt_allowed(1.1));
        g.set_on_ground(1.2, true);
        g.set_on_ground(1.2 + LANDED_CONFIRM_S, false);
        let t0 = 1.2 + LANDED_CONFIRM_S;
        assert!(g.zupt_allowed(t0) && g.zupt_allowed(t0 + TAKEOFF_GRACE_S - 0.01));
        assert!(!g.zupt_allowed(t0 + TAKEOFF_GRACE_S), "the grace's length bounds it");
        assert!(!g.camera_moved(t0 + TAKEOFF_GRACE_S), "nothing left to end");
        // Again: the camera ends it at once, and for good.
        g.set_on_ground(10.0, true);
        g.set_on_ground(20.0, false);
        assert!(g.zupt_allowed(20.5));
        assert!(g.camera_moved(20.5) && !g.zupt_allowed(20.6) && !g.camera_moved(20.6));
        // Disarmed with no landed state: on the ground.
        let mut g = LandedGate::default();
        g.set_armed(false);
        assert!(g.landed() && g.on_ground().is_none());
    }
}
