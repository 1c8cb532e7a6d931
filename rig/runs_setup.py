"""What a run was set up with, as `rig runs` shows it: the arms it used (from its result,
its start record or its provenance) and, for `rig cooperative`, its set-up (object, mode,
who closed the slaves' impedance, model) read back from its command line and result."""

from __future__ import annotations

from pathlib import Path


def source_arms(provenance) -> list[str]:
    """Names of the arms a result comes from, from its provenance's "arms" (a list of
    {"name": ...} or of names); [] without one."""
    if not isinstance(provenance, dict):
        return []
    arms = provenance.get("arms")
    if isinstance(arms, (str, dict)):
        arms = [arms]
    if not isinstance(arms, list):
        return []
    names = []
    for arm in arms:
        name = arm.get("name") if isinstance(arm, dict) else arm
        if name is not None:
            names.append(str(name))
    return names


def arms_of(result: dict, start: dict) -> list[str]:
    """The arms a run used: those its result's provenance names (where the result comes
    from), else those the result names ("arms", "arm"), else those it held or tried to
    hold, else the arm its parameters name on a live rig; [] for none (a fit of a CSV file,
    a load-cell calibration)."""
    names = source_arms(result.get("provenance"))
    if names:
        return names
    arms = result.get("arms")
    if isinstance(arms, list) and arms and all(isinstance(a, str) for a in arms):
        return list(arms)
    if isinstance(result.get("arm"), str) and result["arm"]:
        return [result["arm"]]
    tried = list(result.get("held") or []) + [e.get("arm") for e in result.get("hold_errors") or []
                                              if isinstance(e, dict) and e.get("arm")]
    if tried:
        return list(dict.fromkeys(map(str, tried)))
    config = start.get("config") if isinstance(start.get("config"), dict) else {}
    arm = (start.get("parameters") or {}).get("arm") if isinstance(start.get("parameters"), dict) else None
    arm = arm.get("value") if isinstance(arm, dict) else arm
    if config.get("arms") and isinstance(arm, str) and arm:  # a live run (a fit of a file records no rig)
        return list(config["arms"]) if arm == "all" else [arm]
    return []


def _cooperative_command(start: dict) -> dict:
    """The options of the `rig cooperative` command line a run was started with (its start
    record's argv), defaults included, parsed by the command itself; {} for a run started
    otherwise (a test or a bench calling the procedure) or when the command cannot load."""
    argv = str(start.get("argv") or "").split()
    if not argv or not (Path(argv[0]).name == "rig" or argv[0].endswith(("rig/cli.py", "rig.cli"))):
        return {}
    try:
        args = argv[argv.index("cooperative", 1) + 1:]
        from procedures.cooperative import command

        with command.make_context("cooperative", args, resilient_parsing=True) as ctx:
            return dict(ctx.params)
    except Exception:  # noqa: BLE001 - an old or odd command line: the list shows what the result says
        return {}


def _vector(value) -> list[float] | None:
    """[x, y, z] from a list or a "x,y,z" string; None if it is neither."""
    try:
        v = [float(x) for x in (value.split(",") if isinstance(value, str) else value)]
    except (TypeError, ValueError):
        return None
    return v if len(v) == 3 else None


def cooperative_setup(result: dict, start: dict) -> dict:
    """What a cooperative run held and did: object, force_n, mode, arms, master, move_m,
    rotate_rad, rate_hz (the loop's). From its result; what the result lacks (an aborted
    run's, or the move, which the result does not record) from its start record: the
    configuration snapshot (object, arms, rate), the parameters (force) and the command
    line. A field nothing records is None."""
    config = start.get("config") if isinstance(start.get("config"), dict) else {}
    obj = config.get("object") if isinstance(config.get("object"), dict) else {}
    params = start.get("parameters") if isinstance(start.get("parameters"), dict) else {}
    cmd = _cooperative_command(start)
    arms = result.get("arms") if isinstance(result.get("arms"), list) else None
    if not arms:
        arms = ([a.strip() for a in cmd["arms"].split(",")] if cmd.get("arms") else obj.get("arms")) or []
    force = result.get("force", params.get("force"))
    force = force.get("value") if isinstance(force, dict) else force
    timing = result.get("loop_timing") if isinstance(result.get("loop_timing"), dict) else {}
    rig = config.get("rig") if isinstance(config.get("rig"), dict) else {}
    return {
        "object": result.get("object") or obj.get("kind"),
        "force_n": force if isinstance(force, (int, float)) else None,
        "mode": result.get("mode") or cmd.get("mode"),
        "arms": list(arms),
        # the command takes the last arm as the master when --master is not given
        "master": result.get("master") or cmd.get("master") or (arms[-1] if cmd and arms else None),
        "move_m": _vector(result.get("move", cmd.get("move"))),
        "rotate_rad": _vector(result.get("rotate", cmd.get("rotate"))),
        "rate_hz": timing.get("rate_hz") or rig.get("rate"),
    }


def setup_text(setup: dict) -> str:
    """A cooperative setup in a few words: "spring 5 N, impedance, PSM2 moves +50,0,0 mm, 1000 Hz"."""
    if not setup:
        return ""
    parts = []
    if setup.get("object"):
        force = setup.get("force_n")
        parts.append(setup["object"] + (f" {force:g} N" if force is not None else ""))
    if setup.get("mode"):
        parts.append(setup["mode"])
    move = setup.get("move_m")
    motion = ""
    if move is not None:
        motion = ",".join(f"{1000 * v:+.4g}" if v else "0" for v in move) + " mm"
    turn = setup.get("rotate_rad")
    if turn is not None and any(turn):
        motion += (" and turns " if motion else "turns ") + ",".join(f"{v:+.3g}" if v else "0" for v in turn) + " rad"
    if setup.get("master"):
        parts.append(f"{setup['master']} moves {motion}" if motion else f"master {setup['master']}")
    elif motion:
        parts.append(f"the master moves {motion}")
    if setup.get("rate_hz"):
        parts.append(f"{setup['rate_hz']:g} Hz")
    return ", ".join(parts)
