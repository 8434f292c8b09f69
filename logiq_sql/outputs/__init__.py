"""What users read from a run: the HTML report, plots, replays, OpenSCENARIO and OpenLABEL exports."""
