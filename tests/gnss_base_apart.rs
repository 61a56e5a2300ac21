//! The base station on the link, kept apart. `GPS_RTCM_DATA` carries a base
//! station's corrections to the autopilot; a daemon that took every RTCM
//! observation from the vehicle's system id as the rover's would fuse the
//! base's pseudoranges as its own (a PX4 build that re-streams injected
//! corrections, PX4 #18612). Here the same real-format MSM7 epochs (the
//! simulator's, through RTCM 1077/1097) reach the fusion loop by each
//! stream, with and without a configured rover station id, and with the
//! rover's id announcing an antenna position (MT1005) as only a base does.

use cmsckf::config::Config;
use cmsckf::counters::{Counter, Counters};
use cmsckf::daemon::{Fusion, FusionMsg, RtcmStream};
use cmsckf_sitl::dataset::Dataset;
use rtcm_rs::msg::Msg1005T;
use rtcm_rs::{Message, MessageBuilder};

mod common;

/// The simulator's receiver, as the SITL autopilot relays it.
const ROVER: u16 = 7;

/// Epochs completed as the rover's, and the counters, after `epochs` of
/// RTCM by `stream` under `rover_station_id` (after `first`, if any).
fn feed(rover_station_id: u16, stream: RtcmStream, first: Option<Vec<u8>>, station_id: u16) -> Counters {
    let mut cfg = Config::default();
    cfg.gnss.rover_station_id = rover_station_id;
    let ds = Dataset::generate("racetrack", 1, Some(12.0), &cmsckf::eval::sim_config_for(&cfg)).unwrap();
    let (ctx, _out) = common::fusion_ctx();
    let mut f = Fusion::new(cfg, None);
    if let Some(bytes) = first {
        f.handle(FusionMsg::Rtcm { bytes, stream }, &ctx);
    }
    for ep in &ds.gnss {
        let bytes = cmsckf_sitl::rtcm_out::encode_epoch(ep, station_id).unwrap();
        f.handle(FusionMsg::Rtcm { bytes, stream }, &ctx);
    }
    ctx.counters
}

/// MT1005: station `id` announcing its antenna position.
fn station_position(id: u16) -> Vec<u8> {
    let m = Msg1005T {
        reference_station_id: id,
        gps_flag: 1,
        galileo_flag: 1,
        antenna_ref_point_ecef_x_m: 4_075_580.0,
        antenna_ref_point_ecef_y_m: 931_854.0,
        antenna_ref_point_ecef_z_m: 4_801_568.0,
        ..Default::default()
    };
    MessageBuilder::new()
        .build_message(&Message::Msg1005(m))
        .unwrap()
        .to_vec()
}

#[test]
fn only_the_rovers_own_observations_are_fused() {
    // The rover's id on the vehicle's link: the rover's (12 epochs at 1 Hz).
    let c = feed(ROVER, RtcmStream::LinkVehicle, None, ROVER);
    let n = c.get(Counter::GnssRoverMsmFromLink);
    assert!(n >= 12, "{:?}", c.snapshot());
    assert!(c.get(Counter::GnssEpochs) >= 12);
    assert_eq!(c.get(Counter::GnssBaseMsmFromLink), 0);

    // Another station on the same link: a base's, kept apart.
    let c = feed(ROVER, RtcmStream::LinkVehicle, None, 759);
    assert_eq!(
        (c.get(Counter::GnssEpochs), c.get(Counter::GnssRoverMsmFromLink)),
        (0, 0)
    );
    assert_eq!(c.get(Counter::GnssBaseMsmFromLink), n);

    // No rover id configured: nothing on the link is the rover's.
    let c = feed(0, RtcmStream::LinkVehicle, None, ROVER);
    assert_eq!(c.get(Counter::GnssEpochs), 0);
    assert_eq!(c.get(Counter::GnssBaseMsmFromLink), n);

    // The rover's id from a ground station's system: a base's.
    let c = feed(ROVER, RtcmStream::LinkOther, None, ROVER);
    assert_eq!(c.get(Counter::GnssEpochs), 0);
    assert_eq!(c.get(Counter::GnssBaseMsmFromGroundStation), n);

    // The rover's id announcing its antenna position: it is a base.
    let c = feed(ROVER, RtcmStream::LinkVehicle, Some(station_position(ROVER)), ROVER);
    assert_eq!(c.get(Counter::GnssEpochs), 0, "{:?}", c.snapshot());
    assert_eq!(c.get(Counter::GnssRoverIdIsABase), 1);
    assert_eq!(c.get(Counter::GnssBaseStationPosition), 1);

    // The receiver wired to the companion is the rover, whatever its id.
    let c = feed(0, RtcmStream::Receiver, None, 759);
    assert!(c.get(Counter::GnssEpochs) >= 12);
    assert_eq!(c.get(Counter::GnssRoverMsmFromReceiver), n);
}
