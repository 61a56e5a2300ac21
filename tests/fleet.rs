//! `cmsckf-fleet` (fleet/, Python on Ray) against this build's binary: its
//! own tests (fleet/tests) through `fleet/run-tests.sh`, in a virtual
//! environment of their own under the target directory (Ray comes from
//! PyPI; a stock Debian refuses system-wide installs). They check that a
//! sweep on embedded Ray, and on a 3-node cluster simulated here, equals
//! `cmsckf evaluate` seed by seed, that a killed worker changes nothing,
//! that review writes its table and report, that regress flags a changed
//! build, and that the KubeRay manifest names the documented image.

use std::path::PathBuf;
use std::process::Command;

#[test]
fn the_fleet_tools_give_one_machines_answers() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fleet-venv");
    let status = Command::new("bash")
        .arg(root.join("fleet/run-tests.sh"))
        .arg(&venv)
        .env("CMSCKF_BIN", env!("CARGO_BIN_EXE_cmsckf"))
        .status()
        .expect("bash is needed to run fleet/run-tests.sh");
    assert!(
        status.success(),
        "fleet/run-tests.sh failed ({status}): see its pytest output above"
    );
}
