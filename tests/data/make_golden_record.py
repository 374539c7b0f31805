"""Write the golden flight record of schema version 1 (``tests/data/record_v1_golden.h5``).

It was written once with the v1 writer (``thinkfast.record.recorder`` before schema 2, which kept
rows in memory and wrote the file at close) and committed; never regenerate it: it is what old
files look like. ``tests/test_recorder.py`` checks that today's reader reads its known values.
The rows are those of :func:`golden_rows`, so the test compares against the same numbers.

    python tests/data/make_golden_record.py [OUT]   # only with the schema-1 writer
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ATTRS = {"planner": "tree", "tree_config_sha256": "ab" * 32, "started": 1700000000.25}


def golden_rows() -> dict:
    """Two raw payloads, one accepted detection, one belief, one decision, three EGM rows."""
    cov = np.arange(36, dtype=float).reshape(6, 6) * 1e-4
    return {
        "raw": [(10.0, b'{"stamp": 9.96, "position": [7, 0, 1.2]}'), (10.02, b"not json")],
        "detection": [(10.0, 9.96, np.array([7.46, 0.0, 1.5]), 1)],
        "belief": [
            (
                10.0,
                SimpleNamespace(t=9.96, mean=np.array([7.46, 0, 1.5, -9, 0.1, 3]), cov=cov),
                SimpleNamespace(ok=True, mean=np.array([0.1, 1.2, 0.74]), cov=np.eye(3) * 0.01),
            )
        ],
        "decision": [(10.0, "tracking", 3, 0.625, 7)],
        "egm": [
            (10.0 + 0.004 * i, 100 + i, np.full(6, 0.1 * i), np.full(6, 0.2), np.zeros(6), i == 2)
            for i in range(3)
        ],
    }


def main() -> None:
    from thinkfast.record import recorder

    if recorder.SCHEMA_VERSION != 1:
        sys.exit("this script needs the schema-1 writer (git history before schema 2)")
    out = (
        Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("record_v1_golden.h5")
    )
    rec = recorder.Recorder(out, ATTRS)
    for method, rows in golden_rows().items():
        for row in rows:
            getattr(rec, method)(*row)
    rec.close()
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
