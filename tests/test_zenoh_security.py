"""Zenoh security on loopback: mutual TLS, the shipped router ACL, the router tool's TLS handling, the
maintenance gate and acknowledgements through the ACL.

Certificates are made by the tests (tests/certs.py): a fleet CA issuing the router's certificate
(127.0.0.1/localhost) and client certificates with CNs agent-r1, viewer, operator, intruder; a second
"rogue" CA issuing a certificate with CN operator. Multicast scouting is off everywhere.

"Not delivered" is shown without waiting for a timeout. First the receiver's subscription is shown to
be in place at the router (warm-up samples from an allowed sender arrive). After the forbidden put, the sender makes a
query that the router answers (a final reply, also when access control drops the query): the router
handles a link's messages in order, so by then it has dropped or forwarded the put. Then an allowed
marker is sent to the same receiver and awaited: Zenoh delivers in order per link and priority, so a
forbidden sample that the router had forwarded would arrive before the marker. The same procedure with
an allowed identity delivers (positive control in the same parametrised test).
"""

from __future__ import annotations

import json
import logging
import re
import signal
import subprocess
import sys
import threading
from contextlib import ExitStack
from pathlib import Path

import pytest
import zenoh
from test_agent_pipeline import feed, small_config

from edge_monitor.app import Outputs, build_app
from edge_monitor.sinks.acknowledge import AcknowledgeConfig
from edge_monitor.sinks.loopback import free_loopback_port
from edge_monitor.sinks.maintenance import MaintenanceGate, describe_source
from edge_monitor.sinks.zenoh_publisher import SymptomPublisher, SymptomSubscriber
from edge_monitor.sinks.zenoh_security import (
    TlsFiles,
    ZenohSecurityError,
    apply_settings,
    check_no_downgrade,
    client_tls_settings,
    config_endpoints,
    router_tls_settings,
    tls_settings_of,
)
from edge_monitor.sinks.zenoh_session import ZenohOptions

from certs import CertFiles, CertificateAuthority
from synthetic_frames import make_frames
from waiting import wait_until

REPO = Path(__file__).resolve().parents[1]
ZENOH_DEFAULTS = REPO / "edge_monitor" / "defaults" / "zenoh"
WARM_UP = "warm-up"
WAIT_S = 20.0    # generous bound for deliveries on a loaded machine; never a speed assertion
IDENTITIES = ("agent-r1", "viewer", "operator", "intruder")
CLIENT_FILE = {"agent-r1": "agent_client.json5", "viewer": "viewer_client.json5",
               "operator": "operator_client.json5", "intruder": "viewer_client.json5"}

pytestmark = pytest.mark.timeout(120)


# -- fixtures ------------------------------------------------------------------------------------------


class Pki:
    """Fleet CA with router + client certificates, and a rogue CA with a look-alike operator."""

    def __init__(self, directory: Path) -> None:
        self.fleet = CertificateAuthority(directory, "fleet")
        self.router = self.fleet.issue("router", server=True)
        self.clients: dict[str, CertFiles] = {name: self.fleet.issue(name) for name in IDENTITIES}
        self.rogue = CertificateAuthority(directory, "rogue")
        self.rogue_operator = self.rogue.issue("operator")


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Pki:
    return Pki(tmp_path_factory.mktemp("pki"))


def client_config(pki: Pki, endpoint: str, identity: str | None, ca: Path | None = None,
                  cert: CertFiles | None = None) -> zenoh.Config:
    """The shipped client config of ``identity``'s role with this test's files and endpoint."""
    config = zenoh.Config.from_file(str(ZENOH_DEFAULTS / CLIENT_FILE.get(identity or "viewer")))
    files = cert or (pki.clients[identity] if identity else None)
    tls = client_tls_settings(TlsFiles(ca or pki.fleet.cert, files.cert if files else None,
                                       files.key if files else None))
    if files is None:   # the shipped file names a certificate: drop it for the "no certificate" client
        tls["transport/link/tls"].update(connect_certificate=None, connect_private_key=None, enable_mtls=False)
    return apply_settings(config, {**tls, "connect/endpoints": [endpoint]})


