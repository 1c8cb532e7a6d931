"""The environment of tests/hil/dvrk_client.py runs the dVRK's own Python client unmodified:
in a subprocess, `import crtk, dvrk, PyKDL` works, `crtk.ral` makes its ROS 2 node and
`crtk.utils` (which imports crtk_msgs.srv) imports; crtk_msgs comes from this repository
and PyKDL from the private folder, not from Debian's dist-packages put on the path whole.
Skipped, with the reason, where ../shared/dvrk-clients or python3-pykdl is absent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.dvrk_client import (  # noqa: E402
    DEBIAN_DIST_PACKAGES, REPO, client_env, client_scripts, clients_dir, skip_reason)

pytestmark = [pytest.mark.ros]

PROBE = r"""
import importlib, json, sys
import crtk, dvrk, PyKDL
ral = crtk.ral("dvrk_client_env_test")
utils = importlib.import_module("crtk.utils")
import crtk_msgs, crtk_msgs.srv
frame = crtk.msg_conversions.FrameFromPoseMsg(crtk.msg_conversions.FrameToPoseMsg(PyKDL.Frame(PyKDL.Vector(0.1, 0.2, 0.3))))
out = {
    "ros_version": ral.ros_version(), "node": ral.node_name(),
    "node_names": ral._node.get_node_names(),
    "files": {m.__name__: m.__file__ for m in (crtk, dvrk, PyKDL, crtk_msgs, utils)},
    "srv": sorted(n for n in dir(crtk_msgs.srv) if not n.startswith("_")),
    "psm": dvrk.psm.__name__, "utils": utils.utils.__name__,
    "frame_p": list(frame.p),
    "path": sys.path,
}
ral.shutdown()
print(json.dumps(out))
"""


def test_the_client_imports_and_makes_its_node(ros_domain):
    why = skip_reason()
    if why is not None:
        pytest.skip(why)
    env = client_env(domain=ros_domain)
    assert env["ROS_VERSION"] == "2" and env["ROS_DOMAIN_ID"] == str(ros_domain)
    # a guard against a hang, not a timing check
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, cwd=REPO.parent, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["ros_version"] == 2 and out["node"] == "dvrk_client_env_test"
    assert "dvrk_client_env_test" in out["node_names"]
    files = {name: Path(f) for name, f in out["files"].items()}
    clients = clients_dir()
    assert files["crtk"].is_relative_to(clients / "crtk_python_client" / "src" / "crtk")
    assert files["crtk.utils"].is_relative_to(clients / "crtk_python_client" / "src" / "crtk")
    assert files["dvrk"].is_relative_to(clients / "dvrk_python" / "src" / "dvrk")
    assert files["crtk_msgs"] == REPO / "crtk_msgs" / "__init__.py"
    assert files["PyKDL"].resolve().parent == DEBIAN_DIST_PACKAGES and files["PyKDL"].parent != DEBIAN_DIST_PACKAGES
    assert str(DEBIAN_DIST_PACKAGES) not in out["path"]
    assert {"QueryForwardKinematics", "QueryInverseKinematics", "TriggerOperatingState"} <= set(out["srv"])
    assert (out["psm"], out["utils"]) == ("psm", "utils")
    assert out["frame_p"] == pytest.approx([0.1, 0.2, 0.3])


def test_the_private_pykdl_folder_holds_only_the_module():
    why = skip_reason()
    if why is not None:
        pytest.skip(why)
    folder = Path(client_env()["PYTHONPATH"].split(os.pathsep)[3])
    assert [p.name for p in folder.iterdir()] == [f"PyKDL{__import__('sysconfig').get_config_var('EXT_SUFFIX')}"]
    assert all(p.is_symlink() for p in folder.iterdir())


def test_the_client_scripts_are_listed():
    why = skip_reason()
    if why is not None:
        pytest.skip(why)
    names = [p.name for p in client_scripts()]
    assert "dvrk_arm_test.py" in names and "crtk_servo_jp_example.py" in names
    assert all(p.suffix == ".py" and p.is_file() for p in client_scripts())


def test_skip_reasons(monkeypatch, tmp_path):
    monkeypatch.setenv("DVRK_CLIENTS", str(tmp_path / "nowhere"))
    assert skip_reason() == f"{tmp_path / 'nowhere'} ($DVRK_CLIENTS) is absent"
    assert client_scripts() == []
    with pytest.raises(RuntimeError, match="is absent"):
        client_env()
    monkeypatch.delenv("DVRK_CLIENTS")
    import tests.hil.dvrk_client as helper
    monkeypatch.setattr(helper, "DEFAULT_CLIENTS", tmp_path / "absent")
    assert skip_reason() == "../shared/dvrk-clients is absent"
    for src, package in (("crtk_python_client/src", "crtk"), ("dvrk_python/src", "dvrk")):
        (tmp_path / "absent" / src / package).mkdir(parents=True)
        (tmp_path / "absent" / src / package / "__init__.py").write_text("")
    monkeypatch.setattr(helper, "DEBIAN_DIST_PACKAGES", tmp_path / "no-dist-packages")
    assert skip_reason() == "PyKDL is absent: apt-get install python3-pykdl"


def test_probe_lists_what_the_client_uses(ros_domain):
    """bench/probe_dvrk_client.py, run as a person runs it, lists the client's names: for
    one PSM, the system and the console, 29 topics published, 18 subscribed, 3 services."""
    why = skip_reason()
    if why is not None:
        pytest.skip(why)
    env = dict(os.environ)
    env.pop("ROS_DOMAIN_ID", None)
    done = subprocess.run([sys.executable, str(REPO / "bench" / "probe_dvrk_client.py"), "--json",
                           "--domain", str(ros_domain)],
                          env=env, cwd=REPO.parent, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    doc = json.loads(done.stdout)
    assert doc["counts"] == {"publishes": 29, "subscribes": 18, "calls": 3, "serves": 0}
    used = {(e["name"], e["type"], e["client"]) for e in doc["endpoints"]}
    assert {("/PSM1/measured_js", "sensor_msgs/msg/JointState", "subscribes"),
            ("/PSM1/operating_state", "crtk_msgs/msg/OperatingState", "subscribes"),
            ("/PSM1/state_command", "crtk_msgs/msg/StringStamped", "publishes"),
            ("/PSM1/servo_jp", "sensor_msgs/msg/JointState", "publishes"),
            ("/PSM1/forward_kinematics", "crtk_msgs/srv/QueryForwardKinematics", "calls"),
            ("/PSM1/inverse_kinematics", "crtk_msgs/srv/QueryInverseKinematics", "calls"),
            ("/system/power_on", "std_msgs/msg/Empty", "publishes")} <= used
    assert "/rosout (publishes)" in doc["left_out"]
