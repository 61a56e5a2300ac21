//! Raw GNSS input: reassembly of RTCM3 from MAVLink `GPS_RTCM_DATA`
//! fragments, RTCM3 framing and decoding, broadcast ephemerides and the
//! single-point solution.
//!
//! [`Receiver`] ties them together the way a live stream arrives: messages
//! in order, ephemerides stored as they come, observations grouped into
//! epochs (by time of week and the MSM multiple-message bit) and solved once
//! the epoch is complete.
//!
//! Like the estimator it does no I/O and keeps no clock (but for
//! [`gps_week_now`], the week hint's fallback): bytes come in from
//! `io::mavlink` or `io::gnss_stream`, and it stands on `cmsckf-models` alone.

pub mod dgnss;
pub mod ephemeris_store;
mod epoch_assembly;
mod framing;
pub mod inav;
pub mod lnav;
mod options;
mod raw_sat;
pub mod reassembly;
mod receiver;
pub mod rtcm;
mod sat_measurements;
pub mod spp;
mod stream_decoder;
pub mod ubx;

pub use epoch_assembly::EpochAssembler;
pub use options::{clock_group, parse_systems, IonoMode};
pub use raw_sat::RawSat;
pub use receiver::{gps_week_now, Epoch, Receiver, ReceiverStats};
pub use sat_measurements::{sat_measurements, IonoPolicy};
pub use stream_decoder::StreamDecoder;

#[cfg(test)]
mod tests;
