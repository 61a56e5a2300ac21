//! The simulator's random streams: one ChaCha8 stream per purpose, derived
//! from the flight's seed, so the same seed gives bit-identical data and
//! switching one sensor off does not change the others' noise. Every part
//! that draws (the dataset's sensors, the gusts, the rendered world, the
//! served autopilot) takes its stream from here.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The RNG stream `stream` of `seed`. Streams: 1 initial biases, 2 IMU
/// noise, 3 camera tracks, 4 GNSS, 5 camera latency, 6 GNSS latency, 7 the
/// mock autopilot's EKF errors (drawn while serving), 8 the base station's
/// noise and clock, 9 its latency, 10 the gusts, 11 the rendered world's
/// blocks, 12 the true lens, 13 the mock autopilot's barometer.
pub(crate) fn rng_for(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(stream);
    r
}
