"""The results found for a rig (`rig doctor`): per arm its link lengths, RCM, identified model
and friction terms, the registration of the object's arms and each load cell's calibration.

A result not made yet is a "todo" line naming the command that makes it, never a failure;
newer results of this rig's arms that were set aside (another serial, a base moved) are
named with why, in one line per kind (rig.runs.provenance.set_aside_line).
"""

from __future__ import annotations

from rig.devices.preflight import Check, ok, todo
from rig.runs import provenance

#: per arm: the procedure, what it leaves, the command that makes it for `{arm}`
_PER_ARM = (("link-lengths", "link lengths", "rig link-lengths --arm {arm}"),
            ("calibrate-rcm", "RCM", "rig calibrate-rcm --arm {arm}"))


def _with_set_aside(text: str, skipped: list[str]) -> str:
    line = provenance.set_aside_line(skipped)
    return text + (f" ({line})" if line else "")


def results(cfg) -> list[Check]:
    """Every result the procedures take from logs/ for this rig, found or to make."""
    from rig.runs import model_results

    out: list[Check] = []
    for arm in cfg.arms:
        for procedure, what, command in _PER_ARM:
            f = provenance.find(procedure, cfg, arm=arm)
            label = f"{arm} {what}"
            if f.run_dir is not None:
                out.append(ok(label, _with_set_aside(f"{f.run_dir.name}", f.skipped)))
            else:
                out.append(todo(label, _with_set_aside(f"none yet: `{command.format(arm=arm)}`", f.skipped)))
        skipped: list[str] = []
        try:
            m = model_results.latest_model(cfg=cfg, arm=arm, skipped=skipped)
        except Exception as exc:  # noqa: BLE001 - a corrupt file is this line, not the end of the check
            out.append(Check(f"{arm} model", "fail", f"{str(exc).splitlines()[0]}: run `rig identify --arm {arm}` "
                             "again", 5))
            continue
        if m is not None and m.standard is not None:
            out.append(ok(f"{arm} model", _with_set_aside(str(m.path), skipped)))
        else:
            out.append(todo(f"{arm} model", _with_set_aside(f"none yet: `rig identify --arm {arm}`", skipped)))
        stick = m.stick_slip() if m is not None else None
        if stick is not None:
            out.append(ok(f"{arm} friction terms", f"joint 3 breakaway {stick.fs_pos:+.2f} / {stick.fs_neg:+.2f} N"))
        else:
            out.append(todo(f"{arm} friction terms", f"none yet: `rig friction-ramp --arm {arm}`"))
    arms = list(cfg.object["arms"] or list(cfg.arms)[:2])
    if len(arms) >= 2 and all(a in cfg.arms for a in arms):
        f = provenance.find("register", cfg, arms=arms,
                            usable=lambda run, data: all(a in (data.get("rcm_frames") or {}) for a in arms))
        if f.run_dir is not None:
            out.append(ok("registration", _with_set_aside(f"{', '.join(arms)}: {f.run_dir.name}", f.skipped)))
        else:
            out.append(todo("registration", _with_set_aside(f"none yet of {', '.join(arms)}: `rig register`",
                                                            f.skipped)))
    out.extend(_calibrations(cfg))
    return out


def _calibrations(cfg) -> list[Check]:
    from drivers.loadcell.errors import LoadCellNotCalibrated
    from rig.devices.loadcell_calibrations import load_latest_calibration

    lc = cfg.loadcell
    if lc["driver"] != "serial":
        return []
    out = []
    ports = lc["ports"] or [lc["port"]]
    for k, port in enumerate(ports):
        label = "load cell calibration" if len(ports) == 1 else f"load cell {k} calibration"
        try:
            cal = load_latest_calibration(port)
        except LoadCellNotCalibrated as exc:
            element = f" --element {k}" if len(ports) > 1 else ""
            out.append(todo(label, f"none for {port}: `rig loadcell-calibrate{element}`"
                            + (f" ({str(exc).split('(skipped ', 1)[1].split(')')[0]} set aside)"
                               if "(skipped " in str(exc) else "")))
            continue
        out.append(ok(label, f"{cal.newtons_per_count * 1e3:.4g} mN/count, made on {cal.device or port}"
                      + (f" {cal.created}" if cal.created else "")))
    return out
