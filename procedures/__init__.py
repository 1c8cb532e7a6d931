"""The rig's procedures: one module per `rig` command holding its steps, its report and figures beside it."""
