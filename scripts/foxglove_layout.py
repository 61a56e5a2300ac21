#!/usr/bin/env python3
"""Writes docs/foxglove-layout.sdk.json, the Foxglove SDK/notebook layout for a cmsckf log
(the desktop app imports docs/foxglove-layout.json instead: see docs/foxglove.md).

Why a script: the layout is built from the typed panel classes of
Foxglove's own Python SDK (`foxglove-sdk`, module `foxglove.layouts`), so
every key is one Foxglove defines, rather than hand-written JSON that no
tool here can open. `tests/read_mcap.py --layout` then checks that every
topic and message path the layout names exists in a real log.

Usage: python3 scripts/foxglove_layout.py [OUT.json]   (pip install foxglove-sdk)

Panels: the 3D scene in the z-up `map` frame following `base_link`, the
Map with the fused estimate and the single-point fixes, three plots
(position σ, NIS per degree of freedom with its 95% bounds, time per
frame) and the Log.
"""
import json
import sys

import foxglove.layouts as fl


def series(path: str, label: str, color: str | None = None, dashed: bool = False) -> fl.PlotSeries:
    return fl.PlotSeries(
        value=path,
        label=label,
        enabled=True,
        color=color,
        line_style="dashed" if dashed else None,
        timestamp_method="receiveTime",
    )


def plot(title: str, y_label: str, paths: list[fl.PlotSeries]) -> fl.PlotPanel:
    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(
            paths=paths,
            y_axis_label=y_label,
            show_legend=True,
            legend_display="top",
            is_synced=True,
            x_axis_val="timestamp",
        ),
    )


def item(content, proportion: float = 1.0) -> fl.SplitItem:
    return fl.SplitItem(proportion=proportion, content=content)


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(
        title="3D (map: ENU, z up)",
        config=fl.ThreeDeeConfig(
            fixed_frame="map",
            follow_tf="base_link",
            enu_frame_id="map",
            topics={
                "/pose": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color="#1f77b4"),
                "/keyframes": fl.BaseRendererPosesTopicSettings(visible=True, type="axis", axis_scale=2.0),
                "/landmarks": fl.BaseRendererPointCloudTopicSettings(visible=True, point_size=3.0),
            },
        ),
    )
    map_panel = fl.MapPanel(
        title="Map: fused estimate and GNSS single-point fixes",
        config=fl.MapConfig(
            follow_topic="/location",
            topic_colors={"/location": "#1f77b4", "/gnss/fix": "#2ca02c"},
        ),
    )
    sigma = plot(
        "Position σ (m)",
        "σ (m)",
        [
            series("/filter/state.sigma_p_m[0]", "σ north"),
            series("/filter/state.sigma_p_m[1]", "σ east"),
            series("/filter/state.sigma_p_m[2]", "σ down"),
        ],
    )
    nis = plot(
        "NIS per degree of freedom, with its 95% χ² bounds",
        "NIS / dof",
        [
            series("/filter/update/vision.nis_per_dof", "vision NIS/dof", "#1f77b4"),
            series("/filter/update/vision.nis_per_dof_95[0]", "2.5%", "#d62728", dashed=True),
            series("/filter/update/vision.nis_per_dof_95[1]", "97.5%", "#d62728", dashed=True),
        ],
    )
    timing = plot(
        "Estimator time per camera frame (µs)",
        "µs",
        [series("/filter/update/vision.elapsed_us", "time per frame")],
    )
    log = fl.LogPanel(title="Log", config=fl.LogConfig(topic_to_render="/log", show_level=True))
    left = fl.SplitContainer(direction="column", items=[item(three_d, 3), item(map_panel, 2)])
    right = fl.SplitContainer(
        direction="column",
        items=[item(sigma), item(nis), item(timing), item(log)],
    )
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[item(left, 3), item(right, 2)]))


def main() -> int:
    out = sys.argv[1] if len(sys.argv) > 1 else "docs/foxglove-layout.sdk.json"
    doc = json.loads(layout().to_json())
    with open(out, "w", encoding="utf-8") as f:
        json.dump(doc, f, indent=2, ensure_ascii=False)
        f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
