"""Zenoh transport security helpers: TLS/mTLS settings from certificate files and a no-downgrade check.

Authentication and authorisation belong to the Zenoh router (mutual TLS + access control, see
``edge_monitor/defaults/zenoh/router_acl.json5`` and docs/SECURITY.md). :func:`check_no_downgrade`
makes TLS material with a plain ``tcp/...`` endpoint an error, not a silent fallback; the agent's own
local defence against remote maintenance puts is :mod:`edge_monitor.sinks.maintenance`.

Nothing here imports Zenoh at module level: the settings are plain dicts that :func:`apply_settings`
inserts into a ``zenoh.Config``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from edge_monitor.errors import key_name

log = logging.getLogger(__name__)

TLS_KEY = "transport/link/tls"
SECURE_PROTOCOLS = ("tls", "quic")                 # Zenoh link protocols that encrypt and authenticate


class ZenohSecurityError(ValueError):
    """A TLS/ACL setting cannot be used (missing file, plain-text endpoint with TLS configured, ...)."""


# -- TLS settings ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TlsFiles:
    """PEM files of one Zenoh node.

    ``ca``: certificate of the CA that signed the other side's certificate (clients: the router's;
    router: the clients', needed for mTLS only). ``cert``/``key``: this node's certificate and private
    key (a client presents them for mTLS; a router must have them to listen on ``tls/...``).
    """

    ca: Path | None
    cert: Path | None = None
    key: Path | None = None

    @classmethod
    def from_paths(cls, ca: str | Path | None, cert: str | Path | None = None,
                   key: str | Path | None = None) -> "TlsFiles":
        return cls(*(None if p is None else Path(p) for p in (ca, cert, key)))

    def check(self, need_identity: bool = False, need_ca: bool = False) -> "TlsFiles":
        """Raise :class:`ZenohSecurityError` naming the first missing/unreadable/non-PEM file; returns self.

        ``need_identity``: certificate and key required (router; client of an mTLS router).
        ``need_ca``: CA certificate required (client; mTLS router)."""
        if (self.cert is None) != (self.key is None):
            given, missing = ("certificate", "private key") if self.key is None else ("private key", "certificate")
            raise ZenohSecurityError(f"TLS {given} given without its {missing}; give both (--tls-cert and --tls-key)")
        if need_identity and self.cert is None:
            raise ZenohSecurityError("TLS certificate and private key required (--tls-cert/--tls-key): "
                                     "a router cannot listen on tls/... and an mTLS client cannot connect without them")
        if need_ca and self.ca is None:
            raise ZenohSecurityError("TLS CA certificate required (--tls-ca): it is what the other side's "
                                     "certificate is verified against")
        for role, path in (("CA certificate", self.ca), ("certificate", self.cert), ("private key", self.key)):
            if path is None:
                continue
            if not path.is_file():
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} does not exist; fix the path")
            try:
                head = path.read_bytes()[:4096]
            except OSError as exc:
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} is not readable: {exc.strerror}") from exc
            if b"-----BEGIN " not in head:
                raise ZenohSecurityError(f"TLS {role} file {str(path)!r} is not PEM (no '-----BEGIN' line)")
        return self


def client_tls_settings(files: TlsFiles, verify_name: bool = True) -> dict[str, Any]:
    """Zenoh config inserts for a client/peer that connects over ``tls/...``.

    The router's certificate is checked against ``files.ca`` (and its name/IP against the endpoint when
    ``verify_name``); with ``files.cert``/``files.key`` the client presents its certificate (mTLS),
    which is how the router's access control knows who it is (certificate common name)."""
    files.check(need_ca=True)
    tls: dict[str, Any] = {"root_ca_certificate": str(files.ca), "verify_name_on_connect": bool(verify_name)}
    if files.cert is not None:
        tls.update(connect_certificate=str(files.cert), connect_private_key=str(files.key), enable_mtls=True)
    return {TLS_KEY: tls}


