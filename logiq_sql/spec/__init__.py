"""Scenarios: the TOML files, their contract with their SQL, the plan of a run, new-scenario scaffolds."""
