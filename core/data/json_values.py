"""JSON for documents that carry NumPy values (the commands' ``--json`` documents, dataset results)."""
from __future__ import annotations

import json
import math

__all__ = ["to_jsonable", "plain"]


def to_jsonable(o):
    """``json`` fallback for NumPy values: integers -> int, floats -> float (null when not finite),
    arrays -> lists; anything else is a bug (``TypeError``)."""
    import numpy as np  # only reached for non-JSON values, whose producer has loaded numpy

    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def plain(doc):
    """``doc`` as plain JSON values (what a reader of its ``--json`` text would get back)."""
    return json.loads(json.dumps(doc, default=to_jsonable))