def router_tls_settings(files: TlsFiles, mtls: bool | None = True) -> dict[str, Any]:
    """Zenoh config inserts for a router listening on ``tls/...``; ``mtls``: clients must present a
    certificate signed by ``files.ca`` (required for access control by certificate common name);
    ``None`` leaves ``enable_mtls`` as the config has it (never switches mTLS off behind one's back)."""
    files.check(need_identity=True, need_ca=bool(mtls))
    tls: dict[str, Any] = {"listen_certificate": str(files.cert), "listen_private_key": str(files.key)}
    if mtls is not None:
        tls["enable_mtls"] = bool(mtls)
    if files.ca is not None:
        tls["root_ca_certificate"] = str(files.ca)
    return {TLS_KEY: tls}


def apply_settings(config: Any, settings: Mapping[str, Any]) -> Any:
    """Insert ``settings`` (path → JSON value) into a ``zenoh.Config``; a dict under ``transport/link/tls``
    is merged key by key so that settings from a config file that are not overridden survive."""
    for path, value in settings.items():
        items = ({f"{path}/{k}": v for k, v in value.items()} if path == TLS_KEY and isinstance(value, dict)
                 else {path: value})
        for key, item in items.items():
            try:
                config.insert_json5(key, json.dumps(item))
            except Exception as exc:  # zenoh raises ZError on schema violations
                raise ZenohSecurityError(f"zenoh setting {key_name(key)}={item!r} rejected: {exc}") from exc
    return config


def config_endpoints(config: Any, which: str) -> list[str]:
    """``listen`` or ``connect`` endpoints of a ``zenoh.Config`` for its mode (mode-dependent values
    ``{router: [...], peer: [...], client: [...]}`` resolved with the config's ``mode``, peer by default)."""
    try:
        value = json.loads(config.get_json(f"{which}/endpoints"))
    except Exception:
        return []
    if isinstance(value, dict):
        try:
            mode = json.loads(config.get_json("mode")) or "peer"
        except Exception:
            mode = "peer"
        value = value.get(mode)
    return list(value or [])


def tls_settings_of(config: Any) -> dict[str, Any]:
    """The ``transport/link/tls`` section of a ``zenoh.Config`` (unset keys omitted)."""
    try:
        section = json.loads(config.get_json(TLS_KEY))
    except Exception:
        return {}
    return {k: v for k, v in (section or {}).items() if v is not None}


def check_no_downgrade(endpoints: list[str], tls: Mapping[str, Any], role: str) -> None:
    """Refuse plain-text endpoints when TLS material is configured, and ``tls/...`` endpoints that lack it.

    ``role``: "listen" (a router needs ``listen_certificate``/``listen_private_key``) or "connect"
    (a client needs ``root_ca_certificate`` to authenticate the router)."""
    needed = ("listen_certificate", "listen_private_key") if role == "listen" else ("root_ca_certificate",)
    has_tls = any(tls.get(k) for k in needed)
    secure = [e for e in endpoints if e.split("/", 1)[0] in SECURE_PROTOCOLS]
    plain = [e for e in endpoints if e not in secure]
    if has_tls and plain:
        raise ZenohSecurityError(f"TLS is configured but {role} endpoint(s) {', '.join(plain)} are plain text; "
                                 f"refusing to downgrade: use tls/HOST:PORT")
    missing = [k for k in needed if not tls.get(k)]
    if secure and missing:
        raise ZenohSecurityError(f"{role} endpoint(s) {', '.join(secure)} need TLS setting(s) "
                                 f"{', '.join(TLS_KEY + '/' + k for k in missing)}; give --tls-* files or set them "
                                 f"in the config")
    for key in needed + ("root_ca_certificate",):
        path = tls.get(key)
        if path and not Path(path).is_file():
            raise ZenohSecurityError(f"{TLS_KEY}/{key} file {path!r} does not exist; fix the path")
