#!/usr/bin/env python3
"""Run a Zenoh router on loopback for a fleet of agents (there is no zenohd package here).

    python tools/zenoh_router.py [--port 7447] [--host 127.0.0.1]
    python tools/zenoh_router.py --config edge_monitor/defaults/zenoh/router_acl.json5 \
        --tls-ca ca.pem --tls-cert router.pem --tls-key router.key [--port 7447]

Plain: agents and viewers use ``--zenoh-mode client --zenoh-connect tcp/127.0.0.1:7447``.
Secure: TLS flags (or a config whose ``transport/link/tls`` has a listen certificate, or whose listen
endpoint is ``tls/...``) make the router listen on ``tls/HOST:PORT``; ``--tls-ca`` also requires client
certificates signed by that CA (mTLS), which access control by certificate common name needs. The
router never falls back to plain TCP: TLS configured with a ``tcp/...`` endpoint, or a ``tls/...``
endpoint without certificate files, is refused with a message (exit code 2).

``--host``/``--port`` replace the address of the config's listen endpoint but keep its protocol.
Multicast scouting is always off. Prints ``zenoh router listening on PROTO/HOST:PORT`` once ready,
then one line on the security in force, and exits cleanly (exit code 0) on SIGINT or SIGTERM.
``RUST_LOG=zenoh::net::routing::interceptor::access_control=info`` logs clients that match no ACL
subject (``trace``: every access-control decision).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import zenoh  # noqa: E402

from edge_monitor.sinks.loopback import free_loopback_port  # noqa: E402
from edge_monitor.sinks.zenoh_security import (  # noqa: E402
    SECURE_PROTOCOLS,
    TlsFiles,
    ZenohSecurityError,
    apply_settings,
    check_no_downgrade,
    config_endpoints,
    router_tls_settings,
    tls_settings_of,
)
from edge_monitor.sinks.zenoh_session import DEFAULT_ROUTER_PORT, ZenohSetupError  # noqa: E402

DEFAULT_HOST = "127.0.0.1"
_ZENOH_DEFAULT_LISTEN = json.loads(zenoh.Config().get_json("listen/endpoints"))   # every interface


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=None,
                        help=f"port (default: the config's, else {DEFAULT_ROUTER_PORT}; 0 picks a free one)")
    parser.add_argument("--host", default=None,
                        help=f"address to bind (default: the config's, else {DEFAULT_HOST}; "
                             "anything but loopback exposes the router)")
    parser.add_argument("--config", default=None, metavar="FILE.json5",
                        help="Zenoh JSON5 config (TLS, access control), e.g. "
                             "edge_monitor/defaults/zenoh/router_acl.json5")
    tls = parser.add_argument_group("TLS", "listen on tls/HOST:PORT (overrides the config's TLS files)")
    tls.add_argument("--tls-cert", default=None, metavar="PEM", help="router certificate")
    tls.add_argument("--tls-key", default=None, metavar="PEM", help="router private key")
    tls.add_argument("--tls-ca", default=None, metavar="PEM",
                     help="CA of the client certificates: clients must present one (mTLS)")
    return parser.parse_args(argv)


def build_config(args: argparse.Namespace) -> tuple[zenoh.Config, list[str]]:
    """The router's ``zenoh.Config`` and listen endpoints; raises ZenohSetupError/ZenohSecurityError."""
    config = load_config(args.config)
    apply_settings(config, {"mode": "router", "scouting/multicast/enabled": False})
    if args.tls_cert or args.tls_key or args.tls_ca:
        if not (args.tls_cert and args.tls_key):
            raise ZenohSecurityError("--tls-cert and --tls-key are both needed to listen on TLS")
        files = TlsFiles.from_paths(args.tls_ca, args.tls_cert, args.tls_key)
        apply_settings(config, router_tls_settings(files, mtls=True if args.tls_ca else None))
    explicit = json.loads(config.get_json("listen/endpoints")) != _ZENOH_DEFAULT_LISTEN
    configured = config_endpoints(config, "listen") if explicit else []   # never zenoh's tcp/[::] default
    tls = tls_settings_of(config)
    endpoints = choose_endpoints(configured, bool(tls.get("listen_certificate")), args.host, args.port)
    if endpoints != configured:
        apply_settings(config, {"listen/endpoints": endpoints})
    check_no_downgrade(endpoints, tls, "listen")
    if any(e.split("/", 1)[0] in SECURE_PROTOCOLS for e in endpoints):
        TlsFiles.from_paths(tls.get("root_ca_certificate"), tls.get("listen_certificate"),
                            tls.get("listen_private_key")).check(need_identity=True,
                                                                 need_ca=bool(tls.get("enable_mtls")))
    return config, endpoints


