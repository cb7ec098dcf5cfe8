"""What routers and services do toward a consumer that stops reading (pure data).

Shared by the service's own Zenoh config (``lessmap.runtime.zenoh_config``) and the site
configs ``lessmap certs`` renders (``lessmap.security.siteconfig``), so both drop alike.
"""

from __future__ import annotations

from lessmap_schemas import keys

# How long a DROP message waits for room on a full link. Zenoh's 1 ms dropped transitions
# and frames on a busy host whose sender thread was merely descheduled; a link that stays
# full this long has a consumer that does not read.
WAIT_BEFORE_DROP_US = 50_000


def slow_consumer_qos() -> list[dict[str, object]]:
    """What a router does with lessmap puts toward a full link: drop, never wait.

    A robot puts its frames with BLOCK (it never drops one at its own link), and Zenoh keeps
    a message's congestion control hop by hop: a router forwarding such a frame to an app
    that stopped reading would wait, and stop forwarding that robot's frames to everyone.
    Overwritten on egress, the app that does not read loses its copies; the others do not
    wait (docs/design/slow-consumers.md).
    """
    return [
        {
            "id": "lessmap-slow-consumers",
            "messages": ["put"],
            "key_exprs": [f"{keys.KEY_PREFIX}/**"],
            "flows": ["egress"],
            "overwrite": {"congestion_control": "drop"},
        }
    ]
