"""Where a result came from, and whether it belongs to the rig a procedure runs on.

Every result a later procedure may take (the identified model, the registration, the RCM
frames, the link lengths, a load-cell calibration) carries a ``provenance`` section::

    "provenance": {
        "arms": [{"name": "PSM1", "identity": "simulated PSM1 (plant 9c1f03aa2b7e)",
                  "mounting": "1f0c9a7e3d21"}],   # mounting(): identity, base pose, gravity
        "rig": "5d0e8c41a9b2",                  # rig_identity() of the configuration
        "source": {"run": "20261125T160203123456Z-identify"}
                  # or {"csv": "/abs/path.csv", "sha256": "<hex>"} for a recording
        "package_version": "0.1.0",
        "time": "2026-11-25T16:02:03+00:00",
        "digest": "<sha256 of the whole document without this field>"
    }

An arm's identity is what the configuration and its driver can tell about the hardware:
a simulated arm by its plant (nominal, hidden effects, plant model file), a dVRK arm by
the serial number the configuration gives (`[arms.X] serial`), else by its ROS namespace.
A recording in a CSV file has no arm the rig can recognise.

An arm's mounting is a stable hash of what decides whether a geometric or dynamic result
of it still holds: its identity, its base pose and gravity; the rig identity hashes every
arm's. A result belongs where each arm it holds has the same identity and mounting: a
model of PSM1 stays valid when PSM3 is added to the configuration, a registration of PSM1
and PSM2 does not when PSM2 is moved. Seeds, rates, the object, the load cell, mocap and
ROS settings are left out: changing them does not move an arm.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

from rig.sealed_json import KEY, sealed


# ------------------------------------------------------------------ identities
def _hash(data: Any, n: int = 12) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:n]


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _plant_file_digest(path: str) -> str:
    if not path:
        return ""
    try:
        return file_sha256(path)[:12]
    except OSError:
        return f"unreadable {path}"


def arm_identity(cfg, name: str) -> str:
    """What identifies arm `name` of configuration `cfg` (see the module docstring)."""
    a = cfg.arms[name]
    if a["driver"] == "sim":
        plant = {"effects": cfg.effects.get(name, {}), "plant_model": _plant_file_digest(a.get("plant_model", ""))}
        return f"simulated {name} (plant {_hash(plant)})"
    if a.get("serial"):
        return f"dVRK {name} serial {a['serial']}"
    return f"dVRK arm on {a['namespace'] or '/' + name} (no serial in the configuration)"


def mounting(cfg, name: str) -> str:
    """Stable hash of arm `name`'s identity, its mounting (base pose) and gravity: what a
    result of that arm depends on besides the arm itself."""
    a = cfg.arms[name]
    return _hash({"identity": arm_identity(cfg, name), "base_xyz": [round(float(x), 6) for x in a["base_xyz"]],
                  "base_rpy": [round(float(x), 6) for x in a["base_rpy"]],
                  "gravity": [round(float(x), 6) for x in cfg.rig["gravity"]]})


def rig_identity(cfg) -> str:
    """Stable hash of every arm's mounting (identity, base pose) and gravity: the rig."""
    return _hash({n: mounting(cfg, n) for n in sorted(cfg.arms)})


