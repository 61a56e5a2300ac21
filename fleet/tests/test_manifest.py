"""The KubeRay manifest (deploy/rayjob.yaml) parses, is a RayJob of the Ray
version cmsckf-fleet pins, and names the image and entrypoint that
docs/fleet.md describes and deploy/Dockerfile builds."""

from __future__ import annotations

import re
import shlex

import yaml

from conftest import REPO

IMAGE = "cmsckf-fleet:0.1.0"


def test_the_rayjob_manifest_names_the_documented_image_and_entrypoint():
    job = yaml.safe_load((REPO / "deploy" / "rayjob.yaml").read_text())
    docs = (REPO / "docs" / "fleet.md").read_text()
    dockerfile = (REPO / "deploy" / "Dockerfile").read_text()
    pyproject = (REPO / "fleet" / "pyproject.toml").read_text()

    assert job["apiVersion"] == "ray.io/v1" and job["kind"] == "RayJob"
    cluster = job["spec"]["rayClusterSpec"]
    pinned = re.search(r'"ray==([0-9.]+)"', pyproject).group(1)
    assert cluster["rayVersion"] == pinned
    assert f"FROM rayproject/ray:{pinned}-" in dockerfile

    pods = [cluster["headGroupSpec"]] + cluster["workerGroupSpecs"]
    images = {c["image"] for pod in pods for c in pod["template"]["spec"]["containers"]}
    assert images == {IMAGE}
    assert f"-t {IMAGE}" in dockerfile
    assert f"`{IMAGE}`" in docs

    entrypoint = job["spec"]["entrypoint"]
    argv = shlex.split(entrypoint)
    assert argv[0] == "cmsckf-fleet" and argv[1] in ("review", "sweep", "regress")
    assert entrypoint in docs, "docs/fleet.md must quote the manifest's entrypoint"

    # The manifest's command line is one the package accepts.
    from cmsckf_fleet.cli import parser

    args = parser().parse_args(argv[1:])
    assert args.command == argv[1]
