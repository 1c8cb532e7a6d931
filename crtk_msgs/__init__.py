"""crtk_msgs: the CRTK messages and services of the dVRK, as ROS 2 Jazzy Python interfaces.

    from crtk_msgs.msg import OperatingState, StringStamped, CartesianImpedance, ...
    from crtk_msgs.srv import QueryForwardKinematics, QueryInverseKinematics, TriggerOperatingState

Every message and service of collaborative-robotics/crtk_msgs 1.3.0: msgs/crtk_msgs/msg
and srv hold upstream's definition files byte for byte, so the DDS type names
(crtk_msgs::msg::dds_::OperatingState_, crtk_msgs::srv::dds_::QueryForwardKinematics_Request_,
...), the CDR layout and the RIHS01 type hashes are those of a real dVRK. The ROS 2 Jazzy
code generators from PyPI built what is in this folder, for CPython 3.11 on Linux x86_64;
BUILD_INFO.json says against which ROS wheels and lists every type hash.
`.venv/bin/python msgs/build_crtk_msgs.py` builds it again.

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
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_BUILT_FOR = ("Linux", "x86_64", "cpython", (3, 11))
# In dependency order: each one's crtk_msgs dependencies are loaded before it.
_LIBRARIES = (
    "libcrtk_msgs__rosidl_generator_c.so",
    "libcrtk_msgs__rosidl_typesupport_c.so",
    "libcrtk_msgs__rosidl_typesupport_fastrtps_c.so",
    "libcrtk_msgs__rosidl_typesupport_introspection_c.so",
    "libcrtk_msgs__rosidl_generator_py.so",
)
_REBUILD = "rebuild them with `.venv/bin/python msgs/build_crtk_msgs.py` (see its docstring)"


def _load_libraries() -> tuple[ctypes.CDLL, ...]:
    here = (platform.system(), platform.machine(), sys.implementation.name, sys.version_info[:2])
    if here != _BUILT_FOR:
        raise ImportError(f"crtk_msgs: the shipped message libraries are built for {_BUILT_FOR}, "
                          f"this interpreter is {here}; {_REBUILD}")
    loaded = []
    for name in _LIBRARIES:
        try:
            loaded.append(ctypes.CDLL(str(_HERE / name)))
        except OSError as exc:
            raise ImportError(f"crtk_msgs: cannot load {name} ({exc}). The libraries were built "
                              f"against the ROS 2 wheels named in {_HERE / 'BUILD_INFO.json'}: import "
                              f"rclpy's environment first (the venv's python sets LD_LIBRARY_PATH), "
                              f"or, if those wheels changed, {_REBUILD}") from exc
    return tuple(loaded)


_libraries = _load_libraries()  # kept referenced for the life of the process
