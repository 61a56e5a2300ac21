//! Raw GNSS input. For now: reassembly of RTCM3 from MAVLink
//! `GPS_RTCM_DATA` fragments. Decoding and the filter update are the GNSS
//! issue's.

pub mod reassembly;
