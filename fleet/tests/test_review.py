"""`cmsckf-fleet review` on a directory of demo logs writes one table
(Parquet and CSV) whose figures are `cmsckf review`'s own, each flight's
review page, and the fleet report linking them, worst flight first."""

from __future__ import annotations

import csv
import json
import subprocess

import pyarrow.parquet

from conftest import fleet


def test_review_of_a_directory_writes_the_table_and_the_report(cmsckf, demo_logs, tmp_path):
    out = tmp_path / "review"
    fleet(cmsckf, "review", demo_logs, "--out", out, "--workers", "2", "--replay-mode", "compressed")

    rows = pyarrow.parquet.read_table(out / "fleet.parquet").to_pylist()
    assert sorted(r["flight"] for r in rows) == ["clean", "msckf", "outage"]
    with open(out / "fleet.csv", newline="") as f:
        assert [r["flight"] for r in csv.DictReader(f)] == [r["flight"] for r in rows]

    for r in rows:
        assert r["error"] is None
        want = json.loads(subprocess.run([cmsckf, "review", "--json", r["log"]], capture_output=True, check=True).stdout)
        assert r["duration_s"] == want["duration_s"]
        assert r["ate_m"] == want["position_error_rms_m"]
        assert r["nis_per_dof_mean"] == want["nis_per_dof_mean"]
        assert r["rejected_total"] == sum(want["rejected"].values())
        for reason, n in want["rejected"].items():
            assert r[f"rejected_{reason}"] == n
        assert r["autopilot_acceptance"] == 1 - want["autopilot_rejected_reports"] / want["autopilot_ratio_reports"]
        assert r["resets"] == 0
        assert (out / r["review_page"]).stat().st_size > 10_000  # cmsckf review --html's page

    # Worst first: the camera outage left the filter degraded for a while.
    assert rows[0]["flight"] == "outage"
    assert rows[0]["degraded_s"] > 0 and rows[0]["degraded_s_camera_stale"] > 0
    assert all(r["degraded_s"] == 0 for r in rows[1:])

    # Replayed in compressed mode: the compressed flights come back bit for
    # bit, the msckf one does not.
    replay = {r["flight"]: r for r in rows}
    assert replay["clean"]["replay_differs"] is False and replay["clean"]["replay_max_position_diff_m"] == 0
    assert replay["outage"]["replay_differs"] is False
    assert replay["msckf"]["replay_differs"] is True and replay["msckf"]["replay_max_position_diff_m"] > 0
    assert all(r["replay_realtime_factor"] > 1 for r in rows)

    page = (out / "report.html").read_text()
    assert "<script" not in page and "http" not in page.replace("http-equiv", "")  # self-contained
    links = [page.index(f'href="flights/{name}.html"') for name in ("outage", "clean", "msckf")]
    assert links[0] == min(links)  # the worst flight is the first row
    assert "camera_stale" in page
