"""The options every procedure's command takes (--json, --yes) and the configuration it runs on."""

from __future__ import annotations

import click

from rig.commands.exit_codes import InputError

json_option = click.option("--json", "as_json", is_flag=True,
                           help="Print the result as one JSON document on stdout (report on stderr).")


def _remember_yes(ctx: click.Context, _param, value: bool) -> bool:
    if value:
        root = ctx.find_root()
        root.obj = dict(root.obj or {}, yes=True)
    return value


yes_option = click.option(
    "--yes", is_flag=True, expose_value=False, callback=_remember_yes,
    help="Take every request for a person (mount marker bodies, attach or take off the object, hang masses) "
         "as done without waiting for Enter: for a rig prepared beforehand. Without it, each request waits "
         "for Enter on stdin (a script can answer with newlines). No effect on the simulated rig.")


def config_from_context(ctx: click.Context):
    """The rig configuration of a command: `rig --config FILE`, else ./rig.toml, else the
    built-in simulated rig; a bad file is a one-line click error naming the file and key.
    A command's `--yes` sets `[operator] yes`."""
    from rig import config

    obj = ctx.find_root().obj or {}
    try:
        cfg = config.load(obj.get("config_path"))
    except config.ConfigError as exc:
        raise InputError(str(exc)) from None
    if obj.get("yes"):
        cfg.operator["yes"] = True
    return cfg
