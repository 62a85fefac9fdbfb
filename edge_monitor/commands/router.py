"""edge-monitor router: a Zenoh router on loopback for a fleet of agents and viewers.

Agents, viewers and listeners then use --zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447.
With --tls-cert/--tls-key (or a config with TLS files) it listens on tls/HOST:PORT; --tls-ca also
requires client certificates signed by that CA (mutual TLS), which access control by certificate
common name needs. It never falls back to plain TCP. Multicast scouting is always off.

It prints "zenoh router listening on PROTO/HOST:PORT" once ready, then one line on the security in
force, and stops cleanly on Ctrl-C or SIGTERM. RUST_LOG=zenoh::net::routing::interceptor::access_control=info
logs clients that match no access-control subject (trace: every decision).
"""

from __future__ import annotations

import argparse
import sys

from edge_monitor.sinks.loopback import MAX_PORT, is_port
from edge_monitor.sinks.zenoh_router import (
    DEFAULT_HOST,
    RouterOptions,
    acl_warning,
    describe_security,
    one_line,
    router_config,
)
from edge_monitor.sinks.zenoh_security import ZenohSecurityError
from edge_monitor.sinks.zenoh_session import DEFAULT_ROUTER_PORT, ZenohSetupError
from protocol.console import EXIT_CODES_HELP, EXIT_FAILURE, EXIT_USAGE, stop_on_signals

NAME = "edge-monitor router"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("router", help="run a Zenoh router on loopback for agents and viewers",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                   epilog=f"{EXIT_CODES_HELP}. Ctrl-C or SIGTERM is the normal end: exit code 0")
    parser.add_argument("--port", type=int, default=None,
                        help=f"TCP port (default: the config's, else {DEFAULT_ROUTER_PORT}; 0 picks a free one)")
    parser.add_argument("--host", default=None,
                        help=f"address to listen on (default: the config's, else {DEFAULT_HOST}; "
                             "anything but loopback exposes the router to the network)")
    parser.add_argument("--config", default=None, metavar="FILE.json5",
                        help="Zenoh JSON5 config with TLS and access control, e.g. the shipped router_acl.json5 "
                             "(see docs/SECURITY.md)")
    tls = parser.add_argument_group("TLS", "listen on tls/HOST:PORT (overrides the config's TLS files)")
    tls.add_argument("--tls-cert", default=None, metavar="PEM", help="the router's certificate")
    tls.add_argument("--tls-key", default=None, metavar="PEM", help="the router's private key")
    tls.add_argument("--tls-ca", default=None, metavar="PEM",
                     help="CA of the client certificates: clients must present one (mutual TLS)")
    parser.set_defaults(func=run)
    return parser


def options_of(args: argparse.Namespace) -> RouterOptions:
    return RouterOptions(config=args.config, host=args.host, port=args.port, tls_cert=args.tls_cert,
                         tls_key=args.tls_key, tls_ca=args.tls_ca)


def run(args: argparse.Namespace) -> int:
    import zenoh
    zenoh.try_init_log_from_env()
    if args.port is not None and not is_port(args.port):
        print(f"{NAME}: --port {args.port}: must be 0 … {MAX_PORT} (0 picks a free one)", file=sys.stderr)
        return EXIT_USAGE
    try:
        config, endpoints = router_config(options_of(args))
    except (ZenohSetupError, ZenohSecurityError) as exc:
        print(f"{NAME}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    warning = acl_warning(config)
    if warning:
        print(f"{NAME}: warning: {warning}", file=sys.stderr)
    stop = stop_on_signals()
    try:
        session = zenoh.open(config)
    except Exception as exc:  # zenoh raises ZError: port in use, bad certificate, unsupported protocol
        text = one_line(exc)
        hint = "; choose another --port" if "Address already in use" in text else ""
        print(f"{NAME}: cannot listen on {', '.join(endpoints)}: {text}{hint}", file=sys.stderr)
        return EXIT_FAILURE
    print(f"zenoh router listening on {', '.join(endpoints)}", flush=True)
    print(describe_security(config, endpoints), flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        session.close()
    print("zenoh router stopped", flush=True)
    return 0
