//! The Debian package a companion computer installs (scripts/package-deb.sh),
//! made from this build's own binaries and taken apart as dpkg would: its
//! control fields, the files it puts on the machine, stripped binaries that
//! still run and point at their debug info, that debug info in the -dbgsym
//! package under the binaries' build ids, units that start what the package
//! holds with the config it ships, a shipped config the daemon accepts, and
//! maintainer scripts that parse. (Installing it for real needs a machine's
//! dpkg database and systemd: docs/packaging.md says how that was checked.)
//!
//! Needs Debian's dpkg-deb and binutils (objcopy, readelf), as on the CI
//! machine; without them the test says so and checks nothing.

use std::path::{Path, PathBuf};
use std::process::Command;

fn have(tool: &str) -> bool {
    Command::new(tool)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn sections(elf: &Path) -> String {
    run(Command::new("readelf").args(["-S", "-W"]).arg(elf))
}

fn build_id(elf: &Path) -> String {
    let notes = run(Command::new("readelf").arg("-n").arg(elf).env("LC_ALL", "C"));
    notes
        .lines()
        .find_map(|l| l.trim().strip_prefix("Build ID: "))
        .unwrap_or_else(|| panic!("{} has no build id", elf.display()))
        .to_string()
}

#[test]
fn the_debian_package_holds_a_runnable_daemon_its_units_config_and_debug_info() {
    let missing: Vec<_> = ["dpkg-deb", "objcopy", "readelf"]
        .into_iter()
        .filter(|t| !have(t))
        .collect();
    if !missing.is_empty() {
        eprintln!("skipped: {missing:?} not on this machine (Debian's dpkg and binutils)");
        return;
    }
    let bin_dir = Path::new(env!("CARGO_BIN_EXE_cmsckf")).parent().unwrap().to_path_buf();
    if !bin_dir.join("cmsckf-frontend").is_file() {
        // `cargo test --workspace` (the README's and CI's) builds it.
        eprintln!("skipped: no cmsckf-frontend beside cmsckf (run `cargo test --workspace`)");
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let listed = run(Command::new("bash")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/package-deb.sh"))
        .arg("--bin-dir")
        .arg(&bin_dir)
        .arg("--out")
        .arg(out.path())
        .arg("--fast")
        // The test build has the simulator; a user's build has not (the
        // script refuses such a daemon without this).
        .arg("--allow-sim"));
    let debs: Vec<PathBuf> = listed.lines().map(PathBuf::from).collect();
    assert_eq!(debs.len(), 2, "{listed}");
    let (deb, dbgsym) = (&debs[0], &debs[1]);
    let arch = match std::env::consts::ARCH {
        "x86_64" => "amd64",
        "aarch64" => "arm64",
        other => panic!("no Debian architecture for {other}"),
    };
    let field = |deb: &Path, f: &str| {
        run(Command::new("dpkg-deb").arg("-f").arg(deb).arg(f))
            .trim()
            .to_string()
    };
    assert_eq!(field(deb, "Package"), "cmsckf");
    assert_eq!(field(deb, "Architecture"), arch);
    assert_eq!(field(deb, "Version"), env!("CARGO_PKG_VERSION"));
    let depends = field(deb, "Depends");
    assert!(depends.starts_with("libc6 (>= 2."), "{depends}");
    assert_eq!(field(dbgsym, "Package"), "cmsckf-dbgsym");
    assert_eq!(
        field(dbgsym, "Depends"),
        format!("cmsckf (= {})", env!("CARGO_PKG_VERSION"))
    );

    // What it puts on the machine.
    let root = out.path().join("root");
    run(Command::new("dpkg-deb").arg("-x").arg(deb).arg(&root));
    for f in [
        "usr/bin/cmsckf",
        "usr/bin/cmsckf-frontend",
        "lib/systemd/system/cmsckf.service",
        "lib/systemd/system/cmsckf-frontend.service",
        "etc/cmsckf/cmsckf.toml",
        "etc/default/cmsckf-frontend",
        "usr/share/doc/cmsckf/copyright",
        "usr/share/doc/cmsckf/README.md",
        "usr/share/doc/cmsckf/changelog.gz",
        "usr/share/man/man1/cmsckf.1.gz",
        "usr/share/man/man1/cmsckf-frontend.1.gz",
        "usr/share/lintian/overrides/cmsckf",
        "usr/share/cmsckf/camera-socket.py",
    ] {
        assert!(root.join(f).is_file(), "the package has no /{f}");
    }

    // Stripped binaries that run, each pointing at its debug info, which
    // the -dbgsym package holds under the binary's build id.
    let dbg_root = out.path().join("dbg");
    run(Command::new("dpkg-deb").arg("-x").arg(dbgsym).arg(&dbg_root));
    for b in ["cmsckf", "cmsckf-frontend"] {
        let bin = root.join("usr/bin").join(b);
        let s = sections(&bin);
        assert!(!s.contains(".debug_info"), "{b} is not stripped");
        assert!(s.contains(".gnu_debuglink"), "{b} does not name its debug file");
        let id = build_id(&bin);
        assert_eq!(id, build_id(&bin_dir.join(b)), "stripping changed {b}'s build id");
        let debug = dbg_root.join(format!("usr/lib/debug/.build-id/{}/{}.debug", &id[..2], &id[2..]));
        assert!(debug.is_file(), "no debug info for {b} at {}", debug.display());
        assert!(
            sections(&debug).contains(".debug_info"),
            "{b}'s debug file has no DWARF"
        );
        assert!(
            std::fs::metadata(&bin).unwrap().len() < std::fs::metadata(bin_dir.join(b)).unwrap().len() / 2,
            "{b} is not much smaller stripped"
        );
    }
    let version = run(Command::new(root.join("usr/bin/cmsckf")).arg("--version"));
    assert!(version.starts_with("cmsckf "), "{version}");
    let help = run(Command::new(root.join("usr/bin/cmsckf-frontend")).arg("--help"));
    assert!(
        help.contains("--v4l2"),
        "the packaged front-end has no V4L2 camera: {help}"
    );

    // The shipped config is one the packaged daemon starts with, its
    // socket where the units put it, its clock the V4L2 front-end's.
    let config = root.join("etc/cmsckf/cmsckf.toml");
    let check = run(Command::new(root.join("usr/bin/cmsckf"))
        .args(["run", "--check", "--config"])
        .arg(&config));
    assert!(check.contains("feature socket /run/cmsckf/features.sock"), "{check}");
    let toml = std::fs::read_to_string(&config).unwrap();
    assert!(
        toml.contains("\nclock = \"monotonic\""),
        "the packaged config keeps the autopilot clock"
    );
    assert!(
        toml.contains("\nmodel_noise_px = 0.1 "),
        "the packaged config leaves a host-stamped camera's jitter out of the model noise"
    );

    // The units start what the package holds, as its user, with its config.
    let unit = std::fs::read_to_string(root.join("lib/systemd/system/cmsckf.service")).unwrap();
    for line in [
        "ExecStart=/usr/bin/cmsckf run --config /etc/cmsckf/cmsckf.toml",
        "User=cmsckf",
        "RuntimeDirectoryMode=0750",
        "RuntimeDirectoryPreserve=restart",
        "LogsDirectory=cmsckf",
    ] {
        assert!(unit.lines().any(|l| l == line), "cmsckf.service lacks {line}");
    }
    assert!(
        !unit.contains("DynamicUser=yes"),
        "a dynamic user cannot share the socket"
    );
    let frontend = std::fs::read_to_string(root.join("lib/systemd/system/cmsckf-frontend.service")).unwrap();
    let exec = frontend
        .lines()
        .find_map(|l| l.strip_prefix("ExecStart="))
        .expect("cmsckf-frontend.service has no ExecStart");
    let exe = exec.split_whitespace().next().unwrap();
    assert!(
        root.join(exe.trim_start_matches('/')).is_file(),
        "{exe} is not in the package"
    );
    assert!(exec.contains("--socket /run/cmsckf/features.sock") && exec.contains("--config /etc/cmsckf/cmsckf.toml"));
    assert!(frontend.lines().any(|l| l == "User=cmsckf"));

    // Both units as locked down as the hand-installed one (tests/service.rs):
    // systemd's own exposure score, read offline from the unit file. (Not
    // with `--root`: systemd 257, Debian 13's, looks for units only under
    // the root's /usr/lib, and the package's tree has its /lib unmerged.)
    if have("systemd-analyze") {
        for unit in ["cmsckf.service", "cmsckf-frontend.service"] {
            let out = Command::new("systemd-analyze")
                .args(["security", "--offline=true", "--no-pager"])
                .arg(root.join("lib/systemd/system").join(unit))
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&out.stdout);
            let score: f64 = text
                .lines()
                .find_map(|l| l.split("Overall exposure level for ").nth(1))
                .and_then(|l| l.split(':').nth(1))
                .and_then(|l| l.split_whitespace().next())
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("no exposure score for {unit}: {text}"));
            eprintln!("{unit}: exposure {score}");
            assert!(score <= 3.0, "{unit} exposure {score} > 3.0");
        }
    } else {
        eprintln!("systemd-analyze is not here: the units' exposure is not scored");
    }

    // Conffiles that exist, maintainer scripts that parse.
    let control = out.path().join("control");
    run(Command::new("dpkg-deb").arg("-e").arg(deb).arg(&control));
    let conffiles = std::fs::read_to_string(control.join("conffiles")).unwrap();
    for f in conffiles.lines() {
        assert!(
            root.join(f.trim_start_matches('/')).is_file(),
            "conffile {f} is not in the package"
        );
    }
    // Checksums of every file, for `dpkg --verify`.
    let md5sums = std::fs::read_to_string(control.join("md5sums")).unwrap();
    assert!(md5sums.lines().any(|l| l.ends_with("  usr/bin/cmsckf")), "{md5sums}");
    for script in ["postinst", "prerm", "postrm"] {
        run(Command::new("sh").arg("-n").arg(control.join(script)));
    }
    let postinst = std::fs::read_to_string(control.join("postinst")).unwrap();
    assert!(
        postinst.contains("adduser --system --group"),
        "postinst makes no system user"
    );

    // Debian's policy checker, where it is installed: no error or warning
    // (the one override, the Rust translation of libyaml compiled in, is in
    // the package and says why).
    if have("lintian") {
        let out = Command::new("lintian")
            .args(["--tag-display-limit", "0"])
            .arg(deb)
            .arg(dbgsym)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stdout);
        let tags: Vec<&str> = said
            .lines()
            .filter(|l| l.starts_with("E: ") || l.starts_with("W: "))
            .collect();
        eprintln!("lintian: {} errors or warnings", tags.len());
        assert!(tags.is_empty(), "lintian: {tags:#?}");
    } else {
        eprintln!("lintian is not here: the package is not checked against Debian's policy");
    }
}