class Router:
    """The shipped ACL router config, run in this process (its transports are the delivery barrier)."""

    def __init__(self, pki: Pki) -> None:
        self.endpoint = f"tls/127.0.0.1:{free_loopback_port()}"
        config = zenoh.Config.from_file(str(ZENOH_DEFAULTS / "router_acl.json5"))
        files = TlsFiles(pki.fleet.cert, pki.router.cert, pki.router.key)   # enable_mtls stays the file's
        apply_settings(config, {**router_tls_settings(files, mtls=None),
                                "listen/endpoints": [self.endpoint]})
        self.session = zenoh.open(config)

    def connected(self, zid: str) -> bool:
        return any(str(t.zid) == zid for t in self.session.info.transports())


@pytest.fixture(scope="module")
def router(pki):
    router = Router(pki)
    yield router
    router.session.close()


@pytest.fixture(scope="module")
def sessions(pki, router):
    """One long-lived session per fleet identity through the ACL router, and a second one ("NAME#2") of
    the agent and of a viewer (a session delivers its own puts to itself without the router)."""
    names = IDENTITIES + ("agent-r1#2", "viewer#2")
    opened = {name: zenoh.open(client_config(pki, router.endpoint, name.split("#")[0])) for name in names}
    yield opened
    for session in opened.values():
        session.close()


def through_router(session: zenoh.Session) -> None:
    """Return once the router has handled everything ``session`` sent before (a query round trip)."""
    assert list(session.get("edge/probe/none", timeout=WAIT_S)) == []


class Inbox:
    """Samples received by one subscriber: (key, payload) in arrival order."""

    def __init__(self, session: zenoh.Session, key_expr: str, gate: MaintenanceGate | None = None) -> None:
        self.items: list[tuple[str, str]] = []
        self._lock = threading.Lock()
        self.gate_callback = gate.callback(self._declared) if gate else None
        self.declared: list[int] = []
        self.subscriber = session.declare_subscriber(key_expr, self._on_sample)

    def _declared(self, joint: int) -> None:
        self.declared.append(joint)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_string()
        with self._lock:
            self.items.append((str(sample.key_expr), payload))
        if self.gate_callback and payload != WARM_UP:
            self.gate_callback(sample)

    def warm_up(self, sender: zenoh.Session, key: str) -> None:
        """Put ``WARM_UP`` from an allowed sender until one arrives: the route exists at the router."""
        def arrived() -> bool:
            sender.put(key, WARM_UP)
            return WARM_UP in self.payloads()

        assert wait_until(arrived, WAIT_S, poll_s=0.1), f"no route from the allowed sender on {key}"

    def payloads(self) -> list[str]:
        with self._lock:
            return [payload for _, payload in self.items]

    def close(self) -> None:
        self.subscriber.undeclare()


# -- TLS handshake -------------------------------------------------------------------------------------


def test_fleet_certificates_connect_over_tls(pki, router, sessions):
    """Every fleet identity (even one the ACL does not know) completes the mTLS handshake."""
    for name, session in sessions.items():
        assert wait_until(lambda: router.connected(str(session.info.zid())), WAIT_S), name
        assert session.info.routers_zid() == [router.session.info.zid()]
    cns = {link.auth_identifier for link in router.session.info.links()}
    assert set(IDENTITIES) <= cns          # the router sees each client's certificate CN


@pytest.mark.parametrize("case", ["no certificate", "certificate of another CA", "router not trusted"])
def test_handshake_refused_without_a_fleet_certificate(pki, router, case):
    if case == "no certificate":
        config = client_config(pki, router.endpoint, None)
    elif case == "certificate of another CA":
        config = client_config(pki, router.endpoint, "operator", cert=pki.rogue_operator)
    else:   # the client verifies the router against the rogue CA: the fleet router is not trusted
        config = client_config(pki, router.endpoint, "operator", ca=pki.rogue.cert)
    apply_settings(config, {"scouting/timeout": 2000})
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(config).close()


