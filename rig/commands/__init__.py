"""What every `rig` command shares: exit codes, parameters, --json and --yes, the report, the abort."""
