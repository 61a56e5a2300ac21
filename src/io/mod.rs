//! I/O adapters: they convert between the outside world and the pure
//! estimator at the boundary. `mavlink/` is the only module that names
//! `mavlink::` types; `messages.rs` holds what crosses that boundary.

pub mod base64;
pub mod feature_pipe;
pub mod gnss_stream;
pub mod live_view;
pub mod mavlink;
pub mod mcap_log;
pub mod messages;
pub mod udp_peer;