# -- access control --------------------------------------------------------------------------------


@pytest.mark.parametrize("sender, key, delivered", [
    ("operator", "edge/r1/1/maintenance", True),       # positive control of the procedure
    ("viewer", "edge/r1/1/maintenance", False),
    ("intruder", "edge/r1/1/maintenance", False),
    ("agent-r1#2", "edge/r1/1/maintenance", False),   # an agent never declares maintenance
])
def test_only_an_operator_declares_maintenance(pki, router, sessions, sender, key, delivered):
    inbox = Inbox(sessions["agent-r1"], "edge/r1/*/maintenance")
    try:
        inbox.warm_up(sessions["operator"], "edge/r1/2/maintenance")
        payload = f"from {sender} ({key})"
        sessions[sender].put(key, payload)
        through_router(sessions[sender])
        sessions["operator"].put("edge/r1/2/maintenance", "marker")
        assert wait_until(lambda: "marker" in inbox.payloads(), WAIT_S)
        assert (payload in inbox.payloads()) is delivered
    finally:
        inbox.close()


@pytest.mark.parametrize("sender, key, delivered", [
    ("agent-r1", "edge/r1/1/symptom", True),           # positive control: the agent's own key space
    ("viewer", "edge/r1/1/symptom", False),
    ("viewer", "edge/r1/agent/health", False),
    ("operator", "edge/r1/1/symptom", False),
    ("intruder", "edge/r1/1/symptom", False),
    ("agent-r1", "edge/r2/1/symptom", False),          # agent-r1 cannot speak for robot r2
])
def test_only_the_robots_agent_publishes_its_records(pki, router, sessions, sender, key, delivered):
    inbox = Inbox(sessions["viewer#2"], "edge/**")
    try:
        inbox.warm_up(sessions["agent-r1"], "edge/r1/9/symptom")
        payload = json.dumps({"forged_by": sender, "key": key})
        sessions[sender].put(key, payload)
        through_router(sessions[sender])
        sessions["agent-r1"].put("edge/r1/9/symptom", "marker")
        assert wait_until(lambda: "marker" in inbox.payloads(), WAIT_S)
        assert (payload in inbox.payloads()) is delivered
    finally:
        inbox.close()


def test_agent_outputs_reach_a_viewer_and_state_is_queryable(sessions):
    """The real publisher/subscriber pair (advanced pub/sub, liveliness, state queryable) under the ACL."""
    state = {"joint": 3, "models": "learned"}
    with SymptomPublisher(sessions["agent-r1"], "r1", joints=[3], state_provider=lambda j: state) as publisher, \
            SymptomSubscriber(sessions["viewer"]) as subscriber:
        def received(s: SymptomSubscriber) -> bool:
            return any(r.get("cycle") == 41 for r in s.records("symptom"))

        assert wait_until(lambda: publisher.publish_symptom({"joint": 3, "cycle": 41}) and received(subscriber),
                          WAIT_S)
        assert subscriber.wait_for(lambda s: "r1" in s.agents, WAIT_S)
        replies = [r.ok for r in sessions["viewer"].get("edge/r1/*/state", timeout=WAIT_S) if r.ok]
        assert [(str(r.key_expr), json.loads(r.payload.to_string())) for r in replies] == [("edge/r1/3/state", state)]
        intruder = [r for r in sessions["intruder"].get("edge/r1/*/state", timeout=5.0)]
        assert intruder == []


def test_intruder_subscription_receives_nothing(pki, router, sessions):
    inbox = Inbox(sessions["intruder"], "edge/**")
    control = Inbox(sessions["viewer"], "edge/**")
    try:
        through_router(sessions["intruder"])      # the router has handled the intruder's subscription
        control.warm_up(sessions["agent-r1"], "edge/r1/9/symptom")
        sessions["agent-r1"].put("edge/r1/9/symptom", "marker")
        assert wait_until(lambda: "marker" in control.payloads(), WAIT_S)   # routed to every subscriber
        through_router(sessions["intruder"])      # its final reply comes after the marker, if routed there
        assert inbox.payloads() == []
    finally:
        inbox.close()
        control.close()


