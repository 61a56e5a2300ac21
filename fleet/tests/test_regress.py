"""`cmsckf-fleet regress` flags a deliberately changed build, and finds no
difference between a build and itself."""

from __future__ import annotations

import json

from conftest import fleet


def changed_build(cmsckf: str, tmp_path) -> str:
    """A "new build" whose replay differs from the real one: the same binary,
    replaying with 1.5 px of pixel noise instead of the default 1.0 (a config
    of that one field: every other field keeps its default)."""
    config = tmp_path / "changed.toml"
    config.write_text("[camera]\npixel_noise_px = 1.5\n")
    wrapper = tmp_path / "cmsckf-changed"
    wrapper.write_text(
        "#!/bin/sh\n"
        f'if [ "$1" = replay ]; then exec "{cmsckf}" "$@" --config "{config}"; fi\n'
        f'exec "{cmsckf}" "$@"\n'
    )
    wrapper.chmod(0o755)
    return str(wrapper)


def test_regress_flags_a_changed_build(cmsckf, demo_logs, tmp_path):
    done = fleet(cmsckf, "regress", cmsckf, changed_build(cmsckf, tmp_path), demo_logs, "--json", check=False)
    assert done.returncode == 1, done.stderr
    report = json.loads(done.stdout)
    assert report["flights"] == 3 and report["differing"] == 3 and report["failed"] == 0
    for flight in report["results"]:
        assert flight["differs"]
        assert flight["max_position_diff_m"] > 0
        assert flight["comparison"]["largest"]["abs_diff"] > 0
        assert flight["largest_difference"]


def test_regress_of_a_build_against_itself_finds_nothing(cmsckf, demo_logs):
    done = fleet(cmsckf, "regress", cmsckf, cmsckf, demo_logs)
    assert done.stdout.strip().endswith("0 of 3 flights differ, 0 failed"), done.stdout
    assert "DIFFERS" not in done.stdout
