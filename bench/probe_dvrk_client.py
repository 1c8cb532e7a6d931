#!/usr/bin/env python3
"""What the dVRK's own Python client uses on ROS 2: every topic, every service, with types.

    .venv/bin/python bench/probe_dvrk_client.py                      # the client alone
    .venv/bin/python bench/probe_dvrk_client.py --against rig_sim    # and what rig sim serves of it
    .venv/bin/python bench/probe_dvrk_client.py --json

In one process, the client's own objects -- `dvrk.psm(ral, 'PSM1')`, `dvrk.system(ral)` and
`dvrk.console(ral)` on one `crtk.ral('dvrk_client_probe')`, the unmodified sources of
../shared/dvrk-clients (see tests/hil/dvrk_client.py) -- are created, with no server
running and without spinning; then the ROS graph of that node is read: every topic the
client publishes and subscribes to and every service client it made, with its type and
its QoS (reliability, durability). The node's own infrastructure (/rosout, /parameter_events, its parameter and type
description services) is left out and counted.

--against NODE[,NODE...]: also waits (--wait s) for those nodes (a name, or /namespace/name)
to show up in the graph and reads what they publish, subscribe to and serve; the table
then says for each of the client's names whether it is served: `yes`, `no`, `wrong type:
T` (the other side uses another type), or `QoS: ...` (the types agree but the QoS
profiles cannot match). A topic the client subscribes to is served by a publisher, one it
publishes to by a subscriber, a service client by a service.

The domain: without --against, a private ROS_DOMAIN_ID (or --domain) with localhost
discovery; with --against, --domain or $ROS_DOMAIN_ID (that of the node to compare with),
and $ROS_AUTOMATIC_DISCOVERY_RANGE or LOCALHOST.

Output: a plain-text table; --json one JSON document (endpoints, left_out, against).
Exit status: 0; 2 when the client cannot run here (the reason on stderr); 3 when a node
named by --against did not show up.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NODE = "dvrk_client_probe"
OBSERVER = "dvrk_client_probe_observer"
INFRASTRUCTURE_TOPICS = {"/rosout", "/parameter_events"}
INFRASTRUCTURE_SERVICES = {"describe_parameters", "get_parameter_types", "get_parameters", "list_parameters",
                           "set_parameters", "set_parameters_atomically", "get_type_description"}
# how the client uses a name -> what the other side must have for it to be served
ROLES = {"publishes": "subscriptions", "subscribes": "publishers", "calls": "services"}


def private_domain() -> int:
    return 140 + os.getpid() % 40


# ---------------------------------------------------------------- in the client's process

def _split(full_name: str) -> tuple[str, str]:
    """'/ns/name' or 'name' -> (name, namespace)."""
    full_name = "/" + full_name.strip("/")
    namespace, _, name = full_name.rpartition("/")
    return name, namespace or "/"


def _qos_text(qos) -> str:
    if qos is None:
        return ""
    reliability = qos.reliability.name.lower().replace("best_effort", "best effort")
    durability = qos.durability.name.lower().replace("transient_local", "latched")
    # (the history depth is not part of discovery: the graph reports 0 for other nodes)
    return f"{reliability}, {durability}"


def _endpoints_of(node, name: str, namespace: str) -> dict:
    """{'publishers'|'subscriptions'|'services'|'clients': {topic: (types, [qos...])}} of one node."""
    listing = {
        "publishers": node.get_publisher_names_and_types_by_node(name, namespace),
        "subscriptions": node.get_subscriber_names_and_types_by_node(name, namespace),
        "services": node.get_service_names_and_types_by_node(name, namespace),
        "clients": node.get_client_names_and_types_by_node(name, namespace),
    }
    out: dict = {}
    for kind, pairs in listing.items():
        out[kind] = {}
        for topic, types in pairs:
            qos = []
            if kind in ("publishers", "subscriptions"):
                infos = (node.get_publishers_info_by_topic if kind == "publishers"
                         else node.get_subscriptions_info_by_topic)(topic)
                qos = [i.qos_profile for i in infos if i.node_name == name and i.node_namespace == namespace]
            out[kind][topic] = (list(types), qos)
    return out


def _stable_listing(node, name: str, namespace: str, wait: float, reads: int) -> dict | None:
    """The node's endpoints once `reads` reads 0.2 s apart agree (discovery settled); None
    if the node is not in the graph within `wait` s."""
    deadline = time.monotonic() + wait
    previous, same = None, 0
    while time.monotonic() < deadline:
        if (name, namespace) in node.get_node_names_and_namespaces():
            now = _endpoints_of(node, name, namespace)
            summary = {k: {t: v[0] for t, v in d.items()} for k, d in now.items()}
            same = same + 1 if summary == previous else 1
            if same >= reads:
                return now
            previous = summary
        time.sleep(0.2)
    return None if previous is None else _endpoints_of(node, name, namespace)


def _served(role: str, topic: str, ros_type: str, qos, others: dict) -> str:
    """yes / no / wrong type: T / QoS: reason, for one of the client's endpoints."""
    import rclpy.qos

    kind = ROLES[role]
    found = [(types, profiles) for listing in others.values() for t, (types, profiles) in listing[kind].items()
             if t == topic]
    if not found:
        return "no"
    types = sorted({t for ts, _ in found for t in ts})
    if ros_type not in types:
        return "wrong type: " + ", ".join(types)
    if role != "calls" and qos is not None:
        reasons = []
        for _, profiles in found:
            for other in profiles:
                pub, sub = (qos, other) if role == "publishes" else (other, qos)
                compatibility, reason = rclpy.qos.qos_check_compatible(pub, sub)
                if compatibility == rclpy.qos.QoSCompatibility.ERROR:
                    reasons.append(reason.removeprefix("ERROR: ").rstrip("; "))
                else:
                    return "yes"
        if reasons:
            return "QoS: " + reasons[0]
    return "yes"


