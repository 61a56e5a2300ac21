//! What the GNSS input is told to use: the ionosphere mode (`gnss.iono`),
//! the constellations (`--systems`), and which receiver clock each
//! constellation's codes share.

use serde::{Deserialize, Serialize};

use super::rtcm::System;

/// Ionosphere handling (`gnss.iono`).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum IonoMode {
    Off,
    Klobuchar,
    IonoFree,
    Auto,
}

impl std::str::FromStr for IonoMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "off" => Ok(IonoMode::Off),
            "klobuchar" => Ok(IonoMode::Klobuchar),
            "iono-free" => Ok(IonoMode::IonoFree),
            "auto" => Ok(IonoMode::Auto),
            _ => Err(format!(
                "unknown ionosphere mode '{s}': use off, klobuchar, iono-free or auto"
            )),
        }
    }
}

/// Parses a `--systems` list such as `G,E,R,C,J`: GPS, Galileo, GLONASS,
/// BeiDou, QZSS.
pub fn parse_systems(s: &str) -> Result<Vec<System>, String> {
    let v = s
        .split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(|x| match x {
            "G" => Ok(System::Gps),
            "E" => Ok(System::Galileo),
            "R" => Ok(System::Glonass),
            "C" => Ok(System::BeiDou),
            "J" => Ok(System::Qzss),
            _ => Err(format!(
                "unknown system '{x}': use G (GPS), E (Galileo), R (GLONASS), C (BeiDou), J (QZSS), e.g. G,E,R"
            )),
        })
        .collect::<Result<Vec<_>, _>>()?;
    if v.is_empty() {
        return Err("no system given: use G, E, R, C or J, e.g. G,E".into());
    }
    Ok(v)
}

/// The receiver clock a constellation's codes share: QZSS keeps GPS time,
/// the others have their own (an inter-system bias from GPS's).
pub fn clock_group(s: System) -> System {
    match s {
        System::Qzss => System::Gps,
        other => other,
    }
}
