"""Result documents as strict JSON (numpy values converted, NaN and infinity as null), written atomically and sealed by their provenance digest.

The digest seals the document: a file edited by hand (provenance or numbers) no longer
matches it and is treated as foreign until it is passed explicitly with the flag that
says so (e.g. `--force-model`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from datetime import datetime
from pathlib import Path
from typing import Any


def _json_default(value: Any) -> Any:
    # numpy scalars and arrays, Paths, datetimes: what configs and results hold
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (Path, datetime)):
        return str(value)
    if isinstance(value, (set, frozenset, tuple)):
        return list(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def to_json(value: Any, **kwargs) -> str:
    """JSON text of a metadata or result value (numpy values become lists and floats)."""
    return json.dumps(value, default=_json_default, **kwargs)


def _finite(value: Any) -> Any:
    # JSON has no NaN or infinity; strict readers (jq, browsers) reject Python's NaN token.
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def result_json(result: dict, indent: int | None = 2) -> str:
    """The result as strict JSON (numpy values converted, NaN and inf as null)."""
    return to_json(_finite(json.loads(to_json(result, allow_nan=True))), indent=indent, allow_nan=False)


def write_result(path: Path, result: dict) -> None:
    """Write result.json atomically (a reader never sees half a file)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(result_json(result) + "\n")
    os.replace(tmp, path)


KEY = "provenance"
DIGEST = "digest"


def _canonical(doc: dict) -> str:
    body = dict(doc)
    prov = dict(body.get(KEY) or {})
    prov.pop(DIGEST, None)
    body[KEY] = prov
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)


def seal(doc: dict) -> dict:
    """Set the digest of `doc` (a JSON-ready document holding a provenance section)."""
    doc[KEY][DIGEST] = hashlib.sha256(_canonical(doc).encode()).hexdigest()
    return doc


def sealed(doc: dict) -> bool:
    """True when `doc` (as read from its file) still matches its digest."""
    prov = doc.get(KEY)
    if not isinstance(prov, dict) or not prov.get(DIGEST):
        return False
    try:
        return hashlib.sha256(_canonical(doc).encode()).hexdigest() == prov[DIGEST]
    except (TypeError, ValueError):
        return False


def seal_provenance(doc: dict) -> None:
    """Seal a result that carries a rig provenance (rig.runs.provenance: its arms, or the load
    cell it calibrated) with its digest, as result.json will read back: a later hand edit
    is then seen by the procedure that would take the result."""
    prov = doc.get(KEY)
    if isinstance(prov, dict) and (prov.get("arms") or prov.get("cell")):
        doc[KEY] = dict(prov)
        canonical = json.loads(result_json(doc))
        doc[KEY][DIGEST] = seal(canonical)[KEY][DIGEST]
