"""``edge-monitor acknowledge --robot R --joint J [--quantity Q ...]``: tell a running agent that the
latched alarm(s) of a joint were false.

Asks the agent for the joint's state (``edge/R/J/state``), puts the acknowledgement on
``edge/R/J/acknowledge`` and waits, at most ``--timeout`` seconds in all, for the agent's
"acknowledged" alarm records on ``edge/R/J/alarm``. Each acknowledged detector restarts its statistic
on the same nominal and threshold; a later crossing raises a new alarm (docs/DETECTION.md). The agent
must accept remote acknowledgements (``run --allow-remote-acknowledge`` or ``[acknowledge] remote =
true``), and the Zenoh router must let this identity put on that key (docs/SECURITY.md).
"""

from __future__ import annotations

import argparse
import getpass
import json
import sys
import threading
import time
from typing import Any

from edge_monitor.commands.common import add_tls_arguments, add_zenoh_arguments, zenoh_options_with_tls
from edge_monitor.features.registry import QUANTITIES
from edge_monitor.sinks.acknowledge import AcknowledgeRequest, parse_request
from edge_monitor.sinks.keys import ACKNOWLEDGE, ALARM, STATE, check_robot_name, joint_key
from edge_monitor.sinks.zenoh_session import ZenohOptions, ZenohSetupError, open_session
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, EXIT_OK, UsageError
from protocol.frames import MAX_JOINTS

QUERY_S = 2.0          # one state query waits at most this long; it is repeated until --timeout
EXIT_HELP = (f"{EXIT_CODES_HELP}. Here 0: acknowledged, or no alarm was latched (nothing to do); 2 also: the "
             "agent does not monitor that joint (it says which it does) or does not watch that quantity; 1: no agent "
             "answered, or no acknowledgement came within --timeout (remote acknowledgement off on the agent, "
             "refused by the router's access control or by the agent's gate: see the agent's log and its "
             "health counters acknowledge_refused_*)")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("acknowledge", help="acknowledge a joint's latched alarm(s) on a running agent",
                              description=__doc__.replace("``", ""), epilog=EXIT_HELP)
    p.add_argument("--robot", required=True, help="the agent's robot name")
    p.add_argument("--joint", type=int, required=True, help="the joint whose alarm(s) were false")
    p.add_argument("--quantity", action="append", default=None, choices=list(QUANTITIES), metavar="Q",
                   help=f"acknowledge only this quantity ({', '.join(QUANTITIES)}; repeatable; default: every "
                        "latched one)")
    p.add_argument("--by", default=None, help="who acknowledges (in the alarm record; default: the login name)")
    p.add_argument("--note", default=None, help="why the alarm was false (in the alarm record)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="wait at most S seconds for the agent (default 10)")
    add_zenoh_arguments(p)
    add_tls_arguments(p, "an operator")
    p.set_defaults(func=run)


def _login() -> str | None:
    try:
        name = getpass.getuser()
    except Exception:      # no login name in this environment (containers): the record says nobody
        return None
    try:
        return parse_request(AcknowledgeRequest(by=name).to_payload()).by
    except ValueError:
        return None


def _arguments(args: argparse.Namespace) -> tuple[AcknowledgeRequest, ZenohOptions]:
    """The request and the session the arguments describe; :class:`UsageError` naming a bad one."""
    try:
        check_robot_name(args.robot)
    except ValueError as exc:
        raise UsageError(f"--robot: {exc}") from None
    if not 0 <= args.joint < MAX_JOINTS:
        raise UsageError(f"--joint {args.joint}: a joint index is 0 … {MAX_JOINTS - 1}")
    if not 0 < args.timeout <= 3600:
        raise UsageError(f"--timeout {args.timeout:g}: must be > 0 and at most 3600 s")
    by = args.by if args.by is not None else _login()
    try:
        quantities = None if args.quantity is None else tuple(args.quantity)
        request = parse_request(AcknowledgeRequest(quantities, by, args.note).to_payload())
    except ValueError as exc:
        raise UsageError(f"--by/--note: {exc}") from None
    try:
        options = zenoh_options_with_tls(args)      # a bad config file or a plain endpoint with TLS
    except ZenohSetupError as exc:
        raise UsageError(str(exc)) from None
    return request, options


def run(args: argparse.Namespace) -> int:
    request, options = _arguments(args)
    try:
        session = open_session(options)
    except ZenohSetupError as exc:
        print(f"edge-monitor acknowledge: no agent answered: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        return _acknowledge(session, args.robot, args.joint, request, time.monotonic() + args.timeout, args.timeout)
    finally:
        session.close()


class _Acknowledged:
    """The "acknowledged" alarm records of one joint that arrive while it listens."""

    def __init__(self, session: Any, key: str) -> None:
        self.records: list[dict[str, Any]] = []
        self._changed = threading.Condition()
        self._subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        try:
            record = json.loads(sample.payload.to_bytes())
        except (ValueError, RecursionError):          # not JSON, or nested too deep: not a record
            return
        if isinstance(record, dict) and record.get("state") == "acknowledged":
            with self._changed:
                self.records.append(record)
                self._changed.notify_all()

    def wait_for(self, quantities: set[str] | None, deadline: float) -> list[dict[str, Any]]:
        """Wait until records of all ``quantities`` (None: any one) arrived, or ``deadline``; the records."""
        def done() -> bool:
            got = {q for r in self.records for q in _named(r)}
            return bool(got) if quantities is None else quantities <= got

        with self._changed:
            self._changed.wait_for(done, timeout=max(0.0, deadline - time.monotonic()))
            return list(self.records)

    def close(self) -> None:
        self._subscriber.undeclare()


def _named(record: dict[str, Any]) -> list[str]:
    """The detectors an alarm record names: those of its fault it is about (``detectors``), else its quantity."""
    detectors = record.get("detectors")
    if isinstance(detectors, list) and detectors:
        return [str(d.get("quantity")) for d in detectors if isinstance(d, dict)]
    return [str(record.get("quantity"))]


def _joint_state(session: Any, robot: str, joint: int, deadline: float) -> dict[str, Any] | None:
    """The agent's answer to ``edge/<robot>/<joint>/state``, asked again until ``deadline``; None if none came.
    :class:`UsageError` when the agent answers that it does not monitor the joint."""
    key = joint_key(robot, joint, STATE)
    warned = False
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        unknown = None
        for reply in session.get(key, timeout=min(QUERY_S, remaining)):
            if reply.ok is None:
                unknown = unknown or _not_monitored(reply)
                continue
            try:
                state = json.loads(reply.ok.payload.to_bytes())
            except (ValueError, RecursionError):      # not JSON, or nested too deep: an invalid reply
                if not warned:
                    print(f"edge-monitor acknowledge: ignored an invalid state reply on {key} (not a JSON object)",
                          file=sys.stderr)
                warned, state = True, None
            if isinstance(state, dict):
                return state
        if unknown is not None:
            raise UsageError(f"--joint {joint}: {unknown}; acknowledge one of those joints, or, if joint {joint} "
                             "should be monitored, add it to the agent's joints (its config's joints / joint "
                             "mapping, edge-monitor check-mapping) and restart it")
        time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))


