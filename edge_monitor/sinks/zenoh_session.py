"""Opening a Zenoh session with safe defaults: explicit endpoints, multicast scouting off, loopback only.

Zenoh's own defaults (peer mode, listening on every interface, multicast scouting on) would make an
edge agent visible to the whole plant network. Here nothing listens unless ``--zenoh-listen`` is given,
nothing is discovered by multicast, and peers/routers are reached only through ``--zenoh-connect``.
A Zenoh JSON5 config file (``--zenoh-config``) is taken as the user's explicit choice; if it turns
multicast scouting on, a warning says so.
"""

from __future__ import annotations

import json
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from edge_monitor.errors import key_name
from edge_monitor.sinks.loopback import MAX_PORT, is_port
from edge_monitor.sinks.zenoh_security import (
    TlsFiles,
    apply_settings,
    check_no_downgrade,
    client_tls_settings,
    config_endpoints,
    tls_settings_of,
)

log = logging.getLogger(__name__)

MODES = ("peer", "client", "router")
DEFAULT_ROUTER_PORT = 7447
_ENDPOINT_RE = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")
_PORT_RE = re.compile(r"^(?:tcp|udp|tls|quic|ws)/.*:(\d+)(?:[#?].*)?$")


class ZenohSetupError(ValueError):
    """Zenoh options that cannot work (bad mode, endpoint or config file): a usage error."""


class ZenohUnavailable(ZenohSetupError):
    """The session could not be opened with valid options (occupied port, unreachable router): a runtime
    failure."""


@dataclass
class ZenohOptions:
    """How to open the Zenoh session.

    ``mode``: "peer" | "client" | "router"; ``None`` keeps the mode of ``config_file`` (peer without one).
    ``listen`` / ``connect``: endpoints such as ``tcp/127.0.0.1:7447``.
    ``config_file``: a Zenoh JSON5 config; explicit ``listen``/``connect``/``mode`` override it.
    ``tls``: a :class:`~edge_monitor.sinks.zenoh_security.TlsFiles`: connect over ``tls/...`` checking the
    router against its CA, presenting its certificate/key when given (mTLS); plain endpoints are refused.
    """

    mode: str | None = "peer"
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    config_file: str | None = None
    tls: TlsFiles | None = None

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ZenohSetupError(f"zenoh mode {self.mode!r} is not one of {', '.join(MODES)}; fix --zenoh-mode")
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                if not _ENDPOINT_RE.match(endpoint):
                    raise ZenohSetupError(
                        f"zenoh {name} endpoint {endpoint!r} is not of the form PROTO/HOST:PORT; "
                        f"fix --zenoh-{name}, e.g. tcp/127.0.0.1:{DEFAULT_ROUTER_PORT}"
                    )
                port = _PORT_RE.search(endpoint)
                if port is not None and not is_port(int(port.group(1))):
                    raise ZenohSetupError(f"zenoh {name} endpoint {endpoint!r}: port {port.group(1)} is not "
                                          f"0 … {MAX_PORT}; fix --zenoh-{name}")
        if self.config_file is not None and not Path(self.config_file).is_file():
            what = "is not a file" if Path(self.config_file).exists() else "does not exist"
            raise ZenohSetupError(f"zenoh config file {self.config_file!r} {what}; fix --zenoh-config")
        if self.tls is not None:
            try:
                self.tls.check(need_ca=True)
            except ValueError as exc:
                raise ZenohSetupError(str(exc)) from None

    def to_config(self) -> zenoh.Config:
        """The ``zenoh.Config`` these options describe."""
        if self.config_file is not None:
            try:
                config = zenoh.Config.from_file(self.config_file)
            except Exception as exc:  # zenoh raises ZError for parse/validation failures
                raise ZenohSetupError(f"zenoh config file {self.config_file!r} is invalid: {exc}") from exc
            _warn_if_multicast(config, self.config_file)
        else:
            config = zenoh.Config()
            _insert(config, "scouting/multicast/enabled", False)
            _insert(config, "listen/endpoints", [])  # zenoh would listen on every interface otherwise
        if self.mode is not None:
            _insert(config, "mode", self.mode)
        if self.listen:
            _insert(config, "listen/endpoints", self.listen)
        if self.connect:
            _insert(config, "connect/endpoints", self.connect)
        if self.tls is not None:
            _client_tls(config, self.tls)
        return config

    def describe(self) -> str:
        """One line for logs and status output."""
        parts = [f"mode={self.mode or 'from config'}"]
        if self.listen:
            parts.append("listen=" + ",".join(self.listen))
        if self.connect:
            parts.append("connect=" + ",".join(self.connect))
        if self.config_file:
            parts.append(f"config={self.config_file}")
        if self.tls is not None:
            parts.append("tls" + ("+client certificate" if self.tls.cert is not None else ""))
        return " ".join(parts)


def _insert(config: zenoh.Config, key: str, value: Any) -> None:
    try:
        config.insert_json5(key, json.dumps(value))
    except Exception as exc:
        raise ZenohSetupError(f"zenoh setting {key_name(key)}={value!r} rejected: {exc}") from exc


def _client_tls(config: zenoh.Config, files: TlsFiles) -> None:
    """TLS client settings from ``files``; no plain-text connect endpoint may remain."""
    try:
        apply_settings(config, client_tls_settings(files))
        check_no_downgrade(config_endpoints(config, "connect"), tls_settings_of(config), "connect")
    except ValueError as exc:
        raise ZenohSetupError(str(exc)) from None


def _warn_if_multicast(config: zenoh.Config, path: str) -> None:
    try:
        enabled = json.loads(config.get_json("scouting/multicast/enabled"))
    except Exception:  # key absent in a partial config: zenoh's default (on) applies
        enabled = None
    if enabled is not False:
        log.warning("zenoh config %s leaves multicast scouting on (%s): this session announces itself "
                    "on the local network; set scouting.multicast.enabled=false to keep it private",
                    path, "explicitly" if enabled else "zenoh default")


def open_session(options: ZenohOptions | None = None) -> zenoh.Session:
    """Open a Zenoh session; raise :class:`ZenohSetupError` with the cause and the fix on failure."""
    options = options or ZenohOptions()
    config = options.to_config()
    try:
        session = zenoh.open(config)
    except Exception as exc:
        raise ZenohUnavailable(_explain_open_failure(options, exc)) from exc
    log.info("zenoh session open (%s)", options.describe())
    return session


def _explain_open_failure(options: ZenohOptions, exc: Exception) -> str:
    text = str(exc)
    if "Address already in use" in text:
        return (f"cannot listen on {', '.join(options.listen)}: the port is in use by another program; "
                f"choose another port with --zenoh-listen ({text.split(' at ')[0]})")
    if "Unable to connect" in text:
        return (f"no Zenoh router reachable at {', '.join(options.connect) or '(none given)'}: start one "
                f"(edge-monitor router --port PORT) or fix --zenoh-connect")
    return f"cannot open the Zenoh session ({options.describe()}): {text}"
