"""Users, roles, access and OPC UA security in the gateway file; the mappings' roles checked against them."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from gateway.auth.passwords import hash_password
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import load
from gateway.errors import ConfigError
from gateway.sinks.opcua.config import OpcUaServerConfig

HASH = hash_password("x", n=2**4)


def user(name: str, role: str) -> dict[str, str]:
    return {"name": name, "password_hash": HASH, "role": role}


def error(settings: dict) -> str:
    with pytest.raises(ValidationError) as info:
        GatewayConfig.model_validate(settings)
    return str(info.value)


def test_defaults_access_control_follows_the_users() -> None:
    plain = GatewayConfig()
    assert plain.roles == ["viewer", "operator", "engineer", "admin"]
    assert not plain.access.is_enabled(plain.users)
    with_users = GatewayConfig.model_validate({"users": [user("olga", "operator")]})
    assert with_users.access.is_enabled(with_users.users)
    forced_off = GatewayConfig.model_validate(
        {"users": [user("olga", "operator")], "access": {"enabled": False}}
    )
    assert not forced_off.access.is_enabled(forced_off.users)


def test_users_need_a_known_role_a_unique_name_and_a_real_hash() -> None:
    assert "'boss' is not a role; the roles are viewer, operator, engineer, admin" in error(
        {"users": [user("olga", "boss")]}
    )
    assert "user 'olga' is listed twice" in error({"users": [user("olga", "viewer"), user("olga", "admin")]})
    assert "expected scrypt$N$r$p$salt$key" in error(
        {"users": [{"name": "olga", "password_hash": "olga", "role": "admin"}]}
    )
    assert "use access.anonymous" in error({"users": [user("anonymous", "viewer")]})


def test_roles_are_extendable_and_checked() -> None:
    config = GatewayConfig.model_validate(
        {
            "roles": ["viewer", "operator", "shift-lead", "engineer", "admin"],
            "users": [user("sam", "shift-lead")],
        }
    )
    assert config.users[0].role == "shift-lead"
    assert "listed twice" in error({"roles": ["viewer", "viewer"]})
    assert "lower-case letters" in error({"roles": ["Viewer"]})
    assert "access.default_write_role: 'operator' is not a role" in error({"roles": ["guest", "boss"]})


def test_access_roles_must_exist_and_someone_must_be_able_to_log_in() -> None:
    assert "access.mqtt_writer_role: 'writer' is not a role" in error(
        {"access": {"mqtt_writer_role": "writer"}}
    )
    assert "access.anonymous: 'nobody' is not a role" in error({"access": {"anonymous": "nobody"}})
    assert "nobody could log in" in error({"access": {"enabled": True, "anonymous": "refuse"}})
    assert "nobody could log in" in error({"access": {"anonymous": "refuse"}})
    GatewayConfig.model_validate({"access": {"anonymous": "refuse"}, "users": [user("olga", "viewer")]})


def test_opcua_security_names_and_profiles() -> None:
    assert OpcUaServerConfig().endpoints[0] == "None" and len(OpcUaServerConfig().endpoints) == 7
    assert "None" not in OpcUaServerConfig(profile="secure").endpoints
    assert OpcUaServerConfig(profile="open").endpoints == ("None",)
    explicit = OpcUaServerConfig(security=["Basic256Sha256_SignAndEncrypt"])
    assert explicit.endpoints == ("Basic256Sha256_SignAndEncrypt",)
    with pytest.raises(ValidationError, match="Basic256Sha256_SignAndEncrypt"):
        OpcUaServerConfig(security=["Basic256Sha256"])  # the mode is part of the name
    with pytest.raises(ValidationError, match=r"either opcua\.profile or opcua\.security"):
        OpcUaServerConfig(security=["None"], profile="secure")
    with pytest.raises(ValidationError, match="listed twice"):
        OpcUaServerConfig(security=["None", "None"])


MAPPING = """
machine: m1
driver: {{endpoint: "opc.tcp://127.0.0.1:4841"}}
variables:
  - {{path: Feed/Override, source: "ns=2;s=f", type: UInt16, access: readwrite, role: {role}}}
"""


def test_mapping_roles_are_checked_against_the_gateway_files_roles(tmp_path: Path) -> None:
    (tmp_path / "gateway.yaml").write_text(
        "machines: [m1.yaml]\nroles: [viewer, operator, shift-lead, engineer, admin]\n"
    )
    (tmp_path / "m1.yaml").write_text(MAPPING.format(role="shift-lead"))
    config = load([tmp_path / "gateway.yaml"])
    assert config.machines[0].variables[0].role == "shift-lead"
    (tmp_path / "m1.yaml").write_text(MAPPING.format(role="foreman"))
    with pytest.raises(ConfigError) as info:
        load([tmp_path / "gateway.yaml"])
    [issue] = info.value.issues
    assert (issue.file, issue.line, issue.key) == (str(tmp_path / "m1.yaml"), 5, "variables[0].role")
    assert (
        "'foreman' is not a role; the roles are viewer, operator, shift-lead, engineer, admin"
        in issue.message
    )
