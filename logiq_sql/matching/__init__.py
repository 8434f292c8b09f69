"""The matcher: relations, phases, matches, KPIs and coverage run on an engine, batches, explain, lint."""
