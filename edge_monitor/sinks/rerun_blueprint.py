"""The default Rerun blueprint of the fleet view: a wear overview, one tab per joint, one per agent.

Sent once per recording (with the first block of records; again only if a robot or joint appears later).
"""

from __future__ import annotations

from typing import Any, Mapping


def joint_path(robot: str, joint: int | str) -> str:
    """Entity path of one joint: ``/robot/<robot>/joint/<joint>``."""
    return f"/robot/{robot}/joint/{joint}"


def fleet_blueprint(layout: Mapping[str, set[int]], health_robots: set[str]) -> Any:
    """Tabs: fleet wear overview, one tab per robot joint, one per robot agent."""
    import rerun.blueprint as rrb

    all_cycles = rrb.VisibleTimeRange("cycle", start=rrb.TimeRangeBoundary.infinite(),
                                      end=rrb.TimeRangeBoundary.cursor_relative())
    overview: list[Any] = []
    tabs: list[Any] = []
    for robot in sorted(layout):
        for joint in sorted(layout[robot]):
            base = joint_path(robot, joint)
            overview.append(rrb.TimeSeriesView(origin=f"{base}/wear", name=f"{robot} · joint {joint} wear"))
            tabs.append(rrb.Grid(
                rrb.TimeSeriesView(origin=f"{base}/wear", name="wear: estimate, bounds, trend, critical level"),
                rrb.Spatial2DView(origin=f"{base}/prognosis/cone",
                                  name="forecast cone: wear vs days from now (critical level, horizon)"),
                rrb.TimeSeriesView(origin=f"{base}/prognosis/days", name="days to critical wear: median, 10–90 %"),
                rrb.TimeSeriesView(origin=f"{base}/kl", name="KL distance"),
                rrb.TimeSeriesView(origin=f"{base}/glr", name="GLR statistic vs threshold"),
                rrb.TimeSeriesView(origin=f"{base}/miss", name="miss probability",
                                   axis_y=rrb.ScalarAxis(range=(0.0, 1.0))),
                rrb.Spatial2DView(origin=f"{base}/friction", name="friction ‰ (up) vs speed rad/s, by cycle",
                                  time_ranges=[all_cycles]),
                rrb.Spatial2DView(origin=f"{base}/density", name="torque density: cycle vs nominal"),
                rrb.TimeSeriesView(origin=f"{base}/temperature", name="lubricant temperature °C"),
                rrb.TimeSeriesView(origin=f"{base}/coverage", name="share of cycles tested, per detector",
                                   axis_y=rrb.ScalarAxis(range=(0.0, 1.0))),
                rrb.TextLogView(origin=f"{base}/alarms", name="alarms"),
                rrb.TextLogView(origin=f"{base}/advisories", name="advisories (not faults)"),
                grid_columns=2, name=f"{robot} · joint {joint}"))
    for robot in sorted(set(layout) | health_robots):
        tabs.append(rrb.Vertical(
            rrb.TextLogView(origin=f"/robot/{robot}", name=f"{robot} alarms"),
            rrb.TimeSeriesView(origin=f"/robot/{robot}/agent/health", name=f"{robot} agent health"),
            name=f"{robot} · agent"))
    if overview:
        tabs.insert(0, rrb.Grid(*overview, name="fleet wear"))
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


