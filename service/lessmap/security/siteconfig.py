"""Who may do what on a lessmap site, as Zenoh configs: access rules, router and client files.

Who may do what is decided by the router, from the common name (CN) of the certificate a
session presents (``robot.<fleet>``, or ``robot.<fleet>/<robot>`` for a fleet with per-robot
identities, ``app.<fleet>``, ``viewer.<fleet>``, the service names, and in a mesh the other
routers' ``router.<name>``) or from the user name (usrpwd).
``access_rules`` is the one place that maps those roles to Zenoh ``access_control`` rules;
``lessmap certs`` writes a site's configs from it and renders the templates in ``deploy/``
from it, so they cannot drift apart. Pure data: no cryptography.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from lessmap.config.qos import WAIT_BEFORE_DROP_US, slow_consumer_qos
from lessmap_schemas import keys

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

#: Where the templates in ``deploy/`` expect the site's files.
TEMPLATE_DIR = "/etc/lessmap/tls"
#: The placeholder fleet name of the templates.
TEMPLATE_FLEET = "FLEET"
DEFAULT_ENDPOINT = "tls/127.0.0.1:7447"

P = keys.KEY_PREFIX
ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
#: What a reader (fleet app, viewer) may send: declarations of interest and queries.
READ_MESSAGES = ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"]


def workers_access() -> dict[str, dict[str, Any]]:
    """The subject, rule and policy that let ``serve --workers N``'s workers in.

    The workers reach their parent's router over a Unix socket in a private folder: the
    subject is that link protocol, so no other session gains anything. ``**`` skips
    verbatim chunks (``@``): the service's own keys and Zenoh's advanced publishers'
    (``@adv``) are named as well.
    """
    name = "lessmap-workers"
    return {
        "subject": {"id": name, "link_protocols": ["unixsock-stream"]},
        "rule": {
            "id": name,
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": ALL_MESSAGES,
            "key_exprs": ["**", f"{P}/@/**", "**/@adv/**", f"{P}/@/**/@adv/**"],
        },
        "policy": {"rules": [name], "subjects": [name]},
    }


def robot_name(fleet: str, robot: str | None = None) -> str:
    """Return the certificate CN (or user name) of the robots of ``fleet``, or of one robot.

    ``robot.<fleet>`` speaks for every robot of the fleet, ``robot.<fleet>/<robot>`` for one
    (per-robot identities). Names never hold ``/``, so no CN can be read both ways.
    """
    return f"robot.{fleet}" if robot is None else f"robot.{fleet}/{robot}"


def identity_file(identity: str) -> str:
    """Return where the key and certificate of ``identity`` are, in the site's folder.

    ``<identity>.key`` and ``.pem``, but ``robots/<fleet>/<robot>.key`` and ``.pem`` for a
    per-robot identity: one folder per fleet, and no file name holding a ``/``.
    """
    role_fleet, sep, robot = identity.partition("/")
    return f"robots/{role_fleet.removeprefix('robot.')}/{robot}" if sep else identity


def app_name(fleet: str) -> str:
    """Return the certificate CN (or user name) of the fleet apps of ``fleet``."""
    return f"app.{fleet}"


def viewer_name(fleet: str) -> str:
    """Return the certificate CN (or user name) of the viewers of ``fleet`` (``lessmap view``).

    A viewer reads what a fleet app reads and the robots' frames (their poses, for the
    trajectories): it sees where the robots are, which an app does not.
    """
    return f"viewer.{fleet}"


def router_name(name: str) -> str:
    """Return the certificate CN of the mesh router ``name`` (``router.a``, ``router.b``)."""
    return f"router.{name}"


def _rule(rule_id: str, flow: str, messages: Sequence[str], key_exprs: Sequence[str]) -> Any:
    return {
        "id": rule_id,
        "messages": list(messages),
        "flows": [flow],
        "permission": "allow",
        "key_exprs": list(key_exprs),
    }


def access_rules(
    fleets: Sequence[str],
    service_names: Sequence[str],
    subject_kind: str = "cert_common_names",
    routers: Sequence[str] = (),
    robots: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, Any]:
    """Return the ``access_control`` section: deny by default, allow each role its keys.

    Ingress rules say what a session may send to the router; egress rules what the router
    forwards to it (declarations of interest included: a publisher only sends where a
    subscriber was announced to it).

    Args:
        fleets: fleet names; each gets a robot, an app and a viewer subject.
        service_names: identities of the service instances.
        subject_kind: ``cert_common_names`` (mTLS) or ``usernames`` (usrpwd).
        routers: identities of the other routers of a mesh: they relay every lessmap
            message both ways (each client is still held to its rules by its own router).
        robots: fleet to robot names, for fleets with per-robot identities: a subject
            per robot, held to its own keys, and no fleet-wide robot subject.
    """
    any_robot = f"{P}/*/*"
    # Frames keys end with the robot's partition chunk (schemas/README.md §2a). The rules
    # name it with `*`: the chunk is computed from the fleet and robot names, so it changes
    # nothing in who may put what; the fleet chunk alone decides.
    any_frames = f"{any_robot}/frames/*"
    # Session checkpoints, shipped between service instances: service identities only (a
    # forged checkpoint would inject session state). No chunk below starts with `@`, so `**`
    # covers every partition, fleet and robot.
    checkpoints = f"{P}/@/checkpoints/**"
    # Release announcements of a hand-over (schemas/README.md §2a): service identities only
    # too (a forged one would make a joining instance fetch checkpoints too early).
    released = f"{P}/@/released/**"
    # Every key of the contract a service instance (and a router of a mesh) deals with.
    every_key = [
        any_frames,
        f"{any_frames}/@adv/**",
        f"{any_robot}/transitions",
        f"{any_robot}/transitions/@adv/**",
        f"{any_robot}/errors",
        f"{any_robot}/state",
        f"{any_robot}/areas",
        f"{any_robot}/submaps/*",
        f"{P}/@/health/*",
        f"{P}/@/instances/*",
        f"{P}/@/errors/*",
        checkpoints,
        released,
    ]
    rules = [
        _rule(
            "service-in",
            "ingress",
            ["put", "delete", "reply"],
            [
                f"{any_robot}/transitions",
                f"{any_robot}/transitions/@adv/**",
                f"{any_robot}/errors",
                f"{any_robot}/state",
                f"{any_robot}/areas",
                f"{any_robot}/submaps/*",
                f"{P}/@/health/*",
                f"{P}/@/errors/*",
            ],
        ),
        _rule(
            "service-declare",
            "ingress",
            ["declare_queryable", "liveliness_token"],
            [
                f"{any_robot}/state",
                f"{any_robot}/areas",
                f"{any_robot}/submaps/*",
                f"{any_robot}/transitions/@adv/**",
                f"{P}/@/health/*",
                f"{P}/@/instances/*",
            ],
        ),
        _rule(
            "service-read",
            "ingress",
            ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"],
            [any_frames, f"{any_frames}/@adv/**", f"{P}/@/instances/*"],
        ),
        # The owner puts, the standby subscribes, every instance declares the queryable and
        # a new owner queries it; a former owner puts its releases, which a joining instance
        # subscribes to (schemas/README.md §2a, hand-over).
        _rule(
            "service-checkpoints",
            "ingress",
            ["put", "delete", "declare_subscriber", "declare_queryable", "query", "reply"],
            [checkpoints, released],
        ),
        _rule(
            "service-out",
            "egress",
            ALL_MESSAGES,
            every_key,
        ),
    ]
    # The service declares its subscriber and queryables with wildcards (every fleet at once).
    # A declaration is forwarded to a client only where a rule *includes* its whole key
    # expression, and a client that never learns of the subscriber sends it nothing (Zenoh
    # filters at the writer): robots and apps must see these, and only these, wildcards
    # (`frames/*` includes the per-partition `frames/<p>` subscribers of the owners).
    rules.append(
        _rule(
            "see-service",
            "egress",
            ["declare_subscriber", "declare_queryable"],
            [any_frames, f"{any_robot}/state", f"{any_robot}/areas", f"{any_robot}/submaps/*"],
        )
    )
    subjects: list[dict[str, Any]] = [{"id": "service", subject_kind: list(service_names)}]
    policies: list[dict[str, Any]] = [
        {"rules": ["service-in", "service-declare", "service-read", "service-checkpoints",
                   "service-out"],
         "subjects": ["service"]}
    ]  # fmt: skip
    if routers:
        # Another router of the mesh relays what the roles connected to it may send and
        # what their subscribers, queryables and tokens declare: every message on every
        # lessmap key, both ways (each `@` key named: `**` never matches an `@` chunk).
        # Each role's own rules are enforced by the router it is connected to, on the way
        # in (what it may send or declare) and on the way out (what it receives).
        relayed = every_key
        rules += [
            _rule("router-in", "ingress", ALL_MESSAGES, relayed),
            _rule("router-out", "egress", ALL_MESSAGES, relayed),
        ]
        subjects.append({"id": "routers", subject_kind: list(routers)})
        policies.append({"rules": ["router-in", "router-out"], "subjects": ["routers"]})
    for fleet in fleets:
        # A fleet with per-robot identities has one robot subject per robot, none fleet-wide.
        own = (robots or {}).get(fleet)
        scopes = (
            [(f"robot-{fleet}/{r}", robot_name(fleet, r), r) for r in own]
            if own
            else [(f"robot-{fleet}", robot_name(fleet), "*")]
        )
        for rule_id, identity, robot in scopes:
            robot_rules, policy = _robot_access(rule_id, f"{P}/{fleet}/{robot}")
            rules += robot_rules
            subjects.append({"id": rule_id, subject_kind: [identity]})
            policies.append(policy)
        robots_of_fleet = f"{P}/{fleet}/*"
        frames = f"{robots_of_fleet}/frames/*"  # any robot and partition chunk, this fleet only
        app_keys = [
            f"{robots_of_fleet}/transitions",
            f"{robots_of_fleet}/transitions/@adv/**",
            f"{robots_of_fleet}/errors",
            f"{robots_of_fleet}/state",
            f"{robots_of_fleet}/areas",
            f"{robots_of_fleet}/submaps/*",
            f"{P}/@/health/*",
            f"{P}/@/instances/*",
        ]
        rules += [
            # Fleet apps read their fleet's outputs (with the transitions' history and
            # recovery under @adv) and the service's liveliness and health; viewers read
            # the robots' frames as well (lessmap view draws their poses).
            _rule(f"app-{fleet}-read", "ingress", READ_MESSAGES, app_keys),
            _rule(f"app-{fleet}-out", "egress", ALL_MESSAGES, app_keys),
            _rule(f"viewer-{fleet}-read", "ingress", READ_MESSAGES, [frames, *app_keys]),
            _rule(f"viewer-{fleet}-out", "egress", ALL_MESSAGES, [frames, *app_keys]),
        ]
        subjects += [
            {"id": f"app-{fleet}", subject_kind: [app_name(fleet)]},
            {"id": f"viewer-{fleet}", subject_kind: [viewer_name(fleet)]},
        ]
        policies += [
            {
                "rules": [f"app-{fleet}-read", f"app-{fleet}-out", "see-service"],
                "subjects": [f"app-{fleet}"],
            },
            {
                "rules": [f"viewer-{fleet}-read", f"viewer-{fleet}-out", "see-service"],
                "subjects": [f"viewer-{fleet}"],
            },
        ]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _robot_access(rule_id: str, robots: str) -> tuple[list[Any], dict[str, Any]]:
    """Return the rules and policy of the robot subject ``rule_id``, for the keys of ``robots``.

    ``robots`` is ``P/<fleet>/*`` for a fleet-wide identity, ``P/<fleet>/<robot>`` for one
    robot's: the same rules, so a per-robot identity may do for its robot what a fleet-wide
    one may do for any robot of its fleet, and nothing else.
    """
    frames = f"{robots}/frames/*"  # any partition chunk: the names alone decide
    rules = [
        # Frames and session ends, and what the robot's AdvancedPublisher declares: the
        # cache queryable and its replies, the publisher's liveliness token.
        _rule(f"{rule_id}-put", "ingress", ["put"], [frames]),
        _rule(
            f"{rule_id}-cache",
            "ingress",
            ["declare_queryable", "reply", "liveliness_token"],
            [f"{frames}/@adv/**"],
        ),
        # The SDK's robot follows its own errors and state, and the service instances'
        # tokens (its partition's owner, schemas/README.md §2a).
        _rule(
            f"{rule_id}-read",
            "ingress",
            ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"],
            [f"{robots}/errors", f"{robots}/state", f"{P}/@/instances/*"],
        ),
        _rule(
            f"{rule_id}-out",
            "egress",
            ALL_MESSAGES,
            [
                frames,
                f"{frames}/@adv/**",
                f"{robots}/errors",
                f"{robots}/state",
                f"{P}/@/instances/*",
            ],
        ),
    ]
    policy = {"rules": [r["id"] for r in rules] + ["see-service"], "subjects": [rule_id]}
    return rules, policy


# Routers drop lessmap puts toward a consumer that stops reading (docs/design/slow-consumers.md).
_DROP_WAIT = {"queue": {"congestion_control": {"drop": {"wait_before_drop": WAIT_BEFORE_DROP_US}}}}


def router_config(
    folder: str,
    fleets: Sequence[str],
    service_names: Sequence[str],
    endpoint: str = DEFAULT_ENDPOINT,
    robots: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, Any]:
    """Return the router's config: TLS with client certificates, deny-by-default ACL.

    ``robots`` names the robots of the fleets with per-robot identities (``access_rules``).
    """
    return {
        "mode": "router",
        "listen": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "timestamping": {"enabled": True},
        "qos": {"network": slow_consumer_qos()},
        "transport": {
            "link": {
                "tx": _DROP_WAIT,
                "tls": {
                    "root_ca_certificate": f"{folder}/ca.pem",
                    "listen_private_key": f"{folder}/router.key",
                    "listen_certificate": f"{folder}/router.pem",
                    "enable_mtls": True,
                },
            }
        },
        "access_control": access_rules(fleets, service_names, robots=robots),
    }


def mesh_router_config(
    folder: str,
    name: str,
    mesh: dict[str, str],
    fleets: Sequence[str],
    service_names: Sequence[str],
    robots: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, Any]:
    """Return the config of router ``name`` of a mesh: mTLS both ways, access control.

    It listens on its own endpoint and connects to every other router's, presenting its
    certificate (CN ``router.<name>``) both when it accepts and when it dials, and checking
    that the router dialled is named in its certificate. The access control is the single
    router's plus a subject for the mesh's routers (``access_rules(routers=...)``).

    Args:
        folder: where the site's files are.
        name: this router's name, a key of ``mesh``.
        mesh: every router of the mesh, name to TLS endpoint.
        fleets: fleet names.
        service_names: identities of the service instances.
        robots: the robots of the fleets with per-robot identities (``access_rules``).
    """
    cert = f"{folder}/{router_name(name)}"
    return {
        "mode": "router",
        "listen": {"endpoints": [mesh[name]]},
        "connect": {"endpoints": [e for n, e in mesh.items() if n != name]},
        "scouting": {"multicast": {"enabled": False}},
        "timestamping": {"enabled": True},
        "qos": {"network": slow_consumer_qos()},
        "transport": {
            "link": {
                "tx": _DROP_WAIT,
                "tls": {
                    "root_ca_certificate": f"{folder}/ca.pem",
                    "listen_private_key": f"{cert}.key",
                    "listen_certificate": f"{cert}.pem",
                    "connect_private_key": f"{cert}.key",
                    "connect_certificate": f"{cert}.pem",
                    "enable_mtls": True,
                    "verify_name_on_connect": True,
                },
            }
        },
        "access_control": access_rules(
            fleets, service_names, routers=[router_name(n) for n in mesh], robots=robots
        ),
    }


def client_config(
    folder: str, identity: str, endpoint: str | Sequence[str] = DEFAULT_ENDPOINT
) -> dict[str, Any]:
    """Return a client's config: connect over TLS, prove ``identity`` with its certificate.

    ``endpoint`` may list several routers (a mesh): the client connects to the first that
    answers.
    """
    endpoints = [endpoint] if isinstance(endpoint, str) else list(endpoint)
    return {
        "mode": "client",
        "connect": {"endpoints": endpoints},
        "scouting": {"multicast": {"enabled": False}},
        "timestamping": {"enabled": True},
        "transport": {
            "link": {
                "tls": {
                    "root_ca_certificate": f"{folder}/ca.pem",
                    "connect_private_key": f"{folder}/{identity_file(identity)}.key",
                    "connect_certificate": f"{folder}/{identity_file(identity)}.pem",
                    "enable_mtls": True,
                    # The router's certificate must name the host dialled (its SAN).
                    "verify_name_on_connect": True,
                }
            }
        },
    }


def usrpwd_router_config(
    folder: str,
    fleets: Sequence[str],
    service_names: Sequence[str],
    endpoint: str = DEFAULT_ENDPOINT,
) -> dict[str, Any]:
    """Return a router config that authenticates by user name and password over TLS."""
    conf = router_config(folder, fleets, service_names, endpoint)
    del conf["transport"]["link"]["tls"]["enable_mtls"]
    conf["transport"]["auth"] = {
        "usrpwd": {
            # One `user:password` line per identity, e.g. `robot.warehouse:<secret>`.
            "dictionary_file": f"{folder}/credentials.txt",
        }
    }
    conf["access_control"] = access_rules(fleets, service_names, "usernames")
    return conf


def usrpwd_client_config(
    folder: str, identity: str, endpoint: str = DEFAULT_ENDPOINT
) -> dict[str, Any]:
    """Return a client config that logs in as ``identity`` over server-authenticated TLS."""
    conf = client_config(folder, identity, endpoint)
    conf["transport"]["link"]["tls"] = {
        "root_ca_certificate": f"{folder}/ca.pem",
        "verify_name_on_connect": True,
    }
    conf["transport"]["auth"] = {"usrpwd": {"user": identity, "password": "CHANGE-ME"}}
    return conf


def render(config: dict[str, Any], header: str) -> str:
    """Return ``config`` as JSON5 text (JSON with ``//`` comments), short lists on one line."""
    lines = [f"// {line}".rstrip() for line in header.strip().splitlines()]
    return "\n".join(lines) + "\n" + _dump(config, 0) + "\n"


def _dump(value: Any, indent: int, width: int = 100) -> str:
    flat = _inline(value)
    if not isinstance(value, dict | list) or 2 * indent + len(flat) <= width - 20:
        return flat
    pad = "  " * (indent + 1)
    if isinstance(value, dict):
        items = [f"{pad}{k}: {_dump(v, indent + 1)}" for k, v in value.items()]
        opening, ending = "{", "}"
    else:
        items = [f"{pad}{_dump(v, indent + 1)}" for v in value]
        opening, ending = "[", "]"
    return opening + "\n" + ",\n".join(items) + ",\n" + "  " * indent + ending


def _inline(value: Any) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k}: {_inline(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list):
        return "[" + ", ".join(_inline(v) for v in value) + "]"
    return json.dumps(value, ensure_ascii=False)
