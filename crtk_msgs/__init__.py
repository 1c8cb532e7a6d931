"""crtk_msgs: the CRTK messages and services of the dVRK, as ROS 2 Jazzy Python interfaces.

    from crtk_msgs.msg import OperatingState, StringStamped, CartesianImpedance, ...
    from crtk_msgs.srv import QueryForwardKinematics, QueryInverseKinematics, TriggerOperatingState

Every message and service of collaborative-robotics/crtk_msgs 1.3.0: msgs/crtk_msgs/msg
and srv hold upstream's definition files byte for byte, so the DDS type names
(crtk_msgs::msg::dds_::OperatingState_, crtk_msgs::srv::dds_::QueryForwardKinematics_Request_,
...), the CDR layout and the RIHS01 type hashes are those of a real dVRK. The ROS 2 Jazzy
code generators from PyPI built what is in this folder, on Linux x86_64 for every CPython
the Jazzy wheels exist for that BUILD_INFO.json lists under "abis" (3.11, 3.12, 3.13): the four
C libraries once, the Python side per ABI under its name (`*.cpython-312-x86_64-linux-gnu.so`,
picked by the interpreter's own SOABI). BUILD_INFO.json says against which ROS wheels and
lists every type hash. `.venv/bin/python msgs/build_crtk_msgs.py` builds it again for that
venv's Python.

This module is not generated. It loads the package's C libraries, by path, before any
message is used: rosidl_typesupport_c finds a package's Fast DDS type support with
dlopen("libcrtk_msgs__rosidl_typesupport_fastrtps_c.so"), a bare name that the dynamic
loader then resolves to the library already loaded under that name. (A ROS install
would find it through LD_LIBRARY_PATH; this folder is not on it.) The services live in the
same five libraries as the messages. What these link against, the std_msgs,
geometry_msgs, builtin_interfaces and service_msgs libraries and the rosidl runtime, come
from the ROS wheels' folders, which the venv's interpreter puts on LD_LIBRARY_PATH.
"""

from __future__ import annotations

import ctypes
import platform
import sys
import sysconfig
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_PLATFORM = ("Linux", "x86_64", "cpython")
# In dependency order: each one's crtk_msgs dependencies are loaded before it. The last is
# the Python side, shipped per ABI (its extension modules, crtk_msgs_s__*.<SOABI>.so, are
# found by Python's import among the package's files).
_LIBRARIES = (
    "libcrtk_msgs__rosidl_generator_c.so",
    "libcrtk_msgs__rosidl_typesupport_c.so",
    "libcrtk_msgs__rosidl_typesupport_fastrtps_c.so",
    "libcrtk_msgs__rosidl_typesupport_introspection_c.so",
)
_PYTHON_SIDE = "libcrtk_msgs__rosidl_generator_py"
_REBUILD = "build them for this Python with `.venv/bin/python msgs/build_crtk_msgs.py` (cmake, gcc, g++; see its docstring)"


def shipped_pythons() -> list[str]:
    """The Python versions ("3.11", ...) this package's message libraries are shipped for."""
    import re

    tags = set()
    for p in _HERE.glob(f"{_PYTHON_SIDE}.cpython-*.so"):
        m = re.match(rf"{_PYTHON_SIDE}\.cpython-3(\d+)-", p.name)
        if m:
            tags.add(int(m.group(1)))
    return [f"3.{minor}" for minor in sorted(tags)]


def _load_libraries() -> tuple[ctypes.CDLL, ...]:
    here = (platform.system(), platform.machine(), sys.implementation.name)
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    soabi = sysconfig.get_config_var("SOABI") or ""
    python_side = _HERE / f"{_PYTHON_SIDE}.{soabi}.so"
    if here != _PLATFORM or not python_side.exists():
        shipped = ", ".join(shipped_pythons()) or "none"
        raise ImportError(f"crtk_msgs: no message libraries for Python {version} ({soabi or '/'.join(here)}) in "
                          f"{_HERE} (shipped for Linux x86_64 CPython {shipped}); use a venv of one of those "
                          f"(`python3.12 -m venv .venv && .venv/bin/pip install -e .`), or {_REBUILD}")
    loaded = []
    for path in [*(_HERE / name for name in _LIBRARIES), python_side]:
        try:
            loaded.append(ctypes.CDLL(str(path)))
        except OSError as exc:
            raise ImportError(f"crtk_msgs: cannot load {path.name} ({exc}). The libraries were built "
                              f"against the ROS 2 wheels named in {_HERE / 'BUILD_INFO.json'}: import "
                              f"rclpy's environment first (the venv's python sets LD_LIBRARY_PATH), "
                              f"or, if those wheels changed, {_REBUILD}") from exc
    return tuple(loaded)


_libraries = _load_libraries()  # kept referenced for the life of the process