def choose_endpoints(configured: list[str], tls_configured: bool, host: str | None,
                     port: int | None) -> list[str]:
    """The config's endpoints as they are, unless ``--host``/``--port`` are given or none is configured:
    then one ``PROTO/HOST:PORT`` whose protocol is the config's secure one, else ``tls`` when TLS files
    are configured, else the config's (``tcp`` by default). Port 0: a free loopback port."""
    if configured and host is None and port is None:
        return configured
    protocols = [e.split("/", 1)[0] for e in configured]
    secure = [p for p in protocols if p in SECURE_PROTOCOLS]
    proto = secure[0] if secure else "tls" if tls_configured else protocols[0] if protocols else "tcp"
    default_host, default_port = _address(configured[0] if configured else None)
    host = default_host if host is None else host
    port = default_port if port is None else port
    return [f"{proto}/{host}:{free_loopback_port() if port == 0 else port}"]


def load_config(path: str | None) -> zenoh.Config:
    """The JSON5 config file, or an empty config listening nowhere yet; ZenohSetupError when unusable."""
    if path is None:
        config = zenoh.Config()
        apply_settings(config, {"listen/endpoints": []})   # zenoh would listen on every interface otherwise
        return config
    if not Path(path).is_file():
        raise ZenohSetupError(f"zenoh config file {path!r} does not exist; fix --config")
    try:
        return zenoh.Config.from_file(path)
    except Exception as exc:  # zenoh raises ZError for parse/validation failures
        raise ZenohSetupError(f"zenoh config file {path!r} is invalid: {_one_line(exc)}") from exc


def _one_line(exc: Exception) -> str:
    """Zenoh's error text on one line, without its Rust source location."""
    return " ".join(str(exc).split(" at /", 1)[0].split())


def _address(endpoint: str | None) -> tuple[str, int]:
    """(host, port) of ``PROTO/HOST:PORT``; defaults when absent."""
    if endpoint is None:
        return DEFAULT_HOST, DEFAULT_ROUTER_PORT
    address = endpoint.split("/", 1)[1].split("#", 1)[0]
    host, _, port = address.rpartition(":")
    try:
        return host or DEFAULT_HOST, int(port)
    except ValueError:
        raise ZenohSetupError(f"listen endpoint {endpoint!r} has no port; use PROTO/HOST:PORT") from None


def describe_security(config: zenoh.Config, endpoints: list[str]) -> str:
    """One line: transport security and access control in force."""
    tls = tls_settings_of(config)
    if not any(e.split("/", 1)[0] in SECURE_PROTOCOLS for e in endpoints):
        transport = "PLAIN TEXT (no TLS: anyone who reaches the port can publish and subscribe)"
    elif tls.get("enable_mtls"):
        transport = "TLS, client certificates required (mTLS)"
    else:
        transport = "TLS, no client certificates (clients are not identified)"
    acl = json.loads(config.get_json("access_control"))
    if acl.get("enabled"):
        rules = len(acl.get("rules") or [])
        access = f"access control on (default {acl.get('default_permission')}, {rules} rules)"
    else:
        access = "access control off"
    return f"zenoh router security: {transport}; {access}"


def warn_inconsistent_acl(config: zenoh.Config) -> None:
    """Warn when access control names certificate CNs but mTLS is off (no client could match)."""
    acl = json.loads(config.get_json("access_control"))
    uses_cn = any(s.get("cert_common_names") for s in acl.get("subjects") or [])
    if acl.get("enabled") and uses_cn and not tls_settings_of(config).get("enable_mtls"):
        print("zenoh_router: warning: access control matches certificate common names but mTLS is off "
              "(no --tls-ca / enable_mtls): no client will match those subjects", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    zenoh.try_init_log_from_env()   # RUST_LOG=zenoh::net::routing::interceptor::access_control=trace shows ACL decisions
    try:
        config, endpoints = build_config(args)
    except (ZenohSetupError, ZenohSecurityError) as exc:
        print(f"zenoh_router: {exc}", file=sys.stderr)
        return 2
    warn_inconsistent_acl(config)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        session = zenoh.open(config)
    except Exception as exc:  # zenoh raises ZError: port in use, bad certificate, unsupported protocol
        text = _one_line(exc)
        hint = "; choose another --port" if "Address already in use" in text else ""
        print(f"zenoh_router: cannot listen on {', '.join(endpoints)}: {text}{hint}", file=sys.stderr)
        return 1
    print(f"zenoh router listening on {', '.join(endpoints)}", flush=True)
    print(describe_security(config, endpoints), flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        session.close()
    print("zenoh router stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
