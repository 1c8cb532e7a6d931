"""The dVRK's own Python client (crtk, dvrk) in a subprocess, unmodified: where it is and
the environment it runs in.

The client's sources are not part of the project: ../shared/dvrk-clients (beside the
repository; `DVRK_CLIENTS` names another folder) holds crtk_python_client and dvrk_python
as their upstreams publish them. They need, beside rclpy and the ROS 2 messages of the
venv:

- `crtk_msgs` whole (`crtk.utils` imports crtk_msgs.srv at import time): the repository
  root, where the shipped package is, goes first on PYTHONPATH;
- `PyKDL` (`crtk.msg_conversions`): Debian's python3-pykdl, built for this CPython. Only
  its extension module is put on the path, through a private temporary folder that holds
  nothing but a symlink to it: /usr/lib/python3/dist-packages whole would shadow the
  venv's own packages (numpy, ...);
- `ROS_VERSION=2`, so that `crtk.ral` is the ROS 2 layer.

    from tests.hil.dvrk_client import client_env, skip_reason, client_scripts
    if (why := skip_reason()) is not None:
        pytest.skip(why)
    subprocess.run([sys.executable, "-c", "import crtk, dvrk, PyKDL"], env=client_env(domain=42))

Run the client with this interpreter (sys.executable, the venv's): its rclpy is the one
the shipped crtk_msgs libraries were built against.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sysconfig
import tempfile
from collections.abc import Mapping
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CLIENTS_VARIABLE = "DVRK_CLIENTS"
DEFAULT_CLIENTS = REPO.parent / "shared" / "dvrk-clients"
# Debian's python3-pykdl puts its module here, named for the CPython it was built for.
DEBIAN_DIST_PACKAGES = Path("/usr/lib/python3/dist-packages")
# Inside the clients folder: the importable package folders and the scripts' folders.
PACKAGES = {"crtk": "crtk_python_client/src", "dvrk": "dvrk_python/src"}
SCRIPT_FOLDERS = ("dvrk_python/scripts", "crtk_python_client/scripts")

_pykdl_dir: Path | None = None


def clients_dir() -> Path:
    """The folder holding crtk_python_client/ and dvrk_python/: $DVRK_CLIENTS if set, else
    ../shared/dvrk-clients beside the repository."""
    named = os.environ.get(CLIENTS_VARIABLE)
    return Path(named).expanduser().resolve() if named else DEFAULT_CLIENTS


def _clients_label() -> str:
    named = os.environ.get(CLIENTS_VARIABLE)
    return f"{named} (${CLIENTS_VARIABLE})" if named else "../shared/dvrk-clients"


def pykdl_library() -> Path | None:
    """Debian's PyKDL extension module for this interpreter, or None where it is absent."""
    path = DEBIAN_DIST_PACKAGES / f"PyKDL{sysconfig.get_config_var('EXT_SUFFIX')}"
    return path if path.is_file() else None


def skip_reason() -> str | None:
    """Why the client cannot run here, in one line; None when it can."""
    clients = clients_dir()
    if not clients.is_dir():
        return f"{_clients_label()} is absent"
    for package, src in PACKAGES.items():
        if not (clients / src / package / "__init__.py").is_file():
            return f"{_clients_label()} has no {src}/{package}"
    if pykdl_library() is None:
        return "PyKDL is absent: apt-get install python3-pykdl"
    return None


def _private_pykdl_dir() -> Path:
    """A temporary folder of this process holding only a symlink to Debian's PyKDL module
    (made once, removed when the process exits)."""
    global _pykdl_dir
    library = pykdl_library()
    if library is None:
        raise RuntimeError("PyKDL is absent: apt-get install python3-pykdl")
    if _pykdl_dir is None or not (_pykdl_dir / library.name).exists():
        folder = Path(tempfile.mkdtemp(prefix="dvrk-client-pykdl-"))
        (folder / library.name).symlink_to(library)
        atexit.register(shutil.rmtree, folder, True)
        _pykdl_dir = folder
    return _pykdl_dir


def client_pythonpath() -> list[str]:
    """PYTHONPATH entries, in order: the repository (crtk_msgs), the client's two src
    folders, the private PyKDL folder."""
    clients = clients_dir()
    return [str(REPO), *(str(clients / src) for src in PACKAGES.values()), str(_private_pykdl_dir())]


def client_env(base: Mapping[str, str] | None = None, *, domain: int | None = None, **extra: str) -> dict:
    """The environment in which a subprocess of this interpreter can `import crtk, dvrk,
    PyKDL` unmodified: `base` (default os.environ) with PYTHONPATH as client_pythonpath()
    in front of what it had, ROS_VERSION=2, and, with `domain`, that ROS_DOMAIN_ID and
    localhost discovery; `extra` last. Raises RuntimeError when skip_reason() is not None."""
    why = skip_reason()
    if why is not None:
        raise RuntimeError(f"the dVRK client cannot run here: {why}")
    env = dict(os.environ if base is None else base)
    env["PYTHONPATH"] = os.pathsep.join([*client_pythonpath(), *filter(None, [env.get("PYTHONPATH")])])
    env["ROS_VERSION"] = "2"
    if domain is not None:
        env["ROS_DOMAIN_ID"] = str(domain)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.update(extra)
    return env


def client_scripts() -> list[Path]:
    """The client's scripts: dvrk_python/scripts/*.py, then crtk_python_client/scripts/*.py
    (empty where the clients folder is absent)."""
    clients = clients_dir()
    return [p for folder in SCRIPT_FOLDERS for p in sorted((clients / folder).glob("*.py"))]
