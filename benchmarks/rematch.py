"""One re-match (``match --force --ego every:10``) of a matched file in this process, and its CPU seconds: the
whole match and the relations stage (logiq_sql.core.timing). Run as a script, so that PYTHONPATH chooses the code:

    PYTHONPATH=. python benchmarks/rematch.py COPY.duckdb all
    PYTHONPATH=/tmp/before python benchmarks/rematch.py COPY.duckdb cyclist_close_to_moving_sut

(/tmp/before: ``git archive <commit> logiq_sql queries scenarios | tar -x -C /tmp/before``). It writes the file's
results: match a copy.
"""

from __future__ import annotations

import json
import sys
import time

import logiq_sql
from logiq_sql import match
from logiq_sql.core.timing import cpu_seconds, recording


def main(db: str, which: str) -> dict[str, object]:
    with recording() as rec:
        cpu, wall = cpu_seconds(), time.perf_counter()
        result = match(db, scenarios=None if which == "all" else which.split(","), ego="every:10", force=True)
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    return {"code": logiq_sql.__file__, "which": which, "match_cpu_s": round(cpu, 2), "match_wall_s": round(wall, 2),
            "relations_cpu_s": round(rec.cpu_seconds.get("relations", 0.0), 2),
            "relations_wall_s": round(rec.seconds.get("relations", 0.0), 2), "matches": result.matches.height}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], sys.argv[2])))
