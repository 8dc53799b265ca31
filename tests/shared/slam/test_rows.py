"""Rows (shared.slam.rows): appended and dropped rows read back as a list would hold them."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from shared.slam.rows import Rows

rows_strategy = st.lists(st.tuples(*[st.floats(-1e6, 1e6)] * 3), max_size=80)


@given(rows=rows_strategy, drop=st.sets(st.integers(0, 79)))
def test_rows_read_back_as_a_list_holds_them(rows: list[tuple[float, float, float]], drop: set[int]) -> None:
    r = Rows(3)
    for row in rows:
        r.append(row)
    assert len(r) == len(rows)
    np.testing.assert_array_equal(r.view(), np.array(rows, dtype=float).reshape(-1, 3))
    gone = sorted(i for i in drop if i < len(rows))
    r.drop(gone)
    kept = [row for i, row in enumerate(rows) if i not in set(gone)]
    np.testing.assert_array_equal(r.view(), np.array(kept, dtype=float).reshape(-1, 3))
    r.append((1.0, 2.0, 3.0))
    np.testing.assert_array_equal(r.row(-1), [1.0, 2.0, 3.0])
    assert not r.view().flags.writeable
