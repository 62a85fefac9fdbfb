"""A Zenoh router on loopback for a fleet of agents (there is no ``zenohd`` package on PyPI or Debian).

:func:`router_config` turns the options of ``edge-monitor router`` into a ``zenoh.Config`` in router
mode with multicast scouting off, and the endpoints it listens on. TLS flags (or a config whose
``transport/link/tls`` has a listen certificate, or whose listen endpoint is ``tls/...``) make it listen
on ``tls/HOST:PORT``; a CA also requires client certificates (mTLS). It never falls back to plain TCP:
TLS configured with a ``tcp/...`` endpoint, or a ``tls/...`` endpoint without certificate files, raises
:class:`~edge_monitor.sinks.zenoh_security.ZenohSecurityError`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import zenoh

from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.zenoh_security import (
    SECURE_PROTOCOLS,
    TlsFiles,
    ZenohSecurityError,
    apply_settings,
    check_no_downgrade,
    config_endpoints,
    router_tls_settings,
    tls_settings_of,
)
from edge_monitor.sinks.zenoh_session import DEFAULT_ROUTER_PORT, ZenohSetupError

DEFAULT_HOST = "127.0.0.1"
_ZENOH_DEFAULT_LISTEN = json.loads(zenoh.Config().get_json("listen/endpoints"))   # every interface


@dataclass(frozen=True)
class RouterOptions:
    """``config``: a Zenoh JSON5 file (TLS, access control); ``host``/``port`` replace the address of its
    listen endpoint but keep its protocol (port 0: a free loopback port); ``tls_*``: PEM files."""

    config: str | None = None
    host: str | None = None
    port: int | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    tls_ca: str | None = None


def router_config(options: RouterOptions) -> tuple[zenoh.Config, list[str]]:
    """The router's ``zenoh.Config`` and listen endpoints; raises ZenohSetupError/ZenohSecurityError."""
    config = load_config(options.config)
    apply_settings(config, {"mode": "router", "scouting/multicast/enabled": False})
    if options.tls_cert or options.tls_key or options.tls_ca:
        if not (options.tls_cert and options.tls_key):
            raise ZenohSecurityError("--tls-cert and --tls-key are both needed to listen on TLS")
        files = TlsFiles.from_paths(options.tls_ca, options.tls_cert, options.tls_key)
        apply_settings(config, router_tls_settings(files, mtls=True if options.tls_ca else None))
    explicit = json.loads(config.get_json("listen/endpoints")) != _ZENOH_DEFAULT_LISTEN
    configured = config_endpoints(config, "listen") if explicit else []   # never zenoh's tcp/[::] default
    tls = tls_settings_of(config)
    endpoints = choose_endpoints(configured, bool(tls.get("listen_certificate")), options.host, options.port)
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
    """The config's endpoints as they are, unless ``host``/``port`` are given or none is configured:
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
        raise ZenohSetupError(f"zenoh config file {path!r} is invalid: {one_line(exc)}") from exc


def one_line(exc: Exception) -> str:
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


def acl_warning(config: zenoh.Config) -> str | None:
    """A warning when access control names certificate CNs but mTLS is off (no client could match)."""
    acl = json.loads(config.get_json("access_control"))
    uses_cn = any(s.get("cert_common_names") for s in acl.get("subjects") or [])
    if acl.get("enabled") and uses_cn and not tls_settings_of(config).get("enable_mtls"):
        return ("access control matches certificate common names but mTLS is off (no --tls-ca / enable_mtls): "
                "no client will match those subjects")
    return None
