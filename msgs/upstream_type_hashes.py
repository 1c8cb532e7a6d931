#!/usr/bin/env python3
"""The RIHS01 type hashes of upstream crtk_msgs, from upstream's own files.

    .venv/bin/python msgs/upstream_type_hashes.py [--git DIR] [--rev REV] [--venv DIR] [--json]

Takes the msg/*.msg and srv/*.srv files of collaborative-robotics/crtk_msgs straight from
a git clone of it (default: the mirror at /work/.mirror/collaborative-robotics+crtk_msgs/repo,
revision HEAD; `--git` names another clone), untouched, into a scratch folder, and has the
ROS 2 Jazzy `rosidl hash` command (rosidl_cli with rosidl_adapter and
rosidl_generator_type_description) compute their type descriptions and hashes against
the std_msgs, geometry_msgs, builtin_interfaces and service_msgs definitions that the ROS
wheels ship under share/. It uses the scratch venv that msgs/build_crtk_msgs.py leaves in
build/crtk_msgs/venv (the project's venv lacks catkin_pkg, which rosidl_adapter needs);
`--venv` names another venv with the same wheels.

This is the path that does not go through msgs/crtk_msgs, CMake or
msgs/build_crtk_msgs.py: its output is what tests/msgs/test_crtk_msgs.py records as
upstream's hashes, and what the shipped build (crtk_msgs/BUILD_INFO.json) must equal.
It prints one line per type, `name hash`, or a JSON object with --json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

MIRROR = Path("/work/.mirror/collaborative-robotics+crtk_msgs/repo")
SCRATCH_VENV = Path(__file__).resolve().parents[1] / "build" / "crtk_msgs" / "venv"
PACKAGE = "crtk_msgs"
# The packages whose definitions upstream's interfaces use (upstream's package.xml) and
# service_msgs, which every service's event message uses.
DEPENDENCIES = ("builtin_interfaces", "std_msgs", "geometry_msgs", "service_msgs")


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout


def upstream_files(repo: Path, rev: str) -> dict[str, bytes]:
    """{relative path: bytes} of every msg/*.msg and srv/*.srv at `rev`."""
    names = [n for n in git(repo, "ls-tree", "-r", "--name-only", rev).splitlines()
             if n.startswith(("msg/", "srv/")) and n.endswith((".msg", ".srv"))]
    return {n: subprocess.run(["git", "-C", str(repo), "show", f"{rev}:{n}"], check=True,
                              capture_output=True).stdout for n in names}


def type_hashes(files: dict[str, bytes], venv: Path) -> dict[str, str]:
    share = venv / "share"
    rosidl = venv / "bin" / "rosidl"
    missing = [d for d in DEPENDENCIES if not (share / d).is_dir()]
    if missing or not rosidl.exists():
        sys.exit(f"upstream_type_hashes: {venv} lacks rosidl or share/{missing}; run "
                 "msgs/build_crtk_msgs.py once (it makes that venv), or give --venv")
    with tempfile.TemporaryDirectory(prefix="crtk_msgs-upstream-") as tmp:
        src, out = Path(tmp) / PACKAGE, Path(tmp) / "out"
        for rel, data in files.items():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            (src / rel).write_bytes(data)
        includes = [arg for d in DEPENDENCIES for arg in ("-I", str(share / d))]
        # rosidl finds its own templates through the ament index of the venv
        env = dict(os.environ, AMENT_PREFIX_PATH=str(venv))
        done = subprocess.run([str(rosidl), "hash", "-o", str(out), *includes, PACKAGE,
                               *(f"{src}:{rel}" for rel in sorted(files))], env=env, capture_output=True, text=True)
        if done.returncode:
            sys.exit(f"upstream_type_hashes: rosidl hash failed ({done.returncode}):\n{done.stdout}{done.stderr}")
        hashes = {}
        for desc in sorted(out.rglob("*.json")):
            for entry in json.loads(desc.read_text())["type_hashes"]:
                if entry["type_name"].startswith(f"{PACKAGE}/"):
                    hashes[entry["type_name"]] = entry["hash_string"]
        return dict(sorted(hashes.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--git", type=Path, default=MIRROR, help="a git clone of collaborative-robotics/crtk_msgs")
    ap.add_argument("--rev", default="HEAD", help="the revision to take the files from")
    ap.add_argument("--venv", type=Path, default=SCRATCH_VENV, help="a venv with rosidl and catkin_pkg")
    ap.add_argument("--json", action="store_true", help="print a JSON object")
    args = ap.parse_args()
    if shutil.which("git") is None or not args.git.exists():
        sys.exit(f"upstream_type_hashes: no git clone at {args.git} (--git DIR)")
    commit = git(args.git, "rev-parse", args.rev).strip()
    files = upstream_files(args.git, commit)
    hashes = type_hashes(files, args.venv.resolve())
    if args.json:
        print(json.dumps({"commit": commit, "files": sorted(files), "type_hashes": hashes}, indent=2))
    else:
        print(f"# collaborative-robotics/crtk_msgs {commit}: {len(files)} files, {len(hashes)} types")
        for name, digest in hashes.items():
            print(name, digest)


if __name__ == "__main__":
    main()
