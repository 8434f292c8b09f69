"""The evaluation harness: simulated drives, ground truth from the simulator, scores of the matcher against it.

- ``simulate``: SUMO drives (motorway, junctions) in realistic regimes, with optional perception-like noise.
- ``labels``: ground-truth labels of the scenarios from SUMO's own records, never from the matcher's SQL.
- ``evaluate``: event and timestamp scores of stored matches against labels.
- ``crosscheck``: logiq_sql's TTC and KPIs against SUMO's SSM and FCD values.

None of it is on the product's path: the CLI imports these modules, they never import the CLI. docs/evaluation.md.
"""