# ------------------------------------------------------------------ making it
def _base(arms: list[dict], rig: str | None, source: dict) -> dict:
    from rig.runs.recording import package_version

    return {"arms": arms, "rig": rig, "source": source, "package_version": package_version(),
            "time": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def live(cfg, arms, run_dir) -> dict:
    """Provenance of a result measured on the rig `cfg` with `arms`, in run `run_dir`."""
    return _base([{"name": n, "identity": arm_identity(cfg, n), "mounting": mounting(cfg, n), **_placement(cfg, n)}
                  for n in arms], rig_identity(cfg), {"run": Path(run_dir).name})


def _placement(cfg, name: str) -> dict:
    """What `mounting` hashes besides the identity, in the clear: a result set aside for a
    changed placement then says what changed."""
    a = cfg.arms[name]
    return {"base_xyz": [round(float(x), 6) for x in a["base_xyz"]],
            "base_rpy": [round(float(x), 6) for x in a["base_rpy"]],
            "gravity": [round(float(x), 6) for x in cfg.rig["gravity"]]}


def recording(csv_path, arm_label: str = "recorded arm") -> dict:
    """Provenance of a result computed from a CSV recording: no rig, the file's hash."""
    p = Path(csv_path).resolve()
    sha = file_sha256(p)
    return _base([{"name": arm_label, "identity": f"recording {p.name} (sha256 {sha[:12]})"}], None,
                 {"csv": str(p), "sha256": sha})


# ------------------------------------------------------------------ belonging
def mismatch(doc: dict, cfg, arm: str | None = None, arms: list[str] | None = None) -> str | None:
    """Why the result `doc` does not belong to arm `arm` (or the arms `arms`) of rig `cfg`,
    or None when it does."""
    prov = doc.get(KEY)
    if not isinstance(prov, dict) or not prov.get("arms"):
        return "it carries no provenance (written by an older dvrk-rig or by hand)"
    if not sealed(doc):
        return "it was edited after it was written (its digest does not match)"
    source = prov.get("source") or {}
    if prov.get("rig") is None:
        where = source.get("csv", "a recording")
        return f"it was computed from {where}, not measured on this rig"
    have = {a.get("name"): a for a in prov["arms"]}
    want = [arm] if arm is not None else list(arms or have)
    for n in want:
        if n not in have:
            return f"it holds no result for {n} (it has {', '.join(map(str, have))})"
        if n not in cfg.arms:
            return f"it is a result of {n}, which this rig configuration does not have"
        if have[n].get("identity") != arm_identity(cfg, n):
            now = arm_identity(cfg, n)
            hint = (f" ([arms.{n}] serial was added after it was measured: run it again, or remove the serial)"
                    if "no serial" in str(have[n].get("identity")) and "serial" in now else "")
            return f"its {n} is {have[n].get('identity')}, this rig's is {now}{hint}"
        if have[n].get("mounting") != mounting(cfg, n):
            here = _placement(cfg, n)
            changed = [f"{k} {have[n][k]} then, {here[k]} now" for k in ("base_xyz", "base_rpy", "gravity")
                       if k in have[n] and have[n][k] != here[k]]
            return (f"{n} was measured on another placement ({'; '.join(changed)}): a base moved in rig.toml moves "
                    "the arm's results with it; run the procedure again" if changed else
                    f"it was measured on another rig configuration ({n}'s mounting or gravity differ: "
                    f"{have[n].get('mounting')}, here {mounting(cfg, n)})")
    return None


def _of_other_arms(doc: dict, want: list[str]) -> bool:
    """True when `doc` was measured on a rig and holds none of the arms `want` (PSM2's model,
    looked at for PSM1): passed over without a word. A recording's result, or one without
    a provenance, is still named when it is passed over."""
    prov = doc.get(KEY) if isinstance(doc, dict) else None
    if not want or not isinstance(prov, dict) or prov.get("rig") is None or not isinstance(prov.get("arms"), list):
        return False
    held = {a.get("name") for a in prov["arms"] if isinstance(a, dict)}
    return not (set(want) & held)


def describe(doc: dict) -> str:
    """One phrase naming where a result came from."""
    prov = doc.get(KEY) or {}
    arms = ", ".join(f"{a.get('name')}" for a in prov.get("arms", [])) or "unknown arm"
    source = prov.get("source") or {}
    src = source.get("run") or source.get("csv") or "unknown source"
    return f"{arms} from {src}"


@dataclass
class Found:
    """A result taken implicitly, and the newer ones skipped on the way."""

    run_dir: Path | None
    data: dict | None
    skipped: list[str] = field(default_factory=list)

    def set_aside(self) -> str | None:
        """One line: how many newer results were set aside, and why the newest was."""
        return set_aside_line(self.skipped)


def set_aside_line(skipped: list[str]) -> str | None:
    """`skipped` (find's lines, newest first) as one line, or None when nothing was set aside."""
    if not skipped:
        return None
    if len(skipped) == 1:
        return f"set aside: {skipped[0]}"
    return f"{len(skipped)} results set aside, the newest: {skipped[0]}"


def find(procedure: str, cfg, *, arm: str | None = None, arms: list[str] | None = None,
         document: Callable[[Path, dict], dict | None] | None = None,
         usable: Callable[[Path, dict], bool] | None = None) -> Found:
    """The newest completed run of `procedure` whose result belongs to `arm`/`arms` of rig
    `cfg`; each newer completed run skipped is named with the reason in `skipped`.

    `document(run_dir, result)` gives the document that carries the provenance (default:
    the result itself; a model lives in its own file); `usable(run_dir, result)` filters out
    results that do not hold what the caller needs (they are skipped silently).
    """
    from rig.runs.paths import run_dirs

    out = Found(None, None)
    for run in reversed(run_dirs(procedure)):
        try:
            data = json.loads((run / "result.json").read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or data.get("status", "completed") != "completed":
            continue
        if usable is not None and not usable(run, data):
            continue
        doc = data if document is None else document(run, data)
        if doc is None:
            continue
        if _of_other_arms(doc, [arm] if arm is not None else list(arms or [])):
            continue  # another arm's result of this rig: not one set aside for this arm
        why = mismatch(doc, cfg, arm=arm, arms=arms)
        if why is None:
            out.run_dir, out.data = run, data
            return out
        out.skipped.append(f"skipped {procedure} run {run.name}: {why}")
    return out
