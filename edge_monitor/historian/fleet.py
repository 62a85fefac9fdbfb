"""The fleet questions: per joint the newest wear and its band, the forecast, open faults, the last
maintenance and when its robot was last heard; the joints ranked by wear or by forecast.

Read from the small tables the writer keeps (``joints``, ``faults``, ``agents``), so the cost grows with
the number of joints, not with the history. Ranking by ``forecast`` orders by the prognosis' median days
to the critical wear (``prognosis.days.median`` of the newest symptom), soonest first; joints without a
forecast (none published yet, or beyond the horizon) follow, by wear. The wear band is the one the Rerun
view draws: ϖ̂ ± 2σ, or 0 … the one-sided 95 % bound where wear is not identifiable.
The last maintenance is the newer of a "cleared" alarm record (the agent relearned after a declared
maintenance) and a maintenance request seen on ``edge/<robot>/<joint>/maintenance`` (the agent may have
refused it: ``source`` says which).
"""

from __future__ import annotations

from typing import Any

from edge_monitor.historian.database import Connection, stored_record
from edge_monitor.historian.identity import forecast_days
from edge_monitor.historian.query_spec import HistoryQuery
from edge_monitor.historian.times import utc_of_seconds
from edge_monitor.sinks.rerun_draw import wear_bounds
from protocol.numbers import finite_or_none

_ORDER = {
    "wear": "(wear IS NULL), wear DESC, robot, joint",
    "forecast": "(days_median IS NULL), days_median, (wear IS NULL), wear DESC, robot, joint",
    "robot": "robot, joint",
}


def _where(query: HistoryQuery, joint: bool = True) -> tuple[str, list[Any]]:
    clauses: list[str] = ["1 = 1"]
    params: list[Any] = []
    if query.robot is not None:
        clauses.append("robot = ?")
        params.append(query.robot)
    if joint and query.joint is not None:
        clauses.append("joint = ?")
        params.append(query.joint)
    return " AND ".join(clauses), params


def fleet_answer(conn: Connection, query: HistoryQuery, now: float, online: set[str] | None) -> dict[str, Any]:
    where, params = _where(query)
    rows = conn.rows(f"SELECT robot, joint, cycle, utc, body FROM joints WHERE {where} ORDER BY {_ORDER[query.rank]} "
                     "LIMIT ?", (*params, query.limit + 1))
    agents = _agents(conn, query, now, online)
    faults = _open_faults(conn, where, params)
    maintenance = _maintenance(conn, where, params)
    joints = []
    for rank, (robot, joint, cycle, utc, body) in enumerate(rows[:query.limit], start=1):
        record = stored_record(body)
        agent = agents.get(robot, {})
        joints.append({
            "rank": rank, "robot": robot, "joint": joint, "cycle": cycle, "utc": utc,
            "wear": _wear(record), "critical_wear": finite_or_none(record.get("critical_wear")),
            "alarm": record.get("alarm") is True, "prognosis": record.get("prognosis"),
            "forecast_days": forecast_days(record),
            "open_faults": faults.get((robot, joint), []), "last_maintenance": maintenance.get((robot, joint)),
            "last_heard": agent.get("last_heard"), "stale": agent.get("stale"), "online": agent.get("online")})
    stale = sorted(robot for robot, agent in agents.items() if agent["stale"])
    return {"joints": joints, "agents": list(agents.values()), "stale_agents": stale, "count": len(joints),
            "truncated": len(rows) > query.limit, "next": None}


def _wear(record: dict[str, Any]) -> dict[str, Any]:
    found = record.get("wear")
    wear: dict[str, Any] = found if isinstance(found, dict) else {}
    upper, lower = wear_bounds([record])
    return {"estimate": finite_or_none(wear.get("estimate")), "std": finite_or_none(wear.get("std")),
            "upper_95": finite_or_none(wear.get("upper_95")), "identifiable": wear.get("identifiable"),
            "band": [finite_or_none(lower[0]), finite_or_none(upper[0])]}


def _agents(conn: Connection, query: HistoryQuery, now: float, online: set[str] | None) -> dict[str, dict[str, Any]]:
    where, params = _where(query, joint=False)
    found = conn.rows(f"SELECT robot, first_heard, last_heard, health_at FROM agents WHERE {where} ORDER BY robot "
                      "LIMIT ?", (*params, query.limit))
    return {robot: {"robot": robot, "first_heard": utc_of_seconds(first), "last_heard": utc_of_seconds(last),
                    "silent_s": round(max(0.0, now - last), 3), "stale": now - last > query.stale_s,
                    "online": None if online is None else robot in online, "health_utc": utc_of_seconds(health)}
            for robot, first, last, health in found}


def _open_faults(conn: Connection, where: str, params: list[Any]) -> dict[tuple[str, int], list[dict[str, Any]]]:
    out: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for robot, joint, fault, state, quantity, cycle, at in conn.rows(
            f"SELECT robot, joint, fault, state, quantity, cycle, at FROM faults WHERE {where} AND is_open = 1 "
            "ORDER BY robot, joint, at", params):
        out.setdefault((robot, joint), []).append({"fault": fault, "state": state, "quantity": quantity,
                                                   "cycle": cycle, "utc": utc_of_seconds(at)})
    return out


def _maintenance(conn: Connection, where: str, params: list[Any]) -> dict[tuple[str, int], dict[str, Any]]:
    newest: dict[tuple[str, int], dict[str, Any]] = {}
    for robot, joint, kind, at, cycle in conn.rows(
            f"SELECT robot, joint, kind, MAX(at), MAX(cycle) FROM records WHERE {where} AND "
            "(kind = 'maintenance' OR (kind = 'alarm' AND state = 'cleared')) GROUP BY robot, joint, kind", params):
        key = (robot, joint)
        if key not in newest or at > newest[key]["_at"]:
            newest[key] = {"_at": at, "utc": utc_of_seconds(at), "cycle": cycle,
                           "source": "request" if kind == "maintenance" else "cleared"}
    return {key: {k: v for k, v in value.items() if k != "_at"} for key, value in newest.items()}