def child(args: argparse.Namespace) -> int:
    import crtk
    import dvrk
    import rclpy

    ral = crtk.ral(NODE)
    dvrk.psm(ral, "PSM1")
    dvrk.system(ral)
    dvrk.console(ral)
    observer = rclpy.create_node(OBSERVER)
    try:
        mine = _stable_listing(observer, NODE, "/", 30.0, reads=2)  # local: known at once
        if mine is None:
            print(f"probe_dvrk_client: the client's node /{NODE} is not in the graph", file=sys.stderr)
            return 1
        endpoints, left_out = [], []
        for kind, role in (("publishers", "publishes"), ("subscriptions", "subscribes"), ("clients", "calls"),
                           ("services", "serves")):
            for topic, (types, profiles) in sorted(mine[kind].items()):
                infrastructure = (topic in INFRASTRUCTURE_TOPICS if kind in ("publishers", "subscriptions")
                                  else topic.startswith(f"/{NODE}/") and topic.rsplit("/", 1)[1] in INFRASTRUCTURE_SERVICES)
                for ros_type in types:
                    entry = {"name": topic, "type": ros_type, "client": role,
                             "qos": _qos_text(profiles[0]) if profiles else "", "_qos": profiles[0] if profiles else None}
                    (left_out if infrastructure else endpoints).append(entry)

        against = {}
        if args.against:
            others = {}
            for full in args.against:
                name, namespace = _split(full)
                # a remote node's endpoints arrive one by one: 1 s without change
                listing = _stable_listing(observer, name, namespace, args.wait, reads=6)
                if listing is None:
                    print(f"probe_dvrk_client: no node {namespace.rstrip('/')}/{name} on ROS_DOMAIN_ID="
                          f"{os.environ.get('ROS_DOMAIN_ID', '0')} within {args.wait:g} s", file=sys.stderr)
                    return 3
                others[full] = listing
            for e in endpoints:
                if e["client"] in ROLES:
                    e["served"] = _served(e["client"], e["name"], e["type"], e["_qos"], others)
            against = {full: {kind: sorted(listing[kind]) for kind in listing} for full, listing in others.items()}
        for e in endpoints + left_out:
            del e["_qos"]

        doc = {"node": f"/{NODE}", "domain": int(os.environ.get("ROS_DOMAIN_ID", "0")),
               "objects": ["dvrk.psm(ral, 'PSM1')", "dvrk.system(ral)", "dvrk.console(ral)"],
               "endpoints": endpoints, "left_out": [f"{e['name']} ({e['client']})" for e in left_out],
               "counts": {role: sum(e["client"] == role for e in endpoints) for role in (*ROLES, "serves")},
               "against": against}
        if args.against:
            doc["served"] = {v: sum(e.get("served", "").startswith(v) for e in endpoints)
                             for v in ("yes", "no", "wrong type", "QoS")}
        print(json.dumps(doc, indent=2) if args.json else table(doc))
        return 0
    finally:
        observer.destroy_node()
        ral.shutdown()


def table(doc: dict) -> str:
    columns = ["topic / service", "type", "client"] + (["served?"] if doc["against"] else []) + ["QoS"]
    rows = [[e["name"], e["type"], e["client"]] + ([e.get("served", "")] if doc["against"] else []) + [e["qos"]]
            for e in doc["endpoints"]]
    widths = [max(len(str(r[i])) for r in rows + [columns]) for i in range(len(columns))]
    lines = [f"The dVRK client ({', '.join(doc['objects'])}) as node {doc['node']} on ROS_DOMAIN_ID={doc['domain']}",
             "  ".join(c.ljust(w) for c, w in zip(columns, widths)).rstrip(),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    c = doc["counts"]
    lines.append(f"{len(rows)} names: publishes {c['publishes']}, subscribes {c['subscribes']}, "
                 f"calls {c['calls']} services, serves {c['serves']}; left out as node infrastructure: "
                 f"{len(doc['left_out'])}")
    if doc["against"]:
        s = doc["served"]
        lines.append(f"against {', '.join(doc['against'])}: served {s['yes']}, not served {s['no']}, "
                     f"wrong type {s['wrong type']}, QoS mismatch {s['QoS']}")
    return "\n".join(lines)


# ---------------------------------------------------------------- the launcher

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", type=lambda s: [n for n in s.split(",") if n], default=[],
                    help="node name(s) to compare with, e.g. rig_sim (comma-separated; /ns/name)")
    ap.add_argument("--domain", type=int, help="ROS_DOMAIN_ID (default: private; with --against $ROS_DOMAIN_ID)")
    ap.add_argument("--wait", type=float, default=20.0, help="seconds to wait for an --against node (default 20)")
    ap.add_argument("--json", action="store_true", help="print one JSON document")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)

    sys.path.insert(0, str(REPO))
    from tests.hil.dvrk_client import client_env, skip_reason

    why = skip_reason()
    if why is not None:
        print(f"probe_dvrk_client: the dVRK client cannot run here: {why}", file=sys.stderr)
        return 2
    env = client_env()
    if args.against:
        env["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else os.environ.get("ROS_DOMAIN_ID", "0"))
        env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    else:
        env["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else private_domain())
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    argv = [sys.executable, str(Path(__file__).resolve()), "--child", "--wait", str(args.wait)]
    argv += (["--against", ",".join(args.against)] if args.against else []) + (["--json"] if args.json else [])
    return subprocess.call(argv, env=env)


if __name__ == "__main__":
    sys.exit(main())
