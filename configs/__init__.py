"""Default settings (TOML files) for the workcell, demos, agents, training and evaluation."""