def test_gate_on_the_agent_refuses_what_the_acl_lets_through(pki, router, sessions, caplog):
    """An operator's wildcard put passes the ACL (edge/*/1/maintenance is inside edge/*/*/maintenance)
    and reaches the agent; the agent's gate refuses it and accepts the exact key once per window."""
    gate = MaintenanceGate("r1", allow=True, max_per_joint=1, window_s=3600.0)
    inbox = Inbox(sessions["agent-r1"], gate.key_expr, gate=gate)
    try:
        inbox.warm_up(sessions["operator"], "edge/r1/1/maintenance")   # not gated (test harness)
        with caplog.at_level(logging.WARNING, logger="edge_monitor.sinks.maintenance"):
            for key, payload in (("edge/*/1/maintenance", "wildcard"), ("edge/r1/1/maintenance", "first"),
                                 ("edge/r1/1/maintenance", "second")):
                sessions["operator"].put(key, payload, attachment="operator=alice")
            assert wait_until(lambda: {"wildcard", "first", "second"} <= set(inbox.payloads()), WAIT_S)
        assert inbox.declared == [1]
        assert gate.stats() == {"maintenance_accepted": 1, "maintenance_refused_disabled": 0,
                                "maintenance_refused_bad_key": 1, "maintenance_refused_unknown_joint": 0,
                                "maintenance_refused_rate_limited": 1}
        accepted = [r.getMessage() for r in caplog.records if "ACCEPTED" in r.getMessage()]
        assert len(accepted) == 1 and "payload='first'" in accepted[0] and "operator=alice" in accepted[0]
    finally:
        inbox.close()


def acknowledge_cli(pki: Pki, router: Router, identity: str, timeout_s: float) -> subprocess.CompletedProcess:
    """`edge-monitor acknowledge` of joint 0 of r1 as ``identity``, through the ACL router over mTLS."""
    files = pki.clients[identity]
    return subprocess.run(
        [sys.executable, "-m", "edge_monitor.cli", "acknowledge", "--robot", "r1", "--joint", "0", "--by", identity,
         "--zenoh-mode", "client", "--zenoh-connect", router.endpoint, "--tls-ca", str(pki.fleet.cert),
         "--tls-cert", str(files.cert), "--tls-key", str(files.key), "--timeout", str(timeout_s)],
        capture_output=True, text=True, timeout=timeout_s + 60)


def test_only_an_operator_acknowledges_an_alarm_through_the_acl(pki, router, sessions, tmp_path):
    """An agent (its own session, mTLS as agent-r1) with a latched wear alarm and remote acknowledgements on:
    a viewer's or another agent's put never reaches it (the ACL), a viewer's `edge-monitor acknowledge`
    gets no acknowledgement (exit 1), an operator's acknowledges (exit 0)."""
    agent_files = pki.clients["agent-r1"]
    agent_zenoh = tmp_path / "agent.json5"
    agent_zenoh.write_text(json.dumps({
        "mode": "client", "connect": {"endpoints": [router.endpoint]}, "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": {
            "root_ca_certificate": str(pki.fleet.cert), "connect_certificate": str(agent_files.cert),
            "connect_private_key": str(agent_files.key), "enable_mtls": True, "verify_name_on_connect": True}}}}))
    config = small_config(robot="r1", acknowledge=AcknowledgeConfig(remote=True))
    with ExitStack() as stack:
        app = build_app(config, Outputs(zenoh=ZenohOptions(mode=None, config_file=str(agent_zenoh)), maintenance=True),
                        stack)
        feed(app.agent, make_frames(14, joints=(0,), wear=lambda j, c: 0.0 if c < 5 else 60.0, seed=9))
        wear = app.agent.joints[0].detectors.detectors["wear"]
        assert wear.alarmed
        gate = app.acknowledge_gate
        for sender in ("viewer", "agent-r1#2"):
            sessions[sender].put("edge/r1/0/acknowledge", b"{}")
            through_router(sessions[sender])
        sessions["operator"].put("edge/r1/0/acknowledge", b"marker")     # refused by the gate: a bad payload
        assert wait_until(lambda: gate.stats()["acknowledge_refused_bad_payload"] == 1, WAIT_S)
        assert gate.stats()["acknowledge_accepted"] == 0 and wear.alarmed      # the two puts never arrived
        viewer = acknowledge_cli(pki, router, "viewer", 5.0)
        assert viewer.returncode == 1 and "did not acknowledge" in viewer.stderr, viewer.stdout + viewer.stderr
        assert gate.stats()["acknowledge_accepted"] == 0 and wear.alarmed
        operator = acknowledge_cli(pki, router, "operator", WAIT_S)
        assert operator.returncode == 0, operator.stdout + operator.stderr
        assert re.search(r"\bwear\b.* alarms? acknowledged", operator.stdout) and "by operator" in operator.stdout
        assert gate.stats()["acknowledge_accepted"] == 1 and not wear.alarmed


