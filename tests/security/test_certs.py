"""``lessmap certs`` and the deploy/ configs: what is written, and that it is what Zenoh reads."""

from __future__ import annotations

import json
import re
import stat
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import NameOID

from lessmap.cli.app import main
from lessmap.errors import ConfigError
from lessmap.security.certs import make_site, templates
from lessmap.security.siteconfig import (
    access_rules,
    render,
    usrpwd_client_config,
    usrpwd_router_config,
)
from lessmap_client.session import open_session
from lessmap_schemas import keys
from tests.conftest import free_port, wait_until

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def common_name(path: Path) -> str:
    cert = x509.load_pem_x509_certificate(path.read_bytes())
    value = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
    assert isinstance(value, str)
    return value


def test_a_site_has_one_identity_per_role_and_fleet(tmp_path: Path) -> None:
    site = make_site(tmp_path / "site", ["north", "south"], ["svc-a", "svc-b"])
    folder = site.folder
    for name in ["router", "svc-a", "svc-b", "robot.north", "app.north", "robot.south"]:
        assert common_name(folder / f"{name}.pem") == name
    for key in folder.glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key
    router = x509.load_pem_x509_certificate((folder / "router.pem").read_bytes())
    san = router.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in san.get_values_for_type(x509.DNSName)
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
    ca = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    router.verify_directly_issued_by(ca)
    assert set(site.services) == {"svc-a", "svc-b"}
    assert set(site.robots) == set(site.apps) == {"north", "south"}
    # Every config is one Zenoh reads, naming files that exist in the site folder.
    for config in [site.router, *site.services.values(), *site.robots.values()]:
        zenoh.Config.from_file(str(config))
        for line in config.read_text().splitlines():
            if line.strip().startswith(("root_ca", "listen_", "connect_private", "connect_cert")):
                assert Path(line.split('"')[1]).is_file(), line


def test_an_existing_ca_is_kept_unless_forced(tmp_path: Path) -> None:
    make_site(tmp_path, ["f"])
    before = (tmp_path / "ca.pem").read_bytes()
    with pytest.raises(ConfigError, match="--force"):
        make_site(tmp_path, ["f"])
    assert (tmp_path / "ca.pem").read_bytes() == before
    old_robot = (tmp_path / "robot.f.pem").read_bytes()
    make_site(tmp_path, ["f", "g"], reuse_ca=True)  # re-issue (and add a fleet), same CA
    assert (tmp_path / "ca.pem").read_bytes() == before
    assert (tmp_path / "robot.f.pem").read_bytes() != old_robot
    ca = x509.load_pem_x509_certificate(before)
    for name in ["robot.f.pem", "robot.g.pem", "router.pem"]:
        x509.load_pem_x509_certificate((tmp_path / name).read_bytes()).verify_directly_issued_by(ca)
    make_site(tmp_path, ["f"], force=True)
    assert (tmp_path / "ca.pem").read_bytes() != before
    assert stat.S_IMODE((tmp_path / "ca.key").stat().st_mode) == 0o600
    with pytest.raises(ConfigError, match="no CA"):
        make_site(tmp_path / "empty", ["f"], reuse_ca=True)