def _not_monitored(reply: Any) -> str | None:
    """The agent's "does not monitor joint J (it monitors …)" of an error reply, or None for another error."""
    try:
        body = json.loads(reply.err.payload.to_bytes()) if reply.err is not None else None
    except (ValueError, RecursionError):
        return None
    if isinstance(body, dict) and isinstance(body.get("unknown_joint"), int) and isinstance(body.get("error"), str):
        return " ".join(body["error"].split())[:300]
    return None


def _latched(state: dict[str, Any], request: AcknowledgeRequest) -> list[str] | None:
    """The requested quantities whose alarm the agent has latched; None when its state does not say."""
    detectors = state.get("detectors")
    if not isinstance(detectors, dict):
        return None
    watched = [q for q in detectors if q in QUANTITIES]
    wanted = list(request.quantities or watched)
    missing = [q for q in wanted if q not in detectors]
    if missing:
        raise UsageError(f"--quantity {', '.join(missing)}: not watched on this joint (watched: "
                         f"{', '.join(watched) or 'none'})")
    if not all(isinstance(detectors[q], dict) and "latched" in detectors[q] for q in wanted):
        return None
    return [q for q in wanted if detectors[q]["latched"]]


def _acknowledge(session: Any, robot: str, joint: int, request: AcknowledgeRequest, deadline: float,
                 timeout: float) -> int:
    where = f"robot {robot} joint {joint}"
    listener = _Acknowledged(session, joint_key(robot, joint, ALARM))
    try:
        state = _joint_state(session, robot, joint, deadline)
        if state is None:
            print(f"edge-monitor acknowledge: no agent answered for {where} within {timeout:g} s (is it running "
                  "and reachable, and may this identity query it?)", file=sys.stderr)
            return EXIT_FAILURE
        if state.get("known") is False:
            print(f"{where}: the agent monitors this joint but has learned nothing for it yet (not seen on the "
                  "bus, no saved state): no alarm latched, nothing to acknowledge")
            return EXIT_OK
        latched = _latched(state, request)
        if latched == []:
            print(f"{where}: no latched alarm on {', '.join(request.quantities or ['any quantity'])}: "
                  "nothing to acknowledge")
            return EXIT_OK
        session.put(joint_key(robot, joint, ACKNOWLEDGE), request.to_payload(),
                    attachment=None if request.by is None else f"by={request.by}")
        records = listener.wait_for(None if latched is None else set(latched), deadline)
    finally:
        listener.close()
    if not records:
        print(f"edge-monitor acknowledge: the agent of {where} did not acknowledge within {timeout:g} s: remote "
              "acknowledgement may be off on it (run --allow-remote-acknowledge), or the router's access "
              "control or the agent's gate refused the request (see the agent's log)", file=sys.stderr)
        return EXIT_FAILURE
    for record in records:
        named = _named(record)
        still = ", still open" if record.get("open") else ""
        fault = f" (fault {record['fault']}{still})" if record.get("fault") else ""
        print(f"{where}: {', '.join(named)} alarm{'s' if len(named) > 1 else ''} acknowledged after cycle "
              f"{record.get('cycle')}{fault}{' by ' + str(record['by']) if record.get('by') else ''}; the "
              f"statistics restart on the same nominal and threshold")
    left = sorted(set(latched or ()) - {q for r in records for q in _named(r)})
    if left:
        print(f"{where}: no acknowledgement of {', '.join(left)} within {timeout:g} s (no longer latched?)")
    return EXIT_OK