def test_usrpwd_identities_are_the_alternative_to_client_certificates(pki, tmp_path):
    """TLS without client certificates + Zenoh user/password authentication: ACL subjects by username.
    A wrong password or no credentials cannot connect; only the operator's put reaches the agent."""
    users = tmp_path / "users.txt"
    users.write_text("agent-r1:pw-agent-r1\noperator:pw-operator\nviewer:pw-viewer\n")
    endpoint = f"tls/127.0.0.1:{free_loopback_port()}"
    maintenance = {"permission": "allow", "messages": ["put", "declare_subscriber"], "key_exprs": ["edge/r1/*/maintenance"]}
    config = zenoh.Config()
    apply_settings(config, {
        "mode": "router", "scouting/multicast/enabled": False, "listen/endpoints": [endpoint],
        **router_tls_settings(TlsFiles(None, pki.router.cert, pki.router.key), mtls=False),
        "transport/auth/usrpwd/dictionary_file": str(users),
        "access_control": {"enabled": True, "default_permission": "deny",
                           "rules": [{"id": "operator puts", "flows": ["ingress"], **maintenance},
                                     {"id": "agent listens", "flows": ["ingress", "egress"], **maintenance},
                                     {"id": "probe", "permission": "allow", "messages": ["query"],
                                      "key_exprs": ["edge/**"]}],
                           "subjects": [{"id": "operator", "usernames": ["operator"]},
                                        {"id": "agent", "usernames": ["agent-r1"]},
                                        {"id": "anyone"}],
                           "policies": [{"rules": ["operator puts"], "subjects": ["operator"]},
                                        {"rules": ["agent listens"], "subjects": ["agent"]},
                                        {"rules": ["probe"], "subjects": ["anyone"]}]}})
    router = zenoh.open(config)

    def client(user: str | None, password: str | None) -> zenoh.Config:
        config = zenoh.Config()
        apply_settings(config, {"mode": "client", "scouting/multicast/enabled": False, "scouting/timeout": 2000,
                                "connect/endpoints": [endpoint], **client_tls_settings(TlsFiles(pki.fleet.cert))})
        if user is not None:
            apply_settings(config, {"transport/auth/usrpwd/user": user, "transport/auth/usrpwd/password": password})
        return config

    opened: list[zenoh.Session] = []
    try:
        for user in ("agent-r1", "operator", "viewer"):
            opened.append(zenoh.open(client(user, f"pw-{user}")))
        agent, operator, viewer = opened
        for user, password in (("operator", "wrong"), (None, None)):
            with pytest.raises(zenoh.ZError, match="Unable to connect"):
                zenoh.open(client(user, password)).close()
        inbox = Inbox(agent, "edge/r1/*/maintenance")
        inbox.warm_up(operator, "edge/r1/2/maintenance")
        viewer.put("edge/r1/1/maintenance", "from viewer")
        through_router(viewer)
        operator.put("edge/r1/2/maintenance", "marker")
        assert wait_until(lambda: "marker" in inbox.payloads(), WAIT_S)
        assert "from viewer" not in inbox.payloads()
    finally:
        for session in opened:
            session.close()
        router.close()