def test_the_command_writes_a_site_and_refuses_to_overwrite_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site"
    assert main(["certs", "--out", str(out), "--fleet", "lab", "--fleet", "yard"]) == 0
    written = json.loads(capsys.readouterr().out)
    assert set(written["robots"]) == {"lab", "yard"}
    assert Path(written["router"]).is_file()
    assert main(["certs", "--out", str(out), "--fleet", "lab"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("lessmap certs: ")
    assert "--force" in err[0]
    assert main(["certs", "--out", str(tmp_path / "x"), "--fleet", "bad/name"]) == 1
    assert "fleet" in capsys.readouterr().err


def test_a_missing_cryptography_names_the_extra(tmp_path: Path) -> None:
    code = (
        "import sys; sys.modules['cryptography'] = None; from lessmap.cli.app import main; "
        f"sys.exit(main(['certs', '--out', {str(tmp_path)!r}, '--fleet', 'f']))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    # (the blocked submodule is named here; a real missing install names `cryptography`)
    assert re.fullmatch(
        r"lessmap certs: this needs cryptography[.\w]*, from lessmap's optional extra "
        r"security: pip install '\.\[security\]' in the repository \(README, Install\)",
        lines[0],
    ), lines
    assert not (tmp_path / "ca.key").exists()


@pytest.mark.parametrize("name", sorted(templates()))
def test_deploy_templates_are_what_the_command_renders(name: str) -> None:
    # deploy/ is rendered from the same rules as every site: regenerate it with
    # `lessmap certs --templates --out deploy` after changing them.
    path = DEPLOY / name
    assert path.read_text(encoding="utf-8") == templates()[name]
    zenoh.Config.from_file(str(path))


@pytest.mark.parametrize("name", ["zenoh-router.json5", "zenoh-client.json5"])
def test_plain_deploy_configs_bind_loopback_without_scouting(name: str) -> None:
    text = (DEPLOY / name).read_text(encoding="utf-8")
    for line in text.splitlines():
        code = line.split("//")[0]  # comments may say how to open it
        assert "0.0.0.0" not in code, line
        assert "[::]" not in code, line
    conf = zenoh.Config.from_file(str(DEPLOY / name))
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


def test_user_names_and_passwords_with_access_control(tmp_path: Path) -> None:
    endpoint = f"tls/127.0.0.1:{free_port()}"
    site = make_site(tmp_path, ["f", "g"], endpoint=endpoint)
    folder = str(site.folder)
    credentials = site.folder / "credentials.txt"
    credentials.write_text("robot.f:secret-r\nservice:secret-s\n")
    credentials.chmod(0o600)

    def config(name: str, conf: dict[str, object]) -> str:
        path = site.folder / name
        path.write_text(render(conf, "test"))
        return str(path)

    def client(identity: str, password: str) -> str:
        conf = usrpwd_client_config(folder, identity, endpoint)
        conf["transport"]["auth"]["usrpwd"]["password"] = password
        return config(f"{identity}-{password}.json5", conf)

    router_conf = zenoh.Config.from_file(
        config("router.json5", usrpwd_router_config(folder, ["f", "g"], ["service"], endpoint))
    )
    with zenoh.open(router_conf):
        service = open_session([endpoint], config_file=client("service", "secret-s"))
        robot = open_session([endpoint], config_file=client("robot.f", "secret-r"))
        try:
            got: list[str] = []
            sub = service.declare_subscriber(
                keys.frames("*", "*"), lambda sample: got.append(str(sample.key_expr))
            )
            deadline = time.monotonic() + 10
            while not got and time.monotonic() < deadline:
                robot.put(keys.frames("g", "r"), b"not mine")  # refused: robot.f is not g
                robot.put(keys.frames("f", "r"), b"mine")
                time.sleep(0.1)
            wait_until(lambda: bool(got), 1.0, "robot f's frames at the service")
            time.sleep(0.5)
            sub.undeclare()
            assert set(got) == {keys.frames("f", "r")}
        finally:
            robot.close()
            service.close()
        with pytest.raises(ConnectionError):
            open_session([endpoint], config_file=client("robot.f", "wrong"), timeout_s=2.0)


def rules_of(acl: dict[str, Any], subject_id: str) -> dict[str, dict[str, Any]]:
    """The rules of the policy of ``subject_id``, by rule id."""
    (policy,) = [p for p in acl["policies"] if p["subjects"] == [subject_id]]
    by_id = {rule["id"]: rule for rule in acl["rules"]}
    return {rule_id: by_id[rule_id] for rule_id in policy["rules"]}


def test_per_robot_identities_are_held_to_their_own_keys() -> None:
    acl = access_rules(["f", "g"], ["service"], robots={"f": ["r1", "r2"]})
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert subjects["robot-f/r1"] == ["robot.f/r1"]
    assert subjects["robot-f/r2"] == ["robot.f/r2"]
    assert "robot-f" not in subjects  # no fleet-wide robot identity for f
    assert subjects["robot-g"] == ["robot.g"]
    p = keys.KEY_PREFIX
    r1 = rules_of(acl, "robot-f/r1")
    assert {rule_id: (rule["flows"], rule["key_exprs"]) for rule_id, rule in r1.items()} == {
        "robot-f/r1-put": (["ingress"], [f"{p}/f/r1/frames/*"]),
        "robot-f/r1-cache": (["ingress"], [f"{p}/f/r1/frames/*/@adv/**"]),
        "robot-f/r1-read": (
            ["ingress"],
            [f"{p}/f/r1/errors", f"{p}/f/r1/state", f"{p}/@/instances/*"],
        ),
        "robot-f/r1-out": (
            ["egress"],
            [
                f"{p}/f/r1/frames/*",
                f"{p}/f/r1/frames/*/@adv/**",
                f"{p}/f/r1/errors",
                f"{p}/f/r1/state",
                f"{p}/@/instances/*",
            ],
        ),
        # Declarations of the service's wildcard subscribers and queryables, no data.
        "see-service": (
            ["egress"],
            [f"{p}/*/*/frames/*", f"{p}/*/*/state", f"{p}/*/*/areas", f"{p}/*/*/submaps/*"],
        ),
    }
    assert r1["robot-f/r1-put"]["messages"] == ["put"]
    # Nothing r1 may send touches r2's keys; r1's own frames key is covered.
    r2_keys = [
        keys.frames("f", "r2"),
        f"{keys.frames('f', 'r2')}/@adv/pub/z/1",
        keys.state("f", "r2"),
    ]
    for rule in r1.values():
        if "ingress" in rule["flows"]:
            for expr in rule["key_exprs"]:
                assert not any(zenoh.KeyExpr(expr).intersects(k) for k in r2_keys), expr
    assert zenoh.KeyExpr(f"{p}/f/r1/frames/*").includes(keys.frames("f", "r1"))
    # The other fleet's rules, and those of apps and viewers, are those of a fleet-wide site.
    fleet_wide = access_rules(["f", "g"], ["service"])
    for subject_id in ["robot-g", "app-f", "viewer-f", "app-g", "viewer-g", "service"]:
        assert rules_of(acl, subject_id) == rules_of(fleet_wide, subject_id), subject_id
    assert access_rules(["f"], ["service"], robots={}) == access_rules(["f"], ["service"])


def test_a_site_with_per_robot_identities(tmp_path: Path) -> None:
    mesh = {"a": "tls/127.0.0.1:7001", "b": "tls/127.0.0.1:7002"}
    site = make_site(tmp_path / "site", ["g"], robots={"f": ["r1", "r2"]}, mesh=mesh)
    folder = site.folder
    assert set(site.robots) == {"f/r1", "f/r2", "g"}  # f joins the fleets
    assert set(site.apps) == {"f", "g"}
    assert not (folder / "robot.f.pem").exists()
    for robot in ("r1", "r2"):
        pem, key = (
            folder / "robots" / "f" / f"{robot}.pem",
            folder / "robots" / "f" / f"{robot}.key",
        )
        assert common_name(pem) == f"robot.f/{robot}"
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
        config = site.robots[f"f/{robot}"]
        assert config == folder / "robots" / "f" / f"zenoh-{robot}-mtls.json5"
        assert f'"{key}"' in config.read_text()
        zenoh.Config.from_file(str(config))
    for router in site.routers.values():
        text = router.read_text()
        assert 'cert_common_names: ["robot.f/r1"]' in text
        assert '"robot.f"' not in text
        zenoh.Config.from_file(str(router))


def test_the_robot_option_and_its_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "site"
    assert main(["certs", "--out", str(out), "--robot", "lab/amr-1", "--robot", "lab/amr-2"]) == 0
    written = json.loads(capsys.readouterr().out)
    assert set(written["robots"]) == {"lab/amr-1", "lab/amr-2"}
    bad = {
        "lab": "give FLEET/ROBOT",
        "lab/": "give FLEET/ROBOT",
        "lab/a/b": "give FLEET/ROBOT",
        "lab/a*": "robot name 'a*'",
        "l b/a": "fleet name 'l b'",
        f"lab/{'r' * 60}": "at most 64",
    }
    for value, message in bad.items():
        assert main(["certs", "--out", str(tmp_path / "x"), "--robot", value]) == 1, value
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert message in err[0], err
    args = ["certs", "--out", str(tmp_path / "x"), "--robot", "lab/a", "--robot", "lab/a"]
    assert main(args) == 1
    assert "--robot lab/a is given twice" in capsys.readouterr().err
    assert not (tmp_path / "x" / "ca.key").exists()  # refused before anything is written