# -- router tool ---------------------------------------------------------------------------------------


EDGE = str(Path(sys.executable).parent / "edge-monitor")


def _router(argv: list[str]) -> int:
    """``edge-monitor router ARGV`` in this process (what the installed command runs)."""
    from edge_monitor.cli import main
    return main(["router", *argv])


def test_router_tool_listens_on_tls_with_the_acl_config(pki):
    port = free_loopback_port()
    router = subprocess.Popen(
        [EDGE, "router", "--config", str(ZENOH_DEFAULTS / "router_acl.json5"),
         "--tls-ca", str(pki.fleet.cert), "--tls-cert", str(pki.router.cert), "--tls-key", str(pki.router.key),
         "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert router.stdout.readline().strip() == f"zenoh router listening on tls/127.0.0.1:{port}"
        security = router.stdout.readline()
        assert "mTLS" in security and "access control on (default deny" in security
        endpoint = f"tls/127.0.0.1:{port}"
        agent = zenoh.open(client_config(pki, endpoint, "agent-r1"))
        try:
            assert wait_until(lambda: len(agent.info.routers_zid()) == 1, WAIT_S)
        finally:
            agent.close()
        plain = zenoh.Config()
        apply_settings(plain, {"mode": "client", "scouting/multicast/enabled": False, "scouting/timeout": 2000,
                               "connect/endpoints": [f"tcp/127.0.0.1:{port}"]})
        with pytest.raises(zenoh.ZError):
            zenoh.open(plain).close()
    finally:
        router.send_signal(signal.SIGTERM)
        out, err = router.communicate(timeout=30)
    assert router.returncode == 0, err


def _write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


def test_router_tool_refuses_to_downgrade_tls_to_tcp(pki, tmp_path, capsys):
    tls = {"listen_certificate": str(pki.router.cert), "listen_private_key": str(pki.router.key)}
    config = _write(tmp_path / "tcp_with_tls.json5", json.dumps(
        {"listen": {"endpoints": ["tcp/127.0.0.1:7447"]}, "transport": {"link": {"tls": tls}}}))
    assert _router(["--config", config]) == 2
    assert "refusing to downgrade" in capsys.readouterr().err


def test_router_tool_upgrades_host_and_port_to_tls_when_tls_is_configured(pki, tmp_path):
    tls = {"listen_certificate": str(pki.router.cert), "listen_private_key": str(pki.router.key)}
    config = _write(tmp_path / "tls.json5", json.dumps({"transport": {"link": {"tls": tls}}}))
    from edge_monitor.sinks.zenoh_router import RouterOptions, router_config
    _, endpoints = router_config(RouterOptions(config=config, port=7999))
    assert endpoints == ["tls/127.0.0.1:7999"]


@pytest.mark.parametrize("args, message", [
    (["--tls-cert", "{cert}"], "--tls-cert and --tls-key are both needed"),
    (["--tls-cert", "{cert}", "--tls-key", "{missing}"], "does not exist"),
    (["--config", "{tls_without_files}"], "need TLS setting(s) transport/link/tls/listen_certificate"),
    (["--config", "{acl}"], "/etc/joint-wear-monitor/pki/router.pem' does not exist"),
])
def test_router_tool_refuses_tls_it_cannot_honour(pki, tmp_path, capsys, args, message):
    names = {"cert": str(pki.router.cert), "missing": str(tmp_path / "missing.key"),
             "tls_without_files": _write(tmp_path / "t.json5", '{listen: {endpoints: ["tls/127.0.0.1:7447"]}}'),
             "acl": str(ZENOH_DEFAULTS / "router_acl.json5")}
    assert _router([a.format(**names) for a in args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


# -- TLS settings helpers ----------------------------------------------------------------------------


def test_tls_files_are_checked_with_clear_messages(pki, tmp_path):
    not_pem = tmp_path / "key.der"
    not_pem.write_bytes(b"\x30\x82")
    cases = [(TlsFiles(tmp_path / "nope.pem"), "CA certificate file", "does not exist"),
             (TlsFiles(pki.fleet.cert, pki.router.cert, None), "certificate given without its private key", ""),
             (TlsFiles(pki.fleet.cert, pki.router.cert, not_pem), "is not PEM", "key.der")]
    for files, first, second in cases:
        with pytest.raises(ZenohSecurityError, match=first) as info:
            files.check()
        assert second in str(info.value)
    with pytest.raises(ZenohSecurityError, match="CA certificate required"):
        client_tls_settings(TlsFiles(None))
    with pytest.raises(ZenohSecurityError, match="certificate and private key required"):
        router_tls_settings(TlsFiles(pki.fleet.cert))


def test_client_settings_fill_the_shipped_config(pki):
    config = zenoh.Config.from_file(str(ZENOH_DEFAULTS / "agent_client.json5"))
    agent = pki.clients["agent-r1"]
    apply_settings(config, client_tls_settings(TlsFiles(pki.fleet.cert, agent.cert, agent.key)))
    assert tls_settings_of(config) == {
        "root_ca_certificate": str(pki.fleet.cert), "connect_certificate": str(agent.cert),
        "connect_private_key": str(agent.key), "enable_mtls": True, "verify_name_on_connect": True}
    assert config_endpoints(config, "connect") == ["tls/127.0.0.1:7447"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def test_no_downgrade_check():
    tls = {"listen_certificate": __file__, "listen_private_key": __file__}
    check_no_downgrade(["tls/127.0.0.1:1"], tls, "listen")
    check_no_downgrade(["tcp/127.0.0.1:1"], {}, "listen")              # plain on purpose: allowed
    with pytest.raises(ZenohSecurityError, match="refusing to downgrade"):
        check_no_downgrade(["tls/127.0.0.1:1", "tcp/127.0.0.1:2"], tls, "listen")
    with pytest.raises(ZenohSecurityError, match="refusing to downgrade"):
        check_no_downgrade(["tcp/127.0.0.1:1"], {"root_ca_certificate": __file__}, "connect")
    with pytest.raises(ZenohSecurityError, match="root_ca_certificate"):
        check_no_downgrade(["tls/127.0.0.1:1"], {}, "connect")


# -- maintenance gate (pure logic) -------------------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def make_gate(**kwargs) -> tuple[MaintenanceGate, Clock]:
    clock = Clock()
    return MaintenanceGate("r1", clock=clock, logger=logging.getLogger("test.gate"), **kwargs), clock


def test_gate_is_off_by_default_and_a_flood_is_counted_not_logged_line_by_line(caplog):
    gate, clock = make_gate(log_interval_s=60.0)
    with caplog.at_level(logging.WARNING, logger="test.gate"):
        decisions = [gate.decide("edge/r1/1/maintenance", b"reset") for _ in range(3000)]
        clock.t += 60.0
        gate.decide("edge/r1/1/maintenance", b"reset")
    assert not any(d.accepted for d in decisions) and {d.reason for d in decisions} == {"disabled"}
    assert gate.stats()["maintenance_refused_disabled"] == 3001
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "disabled" in lines[0]
    assert "2999 similar refusal(s) not logged" in lines[1]


def test_gate_rate_limit_per_joint_and_sliding_window():
    gate, clock = make_gate(allow=True, max_per_joint=2, window_s=600.0)
    key = "edge/r1/{}/maintenance".format
    assert [gate.decide(key(1)).accepted for _ in range(3)] == [True, True, False]
    assert gate.decide(key(2)).accepted                      # joints are limited separately
    clock.t += 599.0
    assert not gate.decide(key(1)).accepted                  # both acceptances still inside the window
    clock.t += 1.0
    assert [gate.decide(key(1)).accepted for _ in range(3)] == [True, True, False]
    assert gate.stats() == {"maintenance_accepted": 5, "maintenance_refused_disabled": 0,
                            "maintenance_refused_bad_key": 0, "maintenance_refused_unknown_joint": 0,
                            "maintenance_refused_rate_limited": 3}


def test_gate_refuses_joints_the_robot_cannot_have():
    """Joints 64 and 999 (beyond MAX_JOINTS): refused at the gate and counted, never accepted."""
    gate, _ = make_gate(allow=True, max_per_joint=1)
    assert [gate.decide(f"edge/r1/{j}/maintenance").reason for j in (64, 999)] == ["unknown_joint"] * 2
    assert gate.stats()["maintenance_refused_unknown_joint"] == 2 and gate.stats()["maintenance_accepted"] == 0


@pytest.mark.parametrize("key", ["edge/*/1/maintenance", "edge/**/maintenance", "edge/r1/*/maintenance",
                                 "edge/r2/1/maintenance", "edge/r1/01/maintenance", "edge/r1/x/maintenance",
                                 "edge/r1/1/maintenance/extra", "edge/r10/1/maintenance", "edge/r1/-1/maintenance"])
def test_gate_accepts_only_exact_keys_of_its_robot(key):
    gate, _ = make_gate(allow=True)
    decision = gate.decide(key, b"x")
    assert (decision.accepted, decision.joint, decision.reason) == (False, None, "bad_key")


def test_gate_logs_who_and_what_without_letting_the_payload_forge_lines(caplog):
    gate, _ = make_gate(allow=True, payload_chars=40)
    payload = "replaced\nWARNING forged log line" + "x" * 10_000
    with caplog.at_level(logging.WARNING, logger="test.gate"):
        gate.decide("edge/r1/4/maintenance", payload.encode(), source="zid=ab eid=3 sn=7", attachment=b"op=bob")
    (line,) = [r.getMessage() for r in caplog.records]
    assert "\n" not in line and "replaced\\nWARNING" in line and f"({len(payload)} chars)" in line
    assert "key='edge/r1/4/maintenance'" in line and "source=zid=ab eid=3 sn=7" in line and "op=bob" in line
    assert len(line) < 400


class FakeSample:
    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr, self.payload, self.attachment, self.source_info = key, payload, None, None


def test_gate_callback_declares_accepted_joints_and_never_raises(caplog):
    gate, clock = make_gate(allow=True, max_per_joint=1)
    declared: list[int] = []

    def declare(joint: int) -> None:
        if joint == 5:
            raise ValueError("joint 5: nothing learned yet")
        declared.append(joint)

    callback = gate.callback(declare)
    with caplog.at_level(logging.WARNING, logger="test.gate"):
        for key in ("edge/r1/3/maintenance", "edge/r1/3/maintenance", "edge/r1/5/maintenance", "edge/r2/3/maintenance",
                    "edge/r1/5/maintenance"):
            callback(FakeSample(key, b""))
    assert declared == [3]
    assert any("edge/r1/5/maintenance" in r.getMessage() and "nothing learned" in r.getMessage()
               for r in caplog.records if r.levelno == logging.WARNING)
    # a joint the agent does not monitor is refused after all: not accepted, its rate limit not used up
    assert gate.stats() == {"maintenance_accepted": 1, "maintenance_refused_disabled": 0,
                            "maintenance_refused_bad_key": 1, "maintenance_refused_unknown_joint": 2,
                            "maintenance_refused_rate_limited": 1}
    assert describe_source(FakeSample("k", b"")) == "unknown"


@pytest.mark.parametrize("kwargs, message", [({"robot": "r/1"}, "robot name"), ({"max_per_joint": 0}, "max_per_joint"),
                                             ({"window_s": float("nan")}, "window_s"),
                                             ({"log_interval_s": -1.0}, "log_interval_s")])
def test_gate_rejects_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MaintenanceGate(**{"robot": "r1", **kwargs})
